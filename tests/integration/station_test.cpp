// A training station end to end: lancet-viz --trainee with the real lancet-rt (a scripted hand) and
// a PostgreSQL server this test starts (tests/support/postgres_server.hpp). A session's attempt is
// stored; with the server stopped, the next session's attempt waits in the outbox and the viz
// still exits cleanly; with the server back, the attempt is delivered exactly once (by the next
// lancet-viz start or lancet-records deliver) and delivering again stores nothing new. Under
// CI=true the test fails when the server cannot start; elsewhere it is skipped.
#include <gtest/gtest.h>

#include <csignal>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "postgres_server.hpp"  // tests/support
#include "process_test.hpp"     // tests/support
#include "recording/hdf5_io.hpp"
#include "records/outbox.hpp"
#include "records/sql.hpp"
#include "records/store.hpp"
#include "wait.hpp"  // tests/support

namespace lancet {
namespace {

using namespace std::chrono_literals;
using test::Child;
using test::read_file;

const std::string kRt = std::string(LANCET_BINARY_DIR) + "/firmware_rt/lancet-rt";
const std::string kViz = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-viz";
const std::string kRecords = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-records";
const std::string kSrc = LANCET_SOURCE_DIR;

class Station : public test::ProcessTest {
 public:
  Station() : ProcessTest("sta") {}
  void SetUp() override {
    unsetenv("DISPLAY");  // headless through EGL
    ProcessTest::SetUp();
    test::PostgresServer& server = test::postgres_server();
    if (!server.running()) {
      if (test::ci()) FAIL() << "CI=true and the PostgreSQL test server did not start: " << server.error();
      GTEST_SKIP() << "PostgreSQL tests skipped: " << server.error();
    }
    static int n = 0;
    const std::string name = "station_" + std::to_string(getpid()) + "_" + std::to_string(++n);
    {
      auto admin = records::sql::open_postgresql(server.url());
      ASSERT_TRUE(admin.ok()) << admin.error().message;
      auto created = admin.value()->execute("CREATE DATABASE " + name);
      ASSERT_TRUE(created.ok()) << created.error().message;
    }
    db_ = server.url(name);
    outbox_ = path("outbox");
    ASSERT_EQ(records_cli({"trainee", "add", "t1", "--name", "Ada"}, "add.log"), 0) << read_file(path("add.log"));
    ASSERT_EQ(records_cli({"curriculum", "load", kSrc + "/docs/examples/curriculum.toml"}, "curriculum.log"), 0)
        << read_file(path("curriculum.log"));
  }

  /// lancet-records --db <db> args...: its exit status (output in `log`).
  int records_cli(const std::vector<std::string>& args, const std::string& log) {
    std::vector<std::string> argv{kRecords, "--db", db_};
    argv.insert(argv.end(), args.begin(), args.end());
    Child c(argv, path(log));
    const auto st = c.wait_exit(180s);
    return st && WIFEXITED(*st) ? WEXITSTATUS(*st) : -1;
  }

  std::vector<std::string> viz_argv(const std::string& trainee) const {
    return {kViz, "--headless", "--shm", shm_, "--width", "320", "--height", "200", "--scenario",
            kSrc + "/host_viz/scenarios/skin_incision.toml", "--tool", "none", "--trainee", trainee, "--db", db_, "--outbox", outbox_};
  }

  /// Seconds of servo ticks in the recording the viz is writing into the outbox (0: none yet).
  double recorded_s() const {
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(outbox_, ec)) {
      if (e.path().filename().string().rfind(".recording-", 0) != 0) continue;
      auto rec = record::read_recording(e.path().string());
      if (!rec.ok() || rec.value().samples.size() < 2) return 0;
      return static_cast<double>(rec.value().samples.back().t_ns - rec.value().samples.front().t_ns) * 1e-9;
    }
    return 0;
  }

  /// One session: lancet-viz --trainee t1 and lancet-rt's scripted incision until a second of it
  /// is recorded, then the viz is stopped (SIGINT) and must exit 0. Returns the viz's log.
  std::string session(const std::string& log) {
    std::vector<std::string> argv = viz_argv("t1");
    argv.insert(argv.end(), {"--duration", "600"});
    Child viz(argv, path(log), {"LSAN_OPTIONS=detect_leaks=0"});
    EXPECT_TRUE(test::eventually([&] { return read_file(path(log)).find("is lancet-rt running") != std::string::npos; }, 120s))
        << read_file(path(log));
    Child rt({kRt, "--shm", shm_, "-q", "--trajectory", kSrc + "/docs/examples/demo_incision.csv"}, path("rt-" + log));
    EXPECT_TRUE(test::eventually([&] { return recorded_s() >= 1.0; }, 180s, 300ms)) << read_file(path(log));
    viz.signal(SIGINT);
    const auto vs = viz.wait_exit(120s);
    EXPECT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path(log));
    rt.signal(SIGTERM);
    (void)rt.wait_exit(10s);
    return read_file(path(log));
  }

  /// t1's attempts stored.
  std::size_t stored() {
    auto s = records::Store::open(db_);
    EXPECT_TRUE(s.ok()) << s.error().message;
    if (!s.ok()) return 0;
    auto a = s.value()->attempts(records::AttemptFilter{std::string("t1"), std::nullopt, false});
    EXPECT_TRUE(a.ok());
    return a.ok() ? a.value().size() : 0;
  }

  std::size_t waiting() const { return records::Outbox(outbox_).waiting().size(); }

  std::string db_, outbox_;
};

TEST_F(Station, KeepsAttemptsWhileTheServerIsAwayAndDeliversThemOnce) {
  // The server up: the attempt is stored, the outbox left empty, the standing shown.
  const std::string first = session("viz1.log");
  EXPECT_NE(first.find("records: 1 attempts stored"), std::string::npos) << first;
  EXPECT_NE(first.find("next scenario: skin-incision"), std::string::npos) << first;
  EXPECT_EQ(stored(), 1u);
  EXPECT_EQ(waiting(), 0u);

  // The server gone: the attempt waits in the outbox; the viz says so and exits as ever.
  ASSERT_TRUE(test::postgres_server().stop());
  const std::string second = session("viz2.log");
  EXPECT_NE(second.find("records unreachable"), std::string::npos) << second;
  EXPECT_NE(second.find("1 attempt wait in " + outbox_), std::string::npos) << second;
  EXPECT_EQ(waiting(), 1u);

  // The server back: the next start (no lancet-rt: nothing recorded) delivers what waits, or
  // lancet-records deliver does; either way it is stored once.
  ASSERT_TRUE(test::postgres_server().start());
  std::vector<std::string> argv = viz_argv("t1");
  argv.insert(argv.end(), {"--duration", "1"});
  Child viz(argv, path("viz3.log"), {"LSAN_OPTIONS=detect_leaks=0"});
  const auto vs = viz.wait_exit(120s);
  EXPECT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 0) << read_file(path("viz3.log"));
  EXPECT_EQ(records_cli({"deliver", "--outbox", outbox_}, "deliver1.log"), 0) << read_file(path("deliver1.log"));
  EXPECT_EQ(stored(), 2u) << read_file(path("viz3.log")) << read_file(path("deliver1.log"));
  EXPECT_EQ(waiting(), 0u);
  // Delivering again: nothing new.
  EXPECT_EQ(records_cli({"deliver", "--outbox", outbox_}, "deliver2.log"), 0) << read_file(path("deliver2.log"));
  EXPECT_NE(read_file(path("deliver2.log")).find("0 attempts stored, 0 stored before, 0 waiting"), std::string::npos)
      << read_file(path("deliver2.log"));
  EXPECT_EQ(stored(), 2u);
}

TEST_F(Station, RefusesATraineeTheRecordsDoNotHave) {
  std::vector<std::string> argv = viz_argv("nobody");
  argv.insert(argv.end(), {"--duration", "1"});
  Child viz(argv, path("viz.log"), {"LSAN_OPTIONS=detect_leaks=0"});
  const auto vs = viz.wait_exit(120s);
  EXPECT_TRUE(vs.has_value() && WIFEXITED(*vs) && WEXITSTATUS(*vs) == 2) << read_file(path("viz.log"));
  EXPECT_NE(read_file(path("viz.log")).find("trainee \"nobody\" does not exist"), std::string::npos) << read_file(path("viz.log"));
}

TEST_F(Station, DeliverWithTheServerAwayKeepsTheOutboxAndSaysSo) {
  // An entry waiting (any file will do: it is never read while the server is away).
  std::filesystem::create_directories(outbox_);
  const std::string junk = path("junk.h5");
  { std::ofstream(junk) << "x"; }
  ASSERT_TRUE(records::Outbox(outbox_).add(junk, "t1", false).ok());
  ASSERT_TRUE(test::postgres_server().stop());
  const int rc = records_cli({"deliver", "--outbox", outbox_}, "deliver.log");
  ASSERT_TRUE(test::postgres_server().start());
  EXPECT_EQ(rc, 2) << read_file(path("deliver.log"));
  EXPECT_NE(read_file(path("deliver.log")).find("attempts still wait in"), std::string::npos) << read_file(path("deliver.log"));
  EXPECT_EQ(waiting(), 1u);
}

}  // namespace
}  // namespace lancet
