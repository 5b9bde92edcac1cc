// lancet-records end to end, on both back ends: recordings (written with common/recording, of the
// project's skin-incision scenario) imported, scored and stored once; ten import processes at
// once; each bad input a clear error, exit status 2, and nothing half-written.

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "../score/synthetic_recording.hpp"
#include "process.hpp"
#include "recording/hdf5_io.hpp"
#include "records/store.hpp"
#include "records_cli.hpp"
#include "test_database.hpp"

namespace lancet::records::test {
namespace {

const std::string kScenario = std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml";
const std::string kCurriculum = std::string(LANCET_SOURCE_DIR) + "/docs/examples/curriculum.toml";

class RecordsCliTest : public CliTest {
 protected:
  // A recording of skin-incision (or of the scenario text given): a short cut along its line;
  // `n` makes the file's content differ.
  std::string recording(int n, const std::string& scenario_text = lancet::test::read_file(kScenario)) {
    record::Recording r = record::test::make_recording(1500, [n](std::size_t i, double, ToolSample& s) {
      s.stage = i < 200 ? Stage::kFree : Stage::kCutting;
      s.tool.position = Vec3{-0.015 + 2e-5 * static_cast<double>(i), -0.012 + 1e-6 * n, 0};
      s.force = Vec3{0, 0, 0.5 + 0.01 * n};
    });
    record::test::mark_cut_progress(r);
    r.created = "2026-11-27T02:" + std::string(n < 10 ? "0" : "") + std::to_string(n) + ":00Z";
    r.scenario_toml = scenario_text;
    r.scenario_file = kScenario;
    r.scenario_name = "skin-incision";
    const std::string path = dir_ + "/attempt" + std::to_string(n) + ".h5";
    auto w = record::write_recording(path, r);
    EXPECT_TRUE(w.ok()) << w.error().message;
    return path;
  }

  std::unique_ptr<Store> store() {
    auto s = Store::open(db_);
    EXPECT_TRUE(s.ok()) << s.error().message;
    return s.ok() ? std::move(s.value()) : nullptr;
  }
  std::size_t stored_attempts() {
    auto s = store();
    return s ? s->attempts(AttemptFilter{std::nullopt, std::nullopt, false}).value().size() : 0;
  }
};

TEST_P(RecordsCliTest, ImportScoresAndStoresOnceByContentHash) {
  ASSERT_EQ(cli({"trainee", "add", "t1", "--name", "Al One", "--cohort", "2026a"}).status, 0);
  const std::string a = recording(1), b = recording(2);
  const CliRun first = cli({"import", "--trainee", "t1", a, b});
  ASSERT_EQ(first.status, 0) << first.output;
  EXPECT_NE(first.output.find("skin-incision"), std::string::npos) << first.output;
  // The same recording again, under another name: a no-op.
  std::filesystem::copy_file(a, dir_ + "/copy.h5");
  const CliRun again = cli({"import", "--trainee", "t1", a, dir_ + "/copy.h5"});
  ASSERT_EQ(again.status, 0) << again.output;
  EXPECT_NE(again.output.find("already stored"), std::string::npos) << again.output;

  auto s = store();
  ASSERT_NE(s, nullptr);
  const auto attempts = s->attempts().value();
  ASSERT_EQ(attempts.size(), 2u);
  EXPECT_EQ(attempts[0].recording, a);
  EXPECT_EQ(attempts[0].trainee_id, "t1");
  EXPECT_EQ(attempts[0].scenario, "skin-incision");
  EXPECT_EQ(attempts[0].content_hash.size(), 64u);
  EXPECT_EQ(attempts[0].build, "test");  // the recording's
  EXPECT_FALSE(attempts[0].scored_by.empty());  // lancet-records' own
  EXPECT_EQ(attempts[0].started, "2026-11-27T02:01:00Z");
  EXPECT_EQ(attempts[0].ended, "2026-11-27T02:01:02Z");  // 1.5 s, rounded
  EXPECT_FALSE(attempts[0].metrics.empty());
  EXPECT_GT(attempts[0].banded, 0);  // skin-incision has bands
}

TEST_P(RecordsCliTest, TraineesCurriculumProgressAndExport) {
  ASSERT_EQ(cli({"trainee", "add", "t2", "--name", "Bea", "--cohort", "c"}).status, 0);
  ASSERT_EQ(cli({"trainee", "add", "t1", "--name", "Al"}).status, 0);
  const CliRun list = cli({"trainee", "list"});
  ASSERT_EQ(list.status, 0);
  EXPECT_EQ(list.output, "t1\tAl\t\nt2\tBea\tc\n");
  ASSERT_EQ(cli({"curriculum", "load", kCurriculum}).status, 0);
  const CliRun show = cli({"curriculum", "show"});
  ASSERT_EQ(show.status, 0);
  EXPECT_NE(show.output.find("1. skin-incision: proficient on 3 attempts, 2 of them in a row"), std::string::npos) << show.output;
  ASSERT_EQ(cli({"import", "--trainee", "t1", recording(1), recording(2)}).status, 0);
  const CliRun p = cli({"progress", "t1"});
  ASSERT_EQ(p.status, 0) << p.output;
  EXPECT_NE(p.output.find("skin-incision"), std::string::npos) << p.output;
  EXPECT_NE(p.output.find("  2 attempts"), std::string::npos) << p.output;
  EXPECT_NE(p.output.find("next: skin-incision"), std::string::npos) << p.output;  // 3 needed, 2 made
  const std::string csv = dir_ + "/export.csv";
  ASSERT_EQ(cli({"export", "--csv", "-o", csv}).status, 0);
  const std::string text = lancet::test::read_file(csv);
  EXPECT_EQ(text.rfind("trainee,name,cohort,", 0), 0u);
  EXPECT_NE(text.find("t1,Al,,skin-incision,"), std::string::npos);
}

// progress -o PAGE --reports: lancet-report's page for each attempt, beside the page, linked from
// its row; an attempt whose recording is gone gets none (and the page says so), not a failure.
TEST_P(RecordsCliTest, ProgressPageLinksEachAttemptsReport) {
  ASSERT_EQ(cli({"trainee", "add", "t1", "--name", "Al"}).status, 0);
  ASSERT_EQ(cli({"curriculum", "load", kCurriculum}).status, 0);
  const std::string kept = recording(1), gone = recording(2);
  ASSERT_EQ(cli({"import", "--trainee", "t1", kept, gone}).status, 0);
  std::filesystem::remove(gone);
  EXPECT_EQ(cli({"progress", "t1", "--reports"}).status, 2) << "--reports without a page to link them from";
  const std::string page = dir_ + "/t1.html";
  const CliRun run = cli({"progress", "t1", "-o", page, "--reports"});
  ASSERT_EQ(run.status, 0) << run.output;
  EXPECT_NE(run.output.find("attempt 2: no report"), std::string::npos) << run.output;
  const std::string html = lancet::test::read_file(page);
  EXPECT_NE(html.find("<a class=\"report\" href=\"t1-reports/1.html\">report</a>"), std::string::npos) << html;
  EXPECT_NE(html.find("<td class=\"note\">none</td>"), std::string::npos);
  const std::string report = lancet::test::read_file(dir_ + "/t1-reports/1.html");
  EXPECT_NE(report.find("attempt1.h5"), std::string::npos) << "lancet-report's page for that attempt";
  EXPECT_NE(report.find("skin-incision"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(dir_ + "/t1-reports/2.html"));
}

TEST_P(RecordsCliTest, TenConcurrentImportersStoreEveryAttemptOnce) {
  std::vector<std::string> files;
  for (int i = 0; i < 10; ++i) files.push_back(recording(i));
  // Ten processes at once on a database without tables yet (so they race to create the schema
  // too), each importing all ten recordings, starting at a different one.
  std::vector<std::unique_ptr<lancet::test::Child>> children;
  for (int p = 0; p < 10; ++p) {
    std::vector<std::string> argv{kRecords, "--db", db_, "import"};
    for (int i = 0; i < 10; ++i) argv.push_back(files[static_cast<std::size_t>((p + i) % 10)]);
    children.push_back(std::make_unique<lancet::test::Child>(argv, dir_ + "/writer" + std::to_string(p) + ".txt"));
  }
  std::size_t newly_stored = 0;
  for (int p = 0; p < 10; ++p) {
    const auto st = children[static_cast<std::size_t>(p)]->wait_exit(std::chrono::minutes(5));
    const std::string out = lancet::test::read_file(dir_ + "/writer" + std::to_string(p) + ".txt");
    ASSERT_TRUE(st && WIFEXITED(*st) && WEXITSTATUS(*st) == 0) << "writer " << p << ":\n" << out;
    std::istringstream lines(out);
    for (std::string line; std::getline(lines, line);) {
      if (line.find(".h5: skin-incision") != std::string::npos && line.find("already stored") == std::string::npos) ++newly_stored;
    }
  }
  EXPECT_EQ(newly_stored, 10u);  // each attempt stored by exactly one writer
  auto s = store();
  ASSERT_NE(s, nullptr);
  const auto attempts = s->attempts().value();
  ASSERT_EQ(attempts.size(), 10u);
  for (const Attempt& a : attempts) EXPECT_EQ(a.metrics.size(), attempts[0].metrics.size()) << a.recording;
  EXPECT_EQ(s->schema_version().value(), kSchemaVersion);
}

TEST_P(RecordsCliTest, CorruptOrTruncatedRecordingIsNamedAndNothingStored) {
  const std::string good = recording(1);
  const std::string cut = dir_ + "/truncated.h5";
  {
    const std::string bytes = lancet::test::read_file(good);
    std::ofstream(cut, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size() / 2));
  }
  const std::string junk = dir_ + "/junk.h5";
  std::ofstream(junk) << "not a recording\n";
  for (const std::string& bad : {cut, junk, dir_ + "/missing.h5"}) {
    const CliRun r = cli({"import", bad});
    EXPECT_EQ(r.status, 2) << r.output;
    EXPECT_NE(r.output.find(bad), std::string::npos) << r.output;
  }
  EXPECT_EQ(stored_attempts(), 0u);
  // A bad file among good ones: the good ones are stored, the bad one named, exit 2.
  const CliRun mixed = cli({"import", good, cut});
  EXPECT_EQ(mixed.status, 2);
  EXPECT_NE(mixed.output.find(cut), std::string::npos) << mixed.output;
  EXPECT_EQ(stored_attempts(), 1u);
}

TEST_P(RecordsCliTest, RecordingOfAnUnknownScenarioIsNamed) {
  ASSERT_EQ(cli({"curriculum", "load", kCurriculum}).status, 0);
  std::string text = lancet::test::read_file(kScenario);
  const std::size_t at = text.find("name = \"skin-incision\"");
  ASSERT_NE(at, std::string::npos);
  std::string renamed = text;
  renamed.replace(at, std::string("name = \"skin-incision\"").size(), "name = \"appendectomy\"");
  const CliRun r = cli({"import", recording(1, renamed)});
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.output.find("scenario \"appendectomy\" is not in the curriculum \"Lancet basics\""), std::string::npos) << r.output;
  // A scenario this build cannot read at all.
  const CliRun unreadable = cli({"import", recording(2, "schema_version = 99\nname = \"future\"\n")});
  EXPECT_EQ(unreadable.status, 2);
  EXPECT_NE(unreadable.output.find("is unknown to this build"), std::string::npos) << unreadable.output;
  EXPECT_EQ(stored_attempts(), 0u);
}

TEST_P(RecordsCliTest, CurriculumNamingAMissingScenarioChangesNothing) {
  ASSERT_EQ(cli({"curriculum", "load", kCurriculum}).status, 0);
  const std::string bad = dir_ + "/bad.toml";
  std::ofstream(bad) << "schema_version = 1\nname = \"bad\"\n[[step]]\nscenario = \"appendectomy.toml\"\nrequired = 1\n";
  const CliRun r = cli({"curriculum", "load", bad});
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.output.find("appendectomy.toml"), std::string::npos) << r.output;
  auto s = store();
  ASSERT_NE(s, nullptr);
  EXPECT_EQ(s->curriculum().value().name, "Lancet basics");
}

TEST_P(RecordsCliTest, UnknownTraineeIsNamed) {
  const CliRun r = cli({"import", "--trainee", "ghost", recording(1)});
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.output.find("trainee \"ghost\" does not exist"), std::string::npos) << r.output;
  EXPECT_EQ(cli({"progress", "ghost"}).status, 2);
  EXPECT_EQ(stored_attempts(), 0u);
  const CliRun dup = [&] {
    (void)cli({"trainee", "add", "t1", "--name", "Al"});
    return cli({"trainee", "add", "t1", "--name", "Al again"});
  }();
  EXPECT_EQ(dup.status, 2);
  EXPECT_NE(dup.output.find("trainee \"t1\" already exists"), std::string::npos) << dup.output;
}

TEST_P(RecordsCliTest, NewerSchemaIsRefused) {
  ASSERT_EQ(cli({"trainee", "add", "t1", "--name", "Al"}).status, 0);
  {
    auto c = GetParam() == Backend::kSqlite ? sql::open_sqlite(db_) : sql::open_postgresql(db_);
    ASSERT_TRUE(c.ok());
    ASSERT_TRUE(c.value()->execute("INSERT INTO schema_migrations (version, applied) VALUES (?, ?)", {kSchemaVersion + 1, "2030-01-01T00:00:00Z"}).ok());
  }
  const CliRun r = cli({"import", "--trainee", "t1", recording(1)});
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.output.find("newer than this build's"), std::string::npos) << r.output;
  EXPECT_EQ(cli({"trainee", "list"}).status, 2);
}

INSTANTIATE_TEST_SUITE_P(Backends, RecordsCliTest, ::testing::Values(Backend::kSqlite, Backend::kPostgres), backend_name);

}  // namespace
}  // namespace lancet::records::test
