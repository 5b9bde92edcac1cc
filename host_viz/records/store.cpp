// The training records' store (records/store.hpp): the schema, its migrations, and each record's
// statements, written once for both back ends.

#include "records/store.hpp"

#include <array>
#include <cstdlib>
#include <ctime>
#include <map>
#include <string_view>

#include "records/utc_time.hpp"

namespace lancet::records {
namespace {

using sql::as_double;
using sql::as_int;
using sql::as_text;
using sql::Row;
using sql::Value;

// Migration i + 1 brings the schema from version i to i + 1. Only ever append: a database keeps
// the versions it has applied. Types and syntax both back ends read alike.
const std::array<std::vector<std::string_view>, kSchemaVersion> kMigrations{{
    {
        "CREATE TABLE trainees (id TEXT PRIMARY KEY, name TEXT NOT NULL, cohort TEXT NOT NULL)",
        "CREATE TABLE curriculum (step BIGINT PRIMARY KEY, name TEXT NOT NULL, scenario TEXT NOT NULL, "
        "scenario_hash TEXT NOT NULL, required BIGINT NOT NULL, consecutive BIGINT NOT NULL)",
        "CREATE TABLE attempts (content_hash TEXT PRIMARY KEY, trainee_id TEXT REFERENCES trainees (id), "
        "scenario TEXT NOT NULL, scenario_hash TEXT NOT NULL, recording TEXT NOT NULL, started TEXT NOT NULL, "
        "ended TEXT NOT NULL, duration_s DOUBLE PRECISION, verdict TEXT NOT NULL, proficient BIGINT NOT NULL, "
        "banded BIGINT NOT NULL, passed BIGINT NOT NULL, build TEXT NOT NULL, scored_by TEXT NOT NULL, imported TEXT NOT NULL)",
        "CREATE INDEX attempts_by_trainee ON attempts (trainee_id, scenario, started)",
        "CREATE TABLE attempt_metrics (content_hash TEXT NOT NULL REFERENCES attempts (content_hash) ON DELETE CASCADE, "
        "ordinal BIGINT NOT NULL, name TEXT NOT NULL, value DOUBLE PRECISION, unit TEXT NOT NULL, better TEXT NOT NULL, "
        "band_mean DOUBLE PRECISION, band_sd DOUBLE PRECISION, band_k DOUBLE PRECISION, band_limit DOUBLE PRECISION, "
        "pass BIGINT NOT NULL, hand TEXT NOT NULL, PRIMARY KEY (content_hash, name))",
    },
}};

std::string iso_now() { return iso_utc(std::time(nullptr)); }

Value text_or_null(const std::string& s) {
  if (s.empty()) return std::monostate{};
  return s;
}

constexpr const char* kAttemptColumns =
    "a.content_hash, a.trainee_id, a.scenario, a.scenario_hash, a.recording, a.started, a.ended, a.duration_s, "
    "a.verdict, a.proficient, a.banded, a.passed, a.build, a.scored_by, a.imported";

Attempt attempt_from(const Row& r) {
  Attempt a;
  a.content_hash = as_text(r[0]);
  a.trainee_id = as_text(r[1]);
  a.scenario = as_text(r[2]);
  a.scenario_hash = as_text(r[3]);
  a.recording = as_text(r[4]);
  a.started = as_text(r[5]);
  a.ended = as_text(r[6]);
  a.duration_s = as_double(r[7]);
  a.verdict = as_text(r[8]);
  a.proficient = as_int(r[9]) != 0;
  a.banded = as_int(r[10]);
  a.passed = as_int(r[11]);
  a.build = as_text(r[12]);
  a.scored_by = as_text(r[13]);
  a.imported = as_text(r[14]);
  return a;
}

// The join and WHERE of a query on attempts `a` that `f` filters, and its parameters.
std::string attempts_where(const AttemptFilter& f, std::vector<Value>& params) {
  std::string s = " LEFT JOIN trainees t ON t.id = a.trainee_id WHERE 1 = 1";
  if (f.trainee) {
    s += " AND a.trainee_id = ?";
    params.emplace_back(*f.trainee);
  }
  if (f.cohort) {
    s += " AND t.cohort = ?";
    params.emplace_back(*f.cohort);
  }
  return s;
}

}  // namespace

std::string default_database_path() {
  if (const char* xdg = std::getenv("XDG_DATA_HOME"); xdg != nullptr && *xdg != '\0') return std::string(xdg) + "/lancet/records.db";
  const char* home = std::getenv("HOME");
  return std::string(home != nullptr ? home : ".") + "/.local/share/lancet/records.db";
}

Result<std::unique_ptr<Store>> Store::open(const std::string& db) {
  const bool pg = db.rfind("postgresql://", 0) == 0 || db.rfind("postgres://", 0) == 0;
  auto c = pg ? sql::open_postgresql(db) : sql::open_sqlite(db);
  if (!c.ok()) return c.error();
  return open(std::move(c.value()));
}

Result<std::unique_ptr<Store>> Store::open(std::unique_ptr<sql::Connection> connection) {
  auto s = std::make_unique<Store>(std::move(connection));
  if (auto m = s->migrate(); !m.ok()) return m.error();
  return s;
}

Result<void> Store::migrate() {
  sql::Transaction tx(*c_);
  if (auto r = tx.begin(); !r.ok()) return r;
  if (auto r = c_->execute("CREATE TABLE IF NOT EXISTS schema_migrations (version BIGINT PRIMARY KEY, applied TEXT NOT NULL)"); !r.ok())
    return r.error();
  auto v = schema_version();
  if (!v.ok()) return v.error();
  if (v.value() > kSchemaVersion) {
    return Error{ErrorCode::kMismatch, c_->name() + ": the records' schema is version " + std::to_string(v.value()) +
                                           ", newer than this build's " + std::to_string(kSchemaVersion) +
                                           ": use a newer lancet-records (the database is left as it is)"};
  }
  for (std::int64_t version = v.value() + 1; version <= kSchemaVersion; ++version) {
    for (const std::string_view statement : kMigrations[static_cast<std::size_t>(version - 1)]) {
      if (auto r = c_->execute(std::string(statement)); !r.ok()) return r.error();
    }
    if (auto r = c_->execute("INSERT INTO schema_migrations (version, applied) VALUES (?, ?)", {version, iso_now()}); !r.ok())
      return r.error();
  }
  return tx.commit();
}

Result<std::int64_t> Store::schema_version() {
  auto rows = c_->query("SELECT MAX(version) FROM schema_migrations");
  if (!rows.ok()) return rows.error();
  return rows.value().empty() ? std::int64_t{0} : as_int(rows.value()[0][0]);
}

Result<void> Store::add_trainee(const Trainee& t) {
  sql::Transaction tx(*c_);
  if (auto r = tx.begin(); !r.ok()) return r;
  auto n = c_->execute("INSERT INTO trainees (id, name, cohort) VALUES (?, ?, ?) ON CONFLICT (id) DO NOTHING", {t.id, t.name, t.cohort});
  if (!n.ok()) return n.error();
  if (n.value() == 0) return Error{ErrorCode::kInUse, c_->name() + ": trainee \"" + t.id + "\" already exists"};
  return tx.commit();
}

Result<std::optional<Trainee>> Store::find_trainee(const std::string& id) {
  auto rows = c_->query("SELECT id, name, cohort FROM trainees WHERE id = ?", {id});
  if (!rows.ok()) return rows.error();
  if (rows.value().empty()) return std::optional<Trainee>{};
  const Row& r = rows.value()[0];
  return std::optional<Trainee>(Trainee{as_text(r[0]), as_text(r[1]), as_text(r[2])});
}

Result<std::vector<Trainee>> Store::trainees() {
  auto rows = c_->query("SELECT id, name, cohort FROM trainees ORDER BY id");
  if (!rows.ok()) return rows.error();
  std::vector<Trainee> out;
  for (const Row& r : rows.value()) out.push_back(Trainee{as_text(r[0]), as_text(r[1]), as_text(r[2])});
  return out;
}

Result<void> Store::set_curriculum(const Curriculum& c) {
  sql::Transaction tx(*c_);
  if (auto r = tx.begin(); !r.ok()) return r;
  if (auto r = c_->execute("DELETE FROM curriculum"); !r.ok()) return r.error();
  for (std::size_t i = 0; i < c.steps.size(); ++i) {
    const CurriculumStep& s = c.steps[i];
    auto r = c_->execute("INSERT INTO curriculum (step, name, scenario, scenario_hash, required, consecutive) VALUES (?, ?, ?, ?, ?, ?)",
                         {static_cast<std::int64_t>(i + 1), c.name, s.scenario, s.scenario_hash, s.required, s.consecutive});
    if (!r.ok()) return r.error();
  }
  return tx.commit();
}

Result<Curriculum> Store::curriculum() {
  auto rows = c_->query("SELECT name, scenario, scenario_hash, required, consecutive FROM curriculum ORDER BY step");
  if (!rows.ok()) return rows.error();
  Curriculum c;
  for (const Row& r : rows.value()) {
    c.name = as_text(r[0]);
    c.steps.push_back(CurriculumStep{as_text(r[1]), as_text(r[2]), as_int(r[3]), as_int(r[4])});
  }
  return c;
}

Result<bool> Store::add_attempt(const Attempt& a) {
  sql::Transaction tx(*c_);
  if (auto r = tx.begin(); !r.ok()) return r.error();
  if (!a.trainee_id.empty()) {
    auto t = c_->query("SELECT 1 FROM trainees WHERE id = ?", {a.trainee_id});
    if (!t.ok()) return t.error();
    if (t.value().empty())
      return Error{ErrorCode::kNotFound, c_->name() + ": trainee \"" + a.trainee_id + "\" does not exist (add it: lancet-records trainee add " +
                                             a.trainee_id + " --name NAME)"};
  }
  auto n = c_->execute(
      "INSERT INTO attempts (content_hash, trainee_id, scenario, scenario_hash, recording, started, ended, duration_s, verdict, "
      "proficient, banded, passed, build, scored_by, imported) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (content_hash) DO NOTHING",
      {a.content_hash, text_or_null(a.trainee_id), a.scenario, a.scenario_hash, a.recording, a.started, a.ended, sql::number_or_null(a.duration_s),
       a.verdict, std::int64_t{a.proficient}, a.banded, a.passed, a.build, a.scored_by, iso_now()});
  if (!n.ok()) return n.error();
  if (n.value() == 0) return false;  // stored before; the transaction ends with nothing written
  // Every metric in one statement: one round trip to a server however many there are.
  if (!a.metrics.empty()) {
    std::string statement =
        "INSERT INTO attempt_metrics (content_hash, ordinal, name, value, unit, better, band_mean, band_sd, band_k, band_limit, pass, hand) VALUES ";
    std::vector<Value> params;
    params.reserve(12 * a.metrics.size());
    for (std::size_t i = 0; i < a.metrics.size(); ++i) {
      const AttemptMetric& m = a.metrics[i];
      const auto band = [&](double v) { return m.has_band ? sql::number_or_null(v) : Value{}; };
      statement += i == 0 ? "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)" : ", (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)";
      for (Value& v : std::vector<Value>{a.content_hash, static_cast<std::int64_t>(i), m.name, sql::number_or_null(m.value), m.unit, m.better,
                                         band(m.band_mean), band(m.band_sd), band(m.band_k), band(m.band_limit), std::int64_t{m.pass}, m.hand})
        params.push_back(std::move(v));
    }
    if (auto r = c_->execute(statement, params); !r.ok()) return r.error();
  }
  if (auto r = tx.commit(); !r.ok()) return r.error();
  return true;
}

Result<std::vector<Attempt>> Store::attempts(const AttemptFilter& filter) {
  std::vector<Value> params;
  auto rows = c_->query(std::string("SELECT ") + kAttemptColumns + " FROM attempts a" + attempts_where(filter, params) + " ORDER BY a.started, a.content_hash", params);
  if (!rows.ok()) return rows.error();
  std::vector<Attempt> out;
  out.reserve(rows.value().size());
  for (const Row& r : rows.value()) out.push_back(attempt_from(r));
  if (filter.with_metrics) {
    params.clear();
    auto m = c_->query("SELECT m.content_hash, m.name, m.value, m.unit, m.better, m.band_mean, m.band_sd, m.band_k, m.band_limit, m.pass, m.hand "
                       "FROM attempt_metrics m JOIN attempts a ON a.content_hash = m.content_hash" +
                           attempts_where(filter, params) + " ORDER BY m.content_hash, m.ordinal",
                       params);
    if (!m.ok()) return m.error();
    std::map<std::string, std::vector<AttemptMetric>> by_attempt;
    for (const Row& r : m.value()) {
      AttemptMetric x{as_text(r[1]), as_double(r[2]), as_text(r[3]), as_text(r[4]), !sql::is_null(r[8]),
                      as_double(r[5]), as_double(r[6]), as_double(r[7]), as_double(r[8]), as_int(r[9]) != 0, as_text(r[10])};
      by_attempt[as_text(r[0])].push_back(std::move(x));
    }
    for (Attempt& a : out) a.metrics = std::move(by_attempt[a.content_hash]);
  }
  return out;
}

}  // namespace lancet::records
