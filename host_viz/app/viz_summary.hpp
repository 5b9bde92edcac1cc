#pragma once
// What lancet-viz says at the end of a run: the --stats JSON (the link's figures, the tissue's
// events, the cut and groove, the task, the blood, the screenshot) and a replay's verdict.

#include <cstdint>
#include <string>

#include "app/viz_session.hpp"
#include "record/replay.hpp"
#include "sim/scene_sim.hpp"

namespace lancet::viz {

/// The run's own figures, beside the link's and the scene's.
struct RunFigures {
  std::uint64_t frames = 0;
  double screenshot_variance = -1;  ///< luminance variance of the screenshot (-1: none taken)
  double blood_ms_per_frame = 0;    ///< ms spent on the blood a frame (simulation and upload)
  std::string screenshot;           ///< its path ("" none)
};

/// Writes the --stats JSON to `path`; false when it cannot be written.
[[nodiscard]] bool write_stats(const std::string& path, const VizSession& session, const sim::SceneSim& sim, const RunFigures& run);

/// Prints a replay's verdict (ticks and frames replayed, hashes checked and differing, a gap, a
/// stop, the first difference). Returns 1 when it differs, stopped early (`error`: why) or, headless,
/// did not replay everything; 0 otherwise.
[[nodiscard]] int print_replay_verdict(const record::Replay& replay, const std::string& path, const std::string& error, bool headless);

}  // namespace lancet::viz
