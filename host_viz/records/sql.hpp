#pragma once
// The small SQL interface the training records are written through: one connection to one
// database, statements with positional parameters ("?" in the text), rows of values. Two back
// ends implement it: SQLite (libsqlite3; a file, WAL, a busy timeout) and PostgreSQL (libpq; a
// connection URL). The store (records/store.hpp) is written once above it, with one SQL text for
// both: types TEXT, BIGINT, DOUBLE PRECISION; "INSERT ... ON CONFLICT DO NOTHING"; no
// back-end-specific functions.
//
// Tools only (everything here allocates and blocks on the database). A connection is used by one
// thread at a time.

#include <cstdint>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "lancet/shared_model/result.hpp"

namespace lancet::records::sql {

/// A parameter or a column: NULL, an integer, a number or text. PostgreSQL returns every column as
/// text; read columns through as_int/as_double/as_text, which take either form.
using Value = std::variant<std::monostate, std::int64_t, double, std::string>;
using Row = std::vector<Value>;

[[nodiscard]] bool is_null(const Value& v) noexcept;
/// The column as an integer (0 for NULL or text that is not one).
[[nodiscard]] std::int64_t as_int(const Value& v);
/// The column as a number (NaN for NULL).
[[nodiscard]] double as_double(const Value& v);
/// The column as text ("" for NULL).
[[nodiscard]] std::string as_text(const Value& v);
/// A number as a parameter: NULL when it is not finite (NaN: a metric that was not measured).
[[nodiscard]] Value number_or_null(double v);

class Connection {
 public:
  virtual ~Connection() = default;
  /// Runs one statement; returns its rows (none for a statement that returns none). Errors name
  /// the database and quote the back end's message.
  virtual Result<std::vector<Row>> query(const std::string& statement, const std::vector<Value>& params = {}) = 0;
  /// Runs one statement that returns no rows; returns how many rows it changed.
  virtual Result<std::int64_t> execute(const std::string& statement, const std::vector<Value>& params = {}) = 0;
  /// Begins a transaction that holds the database's write lock until commit() or rollback()
  /// (SQLite: BEGIN IMMEDIATE, waiting up to the busy timeout; PostgreSQL: BEGIN and an
  /// advisory transaction lock, so schema changes and the writes after them are serialised).
  virtual Result<void> begin_write() = 0;
  /// Commits; a commit that fails is rolled back (the transaction is over either way).
  [[nodiscard]] Result<void> commit();
  /// Ends a transaction without its changes; never fails (a lost connection rolls back anyway).
  virtual void rollback() noexcept = 0;
  /// "sqlite" or "postgresql".
  [[nodiscard]] virtual const char* kind() const noexcept = 0;
  /// The database as the user named it (a file, or the URL without its password).
  [[nodiscard]] virtual const std::string& name() const noexcept = 0;
};

/// Opens (creating when missing, with its folders) an SQLite file in WAL mode with a busy timeout
/// of `busy_timeout_ms`.
[[nodiscard]] Result<std::unique_ptr<Connection>> open_sqlite(const std::string& path, int busy_timeout_ms = 60'000);
/// Connects to PostgreSQL by URL ("postgresql://user@host/db", "postgresql:///db?host=/run/dir").
[[nodiscard]] Result<std::unique_ptr<Connection>> open_postgresql(const std::string& url);

/// Rolls back on destruction unless committed: one transaction per scope, nothing half-written
/// when an error returns early.
class Transaction {
 public:
  explicit Transaction(Connection& c) : c_(c) {}
  ~Transaction() {
    if (open_) c_.rollback();
  }
  Transaction(const Transaction&) = delete;
  Transaction& operator=(const Transaction&) = delete;
  [[nodiscard]] Result<void> begin() {
    auto r = c_.begin_write();
    open_ = r.ok();
    return r;
  }
  [[nodiscard]] Result<void> commit() {
    open_ = false;
    return c_.commit();
  }

 private:
  Connection& c_;
  bool open_ = false;
};

}  // namespace lancet::records::sql
