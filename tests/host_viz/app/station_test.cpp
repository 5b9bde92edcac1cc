// lancet-viz --trainee's station (app/station.hpp) on an SQLite file: an unknown trainee refused at
// the start; an attempt recorded into the outbox stored by the delivery thread and the standing
// shown; with the records unreachable, a --record file kept where it is, its attempt waiting and
// the panel saying so.

#include "app/station.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <string>

#include "attempt_recording.hpp"  // tests/host_viz/records
#include "records/curriculum.hpp"
#include "records/outbox.hpp"
#include "records/store.hpp"
#include "temp_files.hpp"

namespace lancet::viz {
namespace {

namespace fs = std::filesystem;

class StationTest : public lancet::test::TempDirTest {
 protected:
  void SetUp() override {
    TempDirTest::SetUp();
    db_ = (dir_ / "records.db").string();
    auto s = records::Store::open(db_);
    ASSERT_TRUE(s.ok()) << s.error().message;
    ASSERT_TRUE(s.value()->add_trainee(records::Trainee{"t1", "Ada", ""}).ok());
    auto c = records::load_curriculum(std::string(LANCET_SOURCE_DIR) + "/docs/examples/curriculum.toml");
    ASSERT_TRUE(c.ok()) << c.error().message;
    ASSERT_TRUE(s.value()->set_curriculum(c.value()).ok());
  }

  StationOptions options(const std::string& trainee, const std::string& db) const {
    return {trainee, db, (dir_ / "outbox").string(), "test"};
  }
  static bool has_line(const Station& s, const std::string& text) {
    const auto lines = s.panel_lines();
    return std::any_of(lines.begin(), lines.end(), [&](const auto& l) { return l.first.find(text) != std::string::npos; });
  }

  std::string db_;
};

// finish() waits for the deliveries asked for; this bound only catches a hang.
constexpr std::chrono::minutes kHang{2};

TEST_F(StationTest, RefusesATraineeTheRecordsDoNotHave) {
  auto s = Station::start(options("nobody", db_));
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kNotFound);
  EXPECT_NE(s.error().message.find("\"nobody\" does not exist"), std::string::npos) << s.error().message;
}

TEST_F(StationTest, StoresAnAttemptRecordedIntoTheOutboxAndShowsTheStanding) {
  auto s = Station::start(options("t1", db_));
  ASSERT_TRUE(s.ok()) << s.error().message;
  Station& station = *s.value();
  const std::string path = station.recording_path();
  EXPECT_NE(path, station.recording_path());  // each its own name
  EXPECT_TRUE(station.records_into_outbox(path));
  records::test::write_attempt_recording(path, 1);
  station.attempt_recorded(path);
  station.finish(kHang);
  EXPECT_FALSE(fs::exists(path));  // moved into an entry, delivered, removed
  EXPECT_TRUE(records::Outbox((dir_ / "outbox").string()).waiting().empty());
  auto store = records::Store::open(db_);
  ASSERT_TRUE(store.ok());
  EXPECT_EQ(store.value()->attempts(records::AttemptFilter{std::string("t1"), std::nullopt, false}).value().size(), 1u);
  EXPECT_TRUE(has_line(station, "1 attempts stored"));
  EXPECT_TRUE(has_line(station, "step 1 of 3: skin-incision"));
  EXPECT_TRUE(has_line(station, "next scenario: skin-incision"));
}

TEST_F(StationTest, KeepsTheAttemptWhileTheRecordsCannotBeReached) {
  const std::string nowhere = "postgresql://lancet@/postgres?host=" + (dir_ / "no-server").string();
  auto s = Station::start(options("t1", nowhere));
  ASSERT_TRUE(s.ok()) << s.error().message;  // said on stderr; on we go
  Station& station = *s.value();
  const std::string mine = (dir_ / "mine.h5").string();  // as --record FILE
  EXPECT_FALSE(station.records_into_outbox(mine));
  records::test::write_attempt_recording(mine, 2);
  station.attempt_recorded(mine);
  station.finish(kHang);
  EXPECT_TRUE(fs::exists(mine));
  EXPECT_EQ(records::Outbox((dir_ / "outbox").string()).waiting().size(), 1u);
  EXPECT_TRUE(has_line(station, "records unreachable: 1 attempt waiting"));
  // The records back: the next station's start delivers it.
  auto next = Station::start(options("t1", db_));
  ASSERT_TRUE(next.ok());
  next.value()->finish(kHang);
  EXPECT_TRUE(records::Outbox((dir_ / "outbox").string()).waiting().empty());
  EXPECT_TRUE(has_line(*next.value(), "1 attempts stored"));
}

}  // namespace
}  // namespace lancet::viz
