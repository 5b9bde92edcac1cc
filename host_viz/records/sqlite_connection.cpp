// The SQLite back end of records/sql.hpp (libsqlite3): one file, WAL (readers never wait for the
// writer; writers from several processes take turns), a busy timeout instead of failing at once,
// foreign keys on.

#include <sqlite3.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <system_error>
#include <thread>

#include "records/sql.hpp"

namespace lancet::records::sql {
namespace {

class SqliteConnection final : public Connection {
 public:
  SqliteConnection(sqlite3* db, std::string path) : db_(db), path_(std::move(path)) {}
  ~SqliteConnection() override { sqlite3_close_v2(db_); }
  SqliteConnection(const SqliteConnection&) = delete;
  SqliteConnection& operator=(const SqliteConnection&) = delete;

  Result<std::vector<Row>> query(const std::string& statement, const std::vector<Value>& params) override {
    std::vector<Row> rows;
    auto r = run(statement, params, &rows);
    if (!r.ok()) return r.error();
    return rows;
  }
  Result<std::int64_t> execute(const std::string& statement, const std::vector<Value>& params) override {
    auto r = run(statement, params, nullptr);
    if (!r.ok()) return r.error();
    return static_cast<std::int64_t>(sqlite3_changes(db_));
  }
  Result<void> begin_write() override {
    auto r = execute("BEGIN IMMEDIATE", {});
    if (!r.ok()) return r.error();
    return {};
  }
  void rollback() noexcept override {
    if (sqlite3_get_autocommit(db_) == 0) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
  }
  [[nodiscard]] const char* kind() const noexcept override { return "sqlite"; }
  [[nodiscard]] const std::string& name() const noexcept override { return path_; }

  Error error(const std::string& what) const {
    return Error{ErrorCode::kSystem, path_ + ": " + what + ": " + sqlite3_errmsg(db_)};
  }

 private:
  // Prepares, binds, steps to the end (collecting rows when `rows` is given), finalises.
  Result<void> run(const std::string& statement, const std::vector<Value>& params, std::vector<Row>* rows) {
    sqlite3_stmt* st = nullptr;
    if (sqlite3_prepare_v2(db_, statement.c_str(), static_cast<int>(statement.size()), &st, nullptr) != SQLITE_OK)
      return error("cannot prepare \"" + statement.substr(0, 60) + "\"");
    for (std::size_t i = 0; i < params.size(); ++i) bind(st, static_cast<int>(i + 1), params[i]);
    int rc = SQLITE_ROW;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
      if (rows == nullptr) continue;
      Row row(static_cast<std::size_t>(sqlite3_column_count(st)));
      for (int c = 0; c < sqlite3_column_count(st); ++c) row[static_cast<std::size_t>(c)] = column(st, c);
      rows->push_back(std::move(row));
    }
    if (rc != SQLITE_DONE) {
      Error e = error("\"" + statement.substr(0, 60) + "\" failed");
      sqlite3_finalize(st);
      return e;
    }
    sqlite3_finalize(st);
    return {};
  }

  static void bind(sqlite3_stmt* st, int i, const Value& v) {
    if (const auto* n = std::get_if<std::int64_t>(&v)) {
      sqlite3_bind_int64(st, i, *n);
    } else if (const auto* d = std::get_if<double>(&v)) {
      sqlite3_bind_double(st, i, *d);
    } else if (const auto* s = std::get_if<std::string>(&v)) {
      sqlite3_bind_text(st, i, s->data(), static_cast<int>(s->size()), nullptr);  // static: `params` outlives the statement
    } else {
      sqlite3_bind_null(st, i);
    }
  }

  static Value column(sqlite3_stmt* st, int c) {
    switch (sqlite3_column_type(st, c)) {
      case SQLITE_INTEGER: return static_cast<std::int64_t>(sqlite3_column_int64(st, c));
      case SQLITE_FLOAT: return sqlite3_column_double(st, c);
      case SQLITE_NULL: return std::monostate{};
      default: {
        const auto* text = reinterpret_cast<const char*>(sqlite3_column_text(st, c));
        return std::string(text, static_cast<std::size_t>(sqlite3_column_bytes(st, c)));
      }
    }
  }

  sqlite3* db_;
  std::string path_;
};

}  // namespace

Result<std::unique_ptr<Connection>> open_sqlite(const std::string& path, int busy_timeout_ms) {
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  if (ec) return Error{ErrorCode::kSystem, path + ": cannot create the folder " + parent.string() + ": " + ec.message()};
  sqlite3* db = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
  auto c = std::make_unique<SqliteConnection>(db, path);  // closes `db` whatever happens next
  if (rc != SQLITE_OK) return c->error("cannot open the database");
  sqlite3_busy_timeout(db, busy_timeout_ms);
  // WAL: one writer at a time, readers alongside it; NORMAL sync is durable at each checkpoint
  // and never corrupts. The journal mode is the file's, so setting it again is a no-op. Switching a
  // new file to WAL needs it to itself, and SQLite answers "database is locked" at once, without
  // the busy handler, while another process is switching it (ten importers starting together on
  // a new file): that one step is retried until the busy timeout.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(busy_timeout_ms);
  for (;;) {
    const int wal = sqlite3_exec(db, "PRAGMA journal_mode=WAL", nullptr, nullptr, nullptr);
    if (wal == SQLITE_OK) break;
    if ((wal & 0xFF) != SQLITE_BUSY || std::chrono::steady_clock::now() >= deadline) return c->error("\"PRAGMA journal_mode=WAL\" failed");
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  for (const char* pragma : {"PRAGMA synchronous=NORMAL", "PRAGMA foreign_keys=ON"}) {
    auto r = c->query(pragma, {});
    if (!r.ok()) return r.error();
  }
  return std::unique_ptr<Connection>(std::move(c));
}

}  // namespace lancet::records::sql
