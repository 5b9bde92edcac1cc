#pragma once
// The real test volumes, kept outside the repository in ../shared/data/volumes (see SOURCES.md
// there). A checkout without them still runs every other test: a test that needs them is skipped
// with a message saying where they should be. Under CI (environment variable CI=true, as GitHub
// Actions and GitLab set it) their absence is a failure instead, so CI cannot pass by skipping.
//
//   TEST(Dicom, Something) {
//     LANCET_SHARED_VOLUMES_OR_RETURN(volumes);   // const std::string volumes = ".../volumes"
//     auto r = load_dicom_series(volumes + "/head_ct_dicom_ge");
//
// In a fixture's SetUp, shared_volumes_dir() alone is enough (a skip or failure there stops the
// test body).

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <string_view>

namespace lancet::test {

/// True when the environment says this is a CI run (CI=true or CI=1).
inline bool running_under_ci() {
  const char* ci = std::getenv("CI");
  if (ci == nullptr) return false;
  const std::string_view v(ci);
  return v == "true" || v == "TRUE" || v == "True" || v == "1";
}

/// `dir` when it is a folder. When it is not, records a skip (GTEST_SKIP) or, under CI, a fatal
/// failure, each naming the folder, and returns "".
inline std::string shared_volumes_dir_at(const std::string& dir) {
  std::error_code ec;
  if (std::filesystem::is_directory(dir, ec)) return dir;
  const std::string why = "the real test volumes are missing: expected the folder " + dir +
                          " (shared/data/volumes beside the repository checkout; see its SOURCES.md)";
  // The gtest macros return from the function they are in: a lambda lets them record only.
  if (running_under_ci()) {
    [&] { FAIL() << why << ". CI=true: a CI run must have them."; }();
  } else {
    [&] { GTEST_SKIP() << why << ". Skipped (under CI=true this fails)."; }();
  }
  return {};
}

/// LANCET_SOURCE_DIR/../shared/data/volumes, checked by shared_volumes_dir_at.
inline std::string shared_volumes_dir() { return shared_volumes_dir_at(std::string(LANCET_SOURCE_DIR) + "/../shared/data/volumes"); }

}  // namespace lancet::test

/// Declares `const std::string var` = the shared volumes folder, or skips / fails the test (see
/// shared_volumes_dir) and returns from the test body.
#define LANCET_SHARED_VOLUMES_OR_RETURN(var)                        \
  const std::string var = ::lancet::test::shared_volumes_dir(); \
  if (var.empty()) return
