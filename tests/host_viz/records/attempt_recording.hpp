#pragma once
// A short recording of the project's skin-incision scenario for the records' tests: a cut along
// its line, the scenario's text inside, content made to differ by `n` (so each is its own attempt).

#include <string>

#include "../score/synthetic_recording.hpp"
#include "process.hpp"
#include "recording/hdf5_io.hpp"

namespace lancet::records::test {

inline const std::string kSkinIncision = std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/skin_incision.toml";

/// Writes the recording to `path`; an error is a test failure.
inline void write_attempt_recording(const std::string& path, int n) {
  record::Recording r = record::test::make_recording(800, [n](std::size_t i, double, ToolSample& s) {
    s.stage = i < 200 ? Stage::kFree : Stage::kCutting;
    s.tool.position = Vec3{-0.015 + 2e-5 * static_cast<double>(i), -0.012 + 1e-6 * n, 0};
  });
  record::test::mark_cut_progress(r);
  r.created = "2026-11-27T03:0" + std::to_string(n % 10) + ":00Z";
  r.scenario_toml = lancet::test::read_file(kSkinIncision);
  r.scenario_file = kSkinIncision;
  r.scenario_name = "skin-incision";
  auto w = record::write_recording(path, r);
  EXPECT_TRUE(w.ok()) << w.error().message;
}

}  // namespace lancet::records::test
