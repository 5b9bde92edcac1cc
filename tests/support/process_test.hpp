#pragma once
// A fixture for tests that start Lancet's processes: a folder of its own per test for logs and
// stats (kept when the test fails, for reading), and a segment name of its own, removed after the
// test because a killed lancet-rt leaves its segment behind.

#include <gtest/gtest.h>
#include <sys/mman.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "process.hpp"

namespace lancet::test {

class ProcessTest : public ::testing::Test {
 public:
  /// A file in this test's folder.
  [[nodiscard]] std::string path(const std::string& file) const { return (dir_ / file).string(); }

 protected:
  /// `prefix` names the suite's folders and segments: /lancet-PREFIX-PID-TEST.
  explicit ProcessTest(std::string prefix) : prefix_(std::move(prefix)) {}

  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const std::string name = std::string(info->name()).substr(0, 40);  // segment names stay short
    const std::string tag = "lancet-" + prefix_ + "-" + std::to_string(getpid()) + "-" + name;
    dir_ = std::filesystem::temp_directory_path() / tag;
    std::filesystem::create_directories(dir_);
    shm_ = "/" + tag;
  }
  void TearDown() override {
    shm_unlink(shm_.c_str());
    if (!HasFailure()) std::filesystem::remove_all(dir_);
  }
  std::filesystem::path dir_;
  std::string shm_;

 private:
  std::string prefix_;
};

}  // namespace lancet::test
