// The replay driver can fail: an input that crashes or hangs the target ends the replay with that
// signal and its name printed last, so the ctest entry replaying a corpus would fail. Shown with a
// target that misbehaves on purpose (replay_selftest_target.cpp).

#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <string>

#include "process.hpp"
#include "temp_files.hpp"

namespace {

const std::string kReplay = std::string(LANCET_BINARY_DIR) + "/tests/fuzz/replay_selftest";

class FuzzReplay : public lancet::test::TempDirTest {
 protected:
  // Runs the replay on dir_/corpus (or `target`); returns the wait status.
  int replay(const std::string& target, std::string& out, std::chrono::seconds limit = std::chrono::seconds(60)) {
    const std::string log = (dir_ / "log.txt").string();
    lancet::test::Child child({kReplay, target}, log, {"LANCET_FUZZ_REPLAY_SECONDS=1"});
    const auto st = child.wait_exit(limit);
    out = lancet::test::read_file(log);
    return st.value_or(-1);
  }
  // A fresh corpus folder holding `files` (name, bytes).
  std::string corpus(const std::vector<std::pair<std::string, std::string>>& files) {
    const std::string name = "corpus" + std::to_string(++corpora_);
    std::filesystem::create_directories(dir_ / name);
    for (const auto& [file, bytes] : files) write(name + "/" + file, bytes);
    return (dir_ / name).string();
  }
  int corpora_ = 0;
};

TEST_F(FuzzReplay, GoodCorpusPasses) {
  std::string out;
  const int st = replay(corpus({{"a", "hello"}, {"b", ""}}), out);
  ASSERT_TRUE(WIFEXITED(st)) << out;
  EXPECT_EQ(WEXITSTATUS(st), 0) << out;
  EXPECT_NE(out.find("2 inputs, every one returned"), std::string::npos) << out;
}

TEST_F(FuzzReplay, CrashingInputFailsAndIsNamed) {
  std::string out;
  int st = replay(corpus({{"a_fine", "hello"}, {"b_crash", "abort now"}, {"c_never_reached", "x"}}), out);
  ASSERT_TRUE(WIFSIGNALED(st)) << out;
  EXPECT_EQ(WTERMSIG(st), SIGABRT);
  EXPECT_NE(out.find("b_crash (9 bytes)"), std::string::npos) << out;
  EXPECT_EQ(out.find("c_never_reached"), std::string::npos) << "the replay stops at the crash";

  st = replay(corpus({{"d_segv", "segv"}}), out);
  // A sanitizer build reports the bad store itself and exits non-zero instead of dying by SIGSEGV.
  const bool failed = WIFSIGNALED(st) ? WTERMSIG(st) == SIGSEGV : WIFEXITED(st) && WEXITSTATUS(st) != 0;
  EXPECT_TRUE(failed) << out;
  EXPECT_NE(out.find("d_segv (4 bytes)"), std::string::npos) << out;
}

TEST_F(FuzzReplay, HangingInputIsEndedAndFails) {
  std::string out;
  const int st = replay(corpus({{"hang", "hang"}}), out, std::chrono::seconds(30));
  ASSERT_TRUE(WIFSIGNALED(st)) << out;
  EXPECT_EQ(WTERMSIG(st), SIGALRM);
  EXPECT_NE(out.find("hang (4 bytes)"), std::string::npos) << out;
}

TEST_F(FuzzReplay, EmptyOrMissingCorpusFails) {
  std::string out;
  std::filesystem::create_directories(dir_ / "empty");
  int st = replay((dir_ / "empty").string(), out);
  ASSERT_TRUE(WIFEXITED(st));
  EXPECT_EQ(WEXITSTATUS(st), 1) << out;
  st = replay((dir_ / "no_such_corpus").string(), out);
  ASSERT_TRUE(WIFEXITED(st));
  EXPECT_EQ(WEXITSTATUS(st), 2) << out;
  EXPECT_NE(out.find("not found"), std::string::npos) << out;
}

}  // namespace
