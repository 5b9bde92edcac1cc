// The PostgreSQL back end of records/sql.hpp (libpq): one connection by URL; parameters are sent
// as text ("?" in the statement becomes $1, $2, ...), columns come back as text.

#include <libpq-fe.h>

#include <cstdio>
#include <optional>
#include <string>
#include <vector>

#include "records/sql.hpp"

namespace lancet::records::sql {
namespace {

// Any transaction that writes takes this advisory lock first, so writers (and the schema's
// migration) take turns as they do on SQLite, and CREATE TABLE IF NOT EXISTS never races.
constexpr const char* kWriteLockKey = "7041952771";  // arbitrary, Lancet's own

// The URL as it may be shown: "user:password@" becomes "user@".
std::string without_password(const std::string& url) {
  const std::size_t scheme = url.find("://");
  const std::size_t at = url.find('@');
  if (scheme == std::string::npos || at == std::string::npos) return url;
  const std::size_t colon = url.find(':', scheme + 3);
  if (colon == std::string::npos || colon > at) return url;
  return url.substr(0, colon) + url.substr(at);
}

// "?" placeholders as PostgreSQL's $n (the store's statements have no "?" inside literals).
std::string numbered(const std::string& statement) {
  std::string out;
  int n = 0;
  for (const char ch : statement) {
    if (ch == '?') {
      out += '$' + std::to_string(++n);
    } else {
      out += ch;
    }
  }
  return out;
}

std::string text_of(const Value& v) {
  if (const auto* n = std::get_if<std::int64_t>(&v)) return std::to_string(*n);
  if (const auto* d = std::get_if<double>(&v)) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", *d);
    return buf;
  }
  return std::get<std::string>(v);
}

class PgConnection final : public Connection {
 public:
  PgConnection(PGconn* conn, std::string name) : conn_(conn), name_(std::move(name)) {}
  ~PgConnection() override { PQfinish(conn_); }
  PgConnection(const PgConnection&) = delete;
  PgConnection& operator=(const PgConnection&) = delete;

  Result<std::vector<Row>> query(const std::string& statement, const std::vector<Value>& params) override {
    PGresult* res = run(statement, params);
    if (auto e = check(res, statement)) return *e;
    std::vector<Row> rows(static_cast<std::size_t>(PQntuples(res)));
    for (int r = 0; r < PQntuples(res); ++r) {
      Row& row = rows[static_cast<std::size_t>(r)];
      row.resize(static_cast<std::size_t>(PQnfields(res)));
      for (int c = 0; c < PQnfields(res); ++c) {
        if (!PQgetisnull(res, r, c)) row[static_cast<std::size_t>(c)] = std::string(PQgetvalue(res, r, c), static_cast<std::size_t>(PQgetlength(res, r, c)));
      }
    }
    PQclear(res);
    return rows;
  }
  Result<std::int64_t> execute(const std::string& statement, const std::vector<Value>& params) override {
    PGresult* res = run(statement, params);
    if (auto e = check(res, statement)) return *e;
    const std::string changed = PQcmdTuples(res);
    PQclear(res);
    return changed.empty() ? std::int64_t{0} : std::stoll(changed);
  }
  Result<void> begin_write() override {
    if (auto r = execute("BEGIN", {}); !r.ok()) return r.error();
    if (auto r = query(std::string("SELECT pg_advisory_xact_lock(") + kWriteLockKey + ")", {}); !r.ok()) {
      rollback();
      return r.error();
    }
    return {};
  }
  void rollback() noexcept override {
    if (PQtransactionStatus(conn_) != PQTRANS_IDLE) PQclear(PQexec(conn_, "ROLLBACK"));
  }
  [[nodiscard]] const char* kind() const noexcept override { return "postgresql"; }
  [[nodiscard]] const std::string& name() const noexcept override { return name_; }

 private:
  PGresult* run(const std::string& statement, const std::vector<Value>& params) {
    std::vector<std::string> texts(params.size());
    std::vector<const char*> values(params.size(), nullptr);
    for (std::size_t i = 0; i < params.size(); ++i) {
      if (is_null(params[i])) continue;
      texts[i] = text_of(params[i]);
      values[i] = texts[i].c_str();
    }
    return PQexecParams(conn_, numbered(statement).c_str(), static_cast<int>(params.size()), nullptr, values.data(), nullptr, nullptr, 0);
  }

  // An error (and the result cleared) when the statement failed; nullopt when it ran.
  std::optional<Error> check(PGresult* res, const std::string& statement) {
    const ExecStatusType st = res != nullptr ? PQresultStatus(res) : PGRES_FATAL_ERROR;
    if (st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK) return std::nullopt;
    std::string message = res != nullptr ? PQresultErrorMessage(res) : PQerrorMessage(conn_);
    while (!message.empty() && message.back() == '\n') message.pop_back();
    PQclear(res);
    return Error{ErrorCode::kSystem, name_ + ": \"" + statement.substr(0, 60) + "\" failed: " + message};
  }

  PGconn* conn_;
  std::string name_;
};

}  // namespace

Result<std::unique_ptr<Connection>> open_postgresql(const std::string& url) {
  PGconn* conn = PQconnectdb(url.c_str());
  auto c = std::make_unique<PgConnection>(conn, without_password(url));  // finishes `conn` whatever happens
  if (conn == nullptr || PQstatus(conn) != CONNECTION_OK) {
    std::string message = conn != nullptr ? PQerrorMessage(conn) : "out of memory";
    while (!message.empty() && message.back() == '\n') message.pop_back();
    return Error{ErrorCode::kNotFound, c->name() + ": cannot connect: " + message};
  }
  // Quiet notices ("relation already exists, skipping") instead of libpq printing them on stderr.
  PQsetNoticeProcessor(conn, [](void*, const char*) {}, nullptr);
  return std::unique_ptr<Connection>(std::move(c));
}

}  // namespace lancet::records::sql
