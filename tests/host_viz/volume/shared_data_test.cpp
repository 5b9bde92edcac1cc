// tests/support/shared_data.hpp can fail: with the real volumes missing, a test that needs them is
// skipped on a developer's machine and fails under CI=true. The test runs itself as a child (the
// "probe", selected by LANCET_SHARED_DATA_PROBE) against a folder that does not exist.

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <string>

#include "process.hpp"
#include "shared_data.hpp"

namespace {

constexpr const char* kTest = "SharedData.MissingFolderSkipsLocallyAndFailsUnderCi";

std::string self_exe() {
  char buf[4096];
  const ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
  return n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
}

TEST(SharedData, MissingFolderSkipsLocallyAndFailsUnderCi) {
  if (std::getenv("LANCET_SHARED_DATA_PROBE") != nullptr) {  // the child
    const std::string dir = lancet::test::shared_volumes_dir_at("/nonexistent/lancet/shared/data/volumes");
    if (dir.empty()) return;
    ADD_FAILURE() << "shared_volumes_dir_at returned a folder that does not exist";
    return;
  }
  const std::string exe = self_exe();
  ASSERT_FALSE(exe.empty());
  const std::string log = ::testing::TempDir() + "shared_data_probe_" + std::to_string(::getpid()) + ".txt";
  const auto probe = [&](const char* ci, std::string& out) {
    lancet::test::Child child({exe, std::string("--gtest_filter=") + kTest}, log, {"LANCET_SHARED_DATA_PROBE=1", ci});
    const auto status = child.wait_exit(std::chrono::seconds(60));
    out = lancet::test::read_file(log);
    return status && WIFEXITED(*status) ? WEXITSTATUS(*status) : -1;
  };
  std::string out;
  EXPECT_EQ(probe("CI=", out), 0) << out;
  EXPECT_NE(out.find("[  SKIPPED ]"), std::string::npos) << out;
  EXPECT_NE(out.find("the real test volumes are missing: expected the folder /nonexistent/lancet/shared/data/volumes"), std::string::npos) << out;
  EXPECT_NE(probe("CI=true", out), 0) << out;
  EXPECT_NE(out.find("[  FAILED  ]"), std::string::npos) << out;
  EXPECT_NE(out.find("CI=true: a CI run must have them"), std::string::npos) << out;
  std::remove(log.c_str());
}

}  // namespace
