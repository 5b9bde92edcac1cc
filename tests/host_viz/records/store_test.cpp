// The records' store, the same tests on both back ends (SQLite in a temporary file, PostgreSQL on
// a server this test starts): the schema and its version, trainees, the curriculum, attempts
// stored once by content hash, one transaction per attempt, a newer schema refused.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "records/store.hpp"
#include "test_database.hpp"

namespace lancet::records::test {
namespace {

Attempt make_attempt(const std::string& hash, const std::string& trainee, const std::string& scenario, const std::string& started, bool proficient) {
  Attempt a;
  a.content_hash = hash;
  a.trainee_id = trainee;
  a.scenario = scenario;
  a.scenario_hash = "s-" + scenario;
  a.recording = "/data/" + hash + ".h5";
  a.started = started;
  a.ended = started;
  a.duration_s = 12.5;
  a.verdict = proficient ? "proficient" : "not_yet";
  a.proficient = proficient;
  a.banded = 2;
  a.passed = proficient ? 2 : 1;
  a.build = "0.1.0-test";
  a.scored_by = "0.1.0-scorer";
  a.metrics.push_back(AttemptMetric{"task_time_s", 12.25, "s", "lower", true, 30, 10, 2, 50, true, "both"});
  a.metrics.push_back(AttemptMetric{"path_length_mm", 0.1, "mm", "lower", true, 100, 20, 2, 140, proficient, "right"});
  a.metrics.push_back(AttemptMetric{"jerk", std::numeric_limits<double>::quiet_NaN(), "m/s³", "lower", false, 0, 0, 0, 0, false, "right"});
  return a;
}

class StoreTest : public BackendTest {
 protected:
  std::unique_ptr<Store> open() {
    auto s = Store::open(db_);
    EXPECT_TRUE(s.ok()) << s.error().message;
    return s.ok() ? std::move(s.value()) : nullptr;
  }
};

TEST_P(StoreTest, NewDatabaseHasTheCurrentSchemaAndReopens) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  EXPECT_EQ(s->schema_version().value(), kSchemaVersion);
  EXPECT_STREQ(s->kind(), GetParam() == Backend::kSqlite ? "sqlite" : "postgresql");
  s.reset();
  auto again = open();  // migrations are not applied twice
  ASSERT_NE(again, nullptr);
  EXPECT_EQ(again->schema_version().value(), kSchemaVersion);
}

TEST_P(StoreTest, NewerSchemaIsRefusedAndLeftAsItIs) {
  {
    auto c = GetParam() == Backend::kSqlite ? sql::open_sqlite(db_) : sql::open_postgresql(db_);
    ASSERT_TRUE(c.ok());
    auto s = Store::open(std::move(c.value()));
    ASSERT_TRUE(s.ok());
  }
  {
    auto c = GetParam() == Backend::kSqlite ? sql::open_sqlite(db_) : sql::open_postgresql(db_);
    ASSERT_TRUE(c.ok());
    ASSERT_TRUE(c.value()->execute("INSERT INTO schema_migrations (version, applied) VALUES (?, ?)", {kSchemaVersion + 1, "2030-01-01T00:00:00Z"}).ok());
  }
  auto s = Store::open(db_);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kMismatch);
  const std::string& m = s.error().message;
  EXPECT_NE(m.find("schema is version " + std::to_string(kSchemaVersion + 1)), std::string::npos) << m;
  EXPECT_NE(m.find("this build's " + std::to_string(kSchemaVersion)), std::string::npos) << m;
  auto c = GetParam() == Backend::kSqlite ? sql::open_sqlite(db_) : sql::open_postgresql(db_);
  ASSERT_TRUE(c.ok());
  auto rows = c.value()->query("SELECT COUNT(*), MAX(version) FROM schema_migrations");
  ASSERT_TRUE(rows.ok());
  EXPECT_EQ(sql::as_int(rows.value()[0][0]), kSchemaVersion + 1);
  EXPECT_EQ(sql::as_int(rows.value()[0][1]), kSchemaVersion + 1);
}

TEST_P(StoreTest, TraineesAreAddedOnceAndListedById) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->add_trainee({"t2", "Bea Two", "2026a"}).ok());
  ASSERT_TRUE(s->add_trainee({"t1", "Al One", ""}).ok());
  auto dup = s->add_trainee({"t1", "Someone else", "x"});
  ASSERT_FALSE(dup.ok());
  EXPECT_EQ(dup.error().code, ErrorCode::kInUse);
  EXPECT_NE(dup.error().message.find("\"t1\""), std::string::npos);
  auto all = s->trainees();
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all.value().size(), 2u);
  EXPECT_EQ(all.value()[0].id, "t1");
  EXPECT_EQ(all.value()[0].name, "Al One");
  EXPECT_EQ(all.value()[1].cohort, "2026a");
  EXPECT_FALSE(s->find_trainee("nobody").value().has_value());
}

TEST_P(StoreTest, CurriculumIsReplacedWhole) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  EXPECT_TRUE(s->curriculum().value().steps.empty());
  ASSERT_TRUE(s->set_curriculum({"first", {{"a", "ha", 3, 2}, {"b", "hb", 1, 1}, {"c", "hc", 2, 2}}}).ok());
  ASSERT_TRUE(s->set_curriculum({"second", {{"b", "hb2", 4, 1}, {"a", "ha", 2, 2}}}).ok());
  const Curriculum c = s->curriculum().value();
  EXPECT_EQ(c.name, "second");
  ASSERT_EQ(c.steps.size(), 2u);
  EXPECT_EQ(c.steps[0].scenario, "b");
  EXPECT_EQ(c.steps[0].scenario_hash, "hb2");
  EXPECT_EQ(c.steps[0].required, 4);
  EXPECT_EQ(c.steps[0].consecutive, 1);
  EXPECT_EQ(c.steps[1].scenario, "a");
}

TEST_P(StoreTest, AttemptRoundTripsWithItsMetrics) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->add_trainee({"t1", "Al One", "c1"}).ok());
  const Attempt in = make_attempt("h1", "t1", "skin-incision", "2026-11-27T01:00:00Z", true);
  auto added = s->add_attempt(in);
  ASSERT_TRUE(added.ok()) << added.error().message;
  EXPECT_TRUE(added.value());
  const auto out = s->attempts().value();
  ASSERT_EQ(out.size(), 1u);
  const Attempt& a = out[0];
  EXPECT_EQ(a.content_hash, "h1");
  EXPECT_EQ(a.trainee_id, "t1");
  EXPECT_EQ(a.scenario_hash, "s-skin-incision");
  EXPECT_EQ(a.recording, in.recording);
  EXPECT_DOUBLE_EQ(a.duration_s, 12.5);
  EXPECT_TRUE(a.proficient);
  EXPECT_EQ(a.passed, 2);
  EXPECT_EQ(a.build, "0.1.0-test");
  EXPECT_EQ(a.scored_by, "0.1.0-scorer");
  EXPECT_FALSE(a.imported.empty());
  ASSERT_EQ(a.metrics.size(), 3u);  // in the order given
  EXPECT_EQ(a.metrics[0].name, "task_time_s");
  EXPECT_EQ(a.metrics[0].value, 12.25);
  EXPECT_EQ(a.metrics[1].value, 0.1);  // exactly: both back ends keep every bit of a double
  EXPECT_TRUE(a.metrics[1].has_band);
  EXPECT_EQ(a.metrics[1].band_limit, 140);
  EXPECT_EQ(a.metrics[1].hand, "right");
  EXPECT_TRUE(std::isnan(a.metrics[2].value));  // unmeasured: NULL
  EXPECT_FALSE(a.metrics[2].has_band);
  EXPECT_EQ(a.metrics[2].unit, "m/s³");
}

TEST_P(StoreTest, SameContentHashIsStoredOnce) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->add_attempt(make_attempt("h1", "", "a", "2026-11-27T01:00:00Z", false)).value());
  Attempt again = make_attempt("h1", "", "a", "2026-11-27T01:00:00Z", true);
  again.recording = "/elsewhere/copy.h5";
  auto r = s->add_attempt(again);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r.value());
  const auto out = s->attempts().value();
  ASSERT_EQ(out.size(), 1u);
  EXPECT_FALSE(out[0].proficient);  // the first one stays
  EXPECT_EQ(out[0].metrics.size(), 3u);
}

TEST_P(StoreTest, UnknownTraineeIsAnErrorAndStoresNothing) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  auto r = s->add_attempt(make_attempt("h1", "ghost", "a", "2026-11-27T01:00:00Z", true));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_NE(r.error().message.find("trainee \"ghost\" does not exist"), std::string::npos) << r.error().message;
  EXPECT_TRUE(s->attempts().value().empty());
}

TEST_P(StoreTest, AttemptFailingPartWayLeavesNothingBehind) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  Attempt a = make_attempt("h1", "", "a", "2026-11-27T01:00:00Z", true);
  a.metrics.push_back(a.metrics[0]);  // the same metric twice: its second row breaks the key
  auto r = s->add_attempt(a);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(s->attempts().value().empty());
  // The connection is usable after the rollback, and the same attempt done right is stored.
  a.metrics.pop_back();
  EXPECT_TRUE(s->add_attempt(a).value());
  EXPECT_EQ(s->attempts().value().at(0).metrics.size(), 3u);
}

TEST_P(StoreTest, AttemptsComeInTheOrderMadeAndFilter) {
  auto s = open();
  ASSERT_NE(s, nullptr);
  ASSERT_TRUE(s->add_trainee({"t1", "Al", "c1"}).ok());
  ASSERT_TRUE(s->add_trainee({"t2", "Bea", "c2"}).ok());
  ASSERT_TRUE(s->add_attempt(make_attempt("hc", "t1", "a", "2026-11-27T03:00:00Z", true)).value());
  ASSERT_TRUE(s->add_attempt(make_attempt("ha", "t1", "a", "2026-11-27T01:00:00Z", false)).value());
  ASSERT_TRUE(s->add_attempt(make_attempt("hb", "t2", "a", "2026-11-27T02:00:00Z", true)).value());
  ASSERT_TRUE(s->add_attempt(make_attempt("hd", "", "a", "2026-11-27T00:00:00Z", true)).value());
  const auto all = s->attempts().value();
  ASSERT_EQ(all.size(), 4u);
  EXPECT_EQ(all[0].content_hash, "hd");
  EXPECT_EQ(all[3].content_hash, "hc");
  const auto t1 = s->attempts(AttemptFilter{"t1", std::nullopt, false}).value();
  ASSERT_EQ(t1.size(), 2u);
  EXPECT_EQ(t1[0].content_hash, "ha");
  EXPECT_TRUE(t1[0].metrics.empty());  // not asked for
  const auto c2 = s->attempts(AttemptFilter{std::nullopt, "c2", true}).value();
  ASSERT_EQ(c2.size(), 1u);
  EXPECT_EQ(c2[0].content_hash, "hb");
  EXPECT_EQ(c2[0].metrics.size(), 3u);
}

INSTANTIATE_TEST_SUITE_P(Backends, StoreTest, ::testing::Values(Backend::kSqlite, Backend::kPostgres), backend_name);

TEST(StoreOpen, DatabaseThatCannotBeOpenedIsNamed) {
  auto pg = Store::open("postgresql://nobody@/nodb?host=/nonexistent-lancet-dir");
  ASSERT_FALSE(pg.ok());
  EXPECT_NE(pg.error().message.find("postgresql://nobody@/nodb"), std::string::npos) << pg.error().message;
  auto lite = Store::open("/proc/lancet-cannot-be-here/records.db");
  ASSERT_FALSE(lite.ok());
  EXPECT_NE(lite.error().message.find("/proc/lancet-cannot-be-here"), std::string::npos) << lite.error().message;
}

}  // namespace
}  // namespace lancet::records::test
