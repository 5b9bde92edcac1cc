#pragma once
// The training records: trainees, the curriculum and every scored attempt, in one database with a
// versioned schema (records/sql.hpp's SQLite file or PostgreSQL server; the same statements for
// both).
//
// The schema (version kSchemaVersion; docs/RECORDS.md has the tables and columns):
//   schema_migrations(version, applied)  one row per migration applied, in order
//   trainees(id, name, cohort)
//   curriculum(position, scenario, scenario_hash, required, consecutive, name)  the ordered steps
//   attempts(content_hash, trainee_id, scenario, scenario_hash, recording, started, ended,
//            duration_s, verdict, proficient, banded, passed, build, scored_by, imported)
//   attempt_metrics(content_hash, name, value, unit, better, band_mean, band_sd, band_k,
//                   band_limit, pass, hand)
// An attempt is keyed by its recording's content hash (SHA-256 of the file): storing the same
// recording again changes nothing. Each attempt is written in one transaction, so an error leaves
// nothing of it behind.
//
// Opening migrates an older schema up to kSchemaVersion (in one transaction that holds the write
// lock, so several stations opening a new database at once apply each migration once) and refuses
// a newer one with an error that names the database and both versions.
//
// Tools only (allocates, blocks on the database). Not thread-safe: one Store per thread.

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "records/sql.hpp"

namespace lancet::records {

/// The schema version this build writes and reads.
inline constexpr std::int64_t kSchemaVersion = 1;

/// Where the records are kept when no --db is given: $XDG_DATA_HOME/lancet/records.db, or
/// ~/.local/share/lancet/records.db.
[[nodiscard]] std::string default_database_path();

struct Trainee {
  std::string id;      ///< chosen by the instructor; unique
  std::string name;
  std::string cohort;  ///< may be empty
};

/// One step of the curriculum: a scenario and when the trainee is proficient at it.
struct CurriculumStep {
  std::string scenario;       ///< the scenario's name (its file's `name`)
  std::string scenario_hash;  ///< SHA-256 (hex) of the scenario file's text when the curriculum was loaded
  std::int64_t required = 1;     ///< proficient attempts needed, >= 1
  std::int64_t consecutive = 1;  ///< of them, in a row, 1..required
};

struct Curriculum {
  std::string name;
  std::vector<CurriculumStep> steps;  ///< in the order the trainee takes them
};

/// One metric of an attempt as score::compute_metrics measured it.
struct AttemptMetric {
  std::string name;   ///< scenario::kScoreMetrics' name
  double value = 0;   ///< in `unit`; NaN: not measured (NULL in the database)
  std::string unit;
  std::string better;  ///< "lower" or "higher"
  bool has_band = false;
  double band_mean = 0, band_sd = 0, band_k = 0, band_limit = 0;  ///< when has_band
  bool pass = false;   ///< within its band (false without one)
  std::string hand;    ///< score::hand_scope_key
};

struct Attempt {
  std::string content_hash;   ///< SHA-256 (hex) of the recording file: the attempt's key
  std::string trainee_id;     ///< "" for a recording made without a trainee
  std::string scenario;       ///< the recorded scenario's name
  std::string scenario_hash;  ///< SHA-256 (hex) of the recorded scenario text
  std::string recording;      ///< the recording's path as imported (informative)
  std::string started;        ///< ISO 8601 UTC, when the recording began
  std::string ended;          ///< ISO 8601 UTC, started plus the recorded duration
  double duration_s = 0;
  std::string verdict;        ///< score::verdict_key
  bool proficient = false;    ///< every banded metric passes
  std::int64_t banded = 0, passed = 0;
  std::string build;          ///< the lancet version that recorded it
  std::string scored_by;      ///< the lancet version that scored it (lancet-records'; "" when not known)
  std::string imported;       ///< ISO 8601 UTC, set by add_attempt
  std::vector<AttemptMetric> metrics;
};

/// Which attempts attempts() returns.
struct AttemptFilter {
  std::optional<std::string> trainee;   ///< only this trainee's
  std::optional<std::string> cohort;    ///< only trainees of this cohort
  bool with_metrics = true;
};

class Store {
 public:
  /// Opens `db`: a "postgresql://" or "postgres://" URL, else an SQLite file (created with its
  /// folders). Migrates an older schema; a newer one is an error (ErrorCode::kMismatch).
  [[nodiscard]] static Result<std::unique_ptr<Store>> open(const std::string& db);
  /// As open, on a connection already made.
  [[nodiscard]] static Result<std::unique_ptr<Store>> open(std::unique_ptr<sql::Connection> connection);

  /// The schema version of the database (kSchemaVersion once opened).
  [[nodiscard]] Result<std::int64_t> schema_version();
  [[nodiscard]] const std::string& name() const noexcept { return c_->name(); }
  [[nodiscard]] const char* kind() const noexcept { return c_->kind(); }

  /// Adds a trainee; an id already there is an error (ErrorCode::kInUse) naming it.
  [[nodiscard]] Result<void> add_trainee(const Trainee& t);
  [[nodiscard]] Result<std::optional<Trainee>> find_trainee(const std::string& id);
  /// Every trainee, by id.
  [[nodiscard]] Result<std::vector<Trainee>> trainees();

  /// Replaces the curriculum with `c` (one transaction).
  [[nodiscard]] Result<void> set_curriculum(const Curriculum& c);
  /// The curriculum; an empty one (no steps) when none was loaded.
  [[nodiscard]] Result<Curriculum> curriculum();

  /// Stores an attempt and its metrics in one transaction. Returns false, changing nothing, when
  /// an attempt with its content hash is already stored. A trainee_id that is not a trainee is an
  /// error (ErrorCode::kNotFound) naming it.
  [[nodiscard]] Result<bool> add_attempt(const Attempt& a);
  /// Attempts in the order they were made (started, then content hash).
  [[nodiscard]] Result<std::vector<Attempt>> attempts(const AttemptFilter& filter = {});

  explicit Store(std::unique_ptr<sql::Connection> c) : c_(std::move(c)) {}

 private:
  Result<void> migrate();
  std::unique_ptr<sql::Connection> c_;
};

}  // namespace lancet::records
