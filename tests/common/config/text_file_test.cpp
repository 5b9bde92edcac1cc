// Reading a config file whole: the text, a missing file, an oversized one.

#include "config/text_file.hpp"

#include <gtest/gtest.h>

#include <string>

#include "temp_files.hpp"

namespace lancet::config {
namespace {

using TextFile = test::TempDirTest;

TEST_F(TextFile, ReadsTheWholeFile) {
  const std::string text = "a = 1\n" + std::string(100'000, '#') + "\n";
  auto r = read_text_file(write("a.toml", text), 1u << 20, "a test file");
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value(), text);
}

TEST_F(TextFile, AMissingFileIsNotFound) {
  auto r = read_text_file((dir_ / "none.toml").string(), 1u << 20, "a test file");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_EQ(r.error().message, "cannot open: No such file or directory");
}

TEST_F(TextFile, AFileOverTheLimitIsRefusedByName) {
  auto r = read_text_file(write("big.toml", std::string((1u << 20) + 1, 'x')), 1u << 20, "a test file");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
  EXPECT_EQ(r.error().message, "file is larger than 1 MiB; not a test file");
}

TEST_F(TextFile, AFolderIsASystemError) {
  auto r = read_text_file(dir_.string(), 1u << 20, "a test file");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kSystem);
  EXPECT_EQ(r.error().message.rfind("cannot read: ", 0), 0u) << r.error().message;
}

}  // namespace
}  // namespace lancet::config
