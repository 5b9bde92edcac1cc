// A station's outbox (records/outbox.hpp) on an SQLite file: entries added whole (copied or
// moved), delivered once by content hash, left waiting while the database cannot be reached, and
// the ones that can never be stored moved aside once with why.

#include "records/outbox.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "attempt_recording.hpp"
#include "process.hpp"
#include "temp_files.hpp"

namespace lancet::records {
namespace {

namespace fs = std::filesystem;

class OutboxTest : public lancet::test::TempDirTest {
 protected:
  void SetUp() override {
    TempDirTest::SetUp();
    db_ = (dir_ / "records.db").string();
    auto s = Store::open(db_);
    ASSERT_TRUE(s.ok()) << s.error().message;
    ASSERT_TRUE(s.value()->add_trainee(Trainee{"t1", "Ada", ""}).ok());
  }

  // A recording of skin-incision whose content `n` makes differ.
  std::string recording(int n) {
    const std::string path = (dir_ / ("attempt" + std::to_string(n) + ".h5")).string();
    test::write_attempt_recording(path, n);
    return path;
  }

  std::size_t stored() {
    auto s = Store::open(db_);
    return s.ok() ? s.value()->attempts(AttemptFilter{std::nullopt, std::nullopt, false}).value().size() : 0;
  }

  std::string outbox_dir() const { return (dir_ / "outbox").string(); }
  std::string db_;
};

TEST_F(OutboxTest, CopiesOrMovesAWholeEntryIn) {
  Outbox box(outbox_dir());
  const std::string kept = recording(1), moved = recording(2);
  auto a = box.add(kept, "t1", false);
  ASSERT_TRUE(a.ok()) << a.error().message;
  auto b = box.add(moved, "t1", true);
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_TRUE(fs::exists(kept));
  EXPECT_FALSE(fs::exists(moved));
  EXPECT_EQ(box.waiting().size(), 2u);
  EXPECT_TRUE(fs::exists(fs::path(a.value()) / "recording.h5"));
  EXPECT_NE(lancet::test::read_file(a.value() + "/entry").find("trainee=t1\n"), std::string::npos);
  // Nothing half-built is left beside the entries.
  for (const auto& e : fs::directory_iterator(outbox_dir())) EXPECT_NE(e.path().filename().string().rfind(".new-", 0), 0u);
  // A recording that is not there: an error naming it, no entry.
  auto missing = box.add((dir_ / "nope.h5").string(), "t1", false);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("nope.h5"), std::string::npos);
  EXPECT_EQ(box.waiting().size(), 2u);
}

TEST_F(OutboxTest, DeliversEachAttemptOnceAndEmpties) {
  Outbox box(outbox_dir());
  const std::string r1 = recording(1);
  ASSERT_TRUE(box.add(r1, "t1", false).ok());
  ASSERT_TRUE(box.add(recording(2), "", false).ok());
  const Delivery d = box.deliver(db_, "test");
  EXPECT_EQ(d.stored, 2u);
  EXPECT_EQ(d.waiting, 0u);
  EXPECT_TRUE(d.rejected.empty());
  EXPECT_TRUE(d.error.empty()) << d.error;
  EXPECT_TRUE(box.waiting().empty());
  EXPECT_EQ(stored(), 2u);
  // The stored attempt names the recording where it was made, and whose it is.
  auto s = Store::open(db_);
  auto mine = s.value()->attempts(AttemptFilter{std::string("t1"), std::nullopt, false});
  ASSERT_EQ(mine.value().size(), 1u);
  EXPECT_EQ(mine.value()[0].recording, fs::absolute(r1).string());
  EXPECT_EQ(mine.value()[0].scored_by, "test");

  // The same recording again (a crash between storing and removing): removed, nothing new.
  ASSERT_TRUE(box.add(r1, "t1", false).ok());
  const Delivery again = box.deliver(db_, "test");
  EXPECT_EQ(again.stored, 0u);
  EXPECT_EQ(again.already_stored, 1u);
  EXPECT_TRUE(box.waiting().empty());
  EXPECT_EQ(stored(), 2u);
  // Nothing waiting: nothing done.
  const Delivery none = box.deliver(db_, "test");
  EXPECT_EQ(none.stored + none.already_stored + none.waiting, 0u);
}

TEST_F(OutboxTest, WaitsWhileTheDatabaseCannotBeReached) {
  Outbox box(outbox_dir());
  ASSERT_TRUE(box.add(recording(1), "t1", false).ok());
  // A PostgreSQL URL whose socket folder has no server.
  const std::string nowhere = "postgresql://lancet@/postgres?host=" + (dir_ / "no-server").string();
  const Delivery d = box.deliver(nowhere, "test");
  EXPECT_EQ(d.stored, 0u);
  EXPECT_EQ(d.waiting, 1u);
  EXPECT_FALSE(d.error.empty());
  EXPECT_EQ(box.waiting().size(), 1u);
  // Once it can be reached, delivered.
  EXPECT_EQ(box.deliver(db_, "test").stored, 1u);
  EXPECT_TRUE(box.waiting().empty());
}

TEST_F(OutboxTest, MovesWhatCanNeverBeStoredAsideOnce) {
  Outbox box(outbox_dir());
  const std::string junk = write("junk.h5", "not an HDF5 file");
  ASSERT_TRUE(box.add(junk, "t1", false).ok());
  ASSERT_TRUE(box.add(recording(1), "nobody", false).ok());
  ASSERT_TRUE(box.add(recording(2), "t1", false).ok());
  const Delivery d = box.deliver(db_, "test");
  EXPECT_EQ(d.stored, 1u);
  EXPECT_EQ(d.waiting, 0u);
  ASSERT_EQ(d.rejected.size(), 2u);
  EXPECT_NE(d.rejected[0].find("recording.h5"), std::string::npos) << d.rejected[0];
  EXPECT_NE(d.rejected[1].find("nobody"), std::string::npos) << d.rejected[1];
  EXPECT_TRUE(box.waiting().empty());
  // Aside, each with its reason; never tried again.
  std::size_t aside = 0;
  for (const auto& e : fs::directory_iterator(fs::path(outbox_dir()) / ".rejected")) {
    EXPECT_TRUE(fs::exists(e.path() / "reason"));
    EXPECT_TRUE(fs::exists(e.path() / "recording.h5"));
    ++aside;
  }
  EXPECT_EQ(aside, 2u);
  const Delivery again = box.deliver(db_, "test");
  EXPECT_TRUE(again.rejected.empty());
  EXPECT_EQ(stored(), 1u);
}

TEST(OutboxPath, BesideAnSqliteFileElseInTheUsersData) {
  EXPECT_EQ(default_outbox_path("/var/lib/lancet/records.db"), "/var/lib/lancet/outbox");
  const std::string pg = default_outbox_path("postgresql://lab@server/records");
  EXPECT_NE(pg.find("lancet/outbox"), std::string::npos) << pg;
}

}  // namespace
}  // namespace lancet::records
