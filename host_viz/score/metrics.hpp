#pragma once
// Skill metrics of one recorded attempt: how long, how far and how smoothly the tool
// moved, how hard it pressed, how well the task was done and what was damaged, each against the
// experts' band the scenario's [score] section gives (host_viz/scenarios/README.md).
//
// compute_metrics() is a pure function of the Recording and the scenario: the same input gives
// bit-identical output (sequential sums in sample order, no threads, no clock). It allocates
// (tools and the report only; never on the real-time path).
//
// Definitions shared by several metrics:
//   - interaction: a tick whose stage is not Stage::kFree (the tool touches, cuts, pulls or drills);
//   - the task window: from the first to the last interaction tick (inclusive); the motion
//     metrics (path, angle, movements, jerk) are taken over it, so walking up to the tissue and
//     away from it does not count;
//   - the motion filter: a first-order low-pass (y += a·(x − y), a = dt / (dt + 1/(2π·fc)),
//     fc = Score::movement_filter_hz, dt from the ticks' t_ns) run over the whole recording, on
//     the tool tip's speed (from 0) for movements and on its position (from the first position)
//     for the jerk.
// A metric that cannot be measured (no interaction, no frames, no cut) has value NaN: it never
// passes a band, and the report and the JSON show it as missing.
//
// Two hands (Recording::hands == 2, or any sample of the left hand): the samples are split by
// ToolSample::hand first, so no figure ever runs across alternating right and left samples. Then
//   - the task window spans both hands: from the first interaction tick of either hand to the
//     last of either (a one-handed recording's window is unchanged);
//   - the right (dominant) hand's figure: path, angle, economy of motion, movements, jerk, mean
//     force (each over the right hand's samples in the task window);
//   - both hands: task time (the window), peak force (the larger of the two), time above the
//     force limit (ticks at which either hand's force is above it, each tick once), the incision
//     (each hand's cuts from its own rupture and cut progress events; the deviation over the cut
//     progress points of both);
//   - the frames' figures (damage, blood, drill) are the scene's, whichever hand did it;
//   - kTwoHandScoreMetrics are added (Metric::hand says whose each figure is):
//       right_/left_path_length_mm: that hand's tool-tip path over the task window, as
//         path_length_mm;
//       right_/left_economy_of_motion_ratio: that hand's path over the task window divided by the
//         straight distance between its tool tip at the window's first and last of its ticks
//         (NaN when that distance is under kEconomyMinDisplacement: the hand ended where it
//         began). Not economy_of_motion_ratio, which divides by the task's ideal path;
//       left_idle_time_s: the task window cut into consecutive kIdleBlockNs blocks from its
//         start (a step between two ticks belongs to the block its later tick falls in); a block
//         is idle when the left tool tip's net displacement over it divided by its duration is
//         below kIdleSpeed and none of its ticks is in interaction (a retractor holding the tissue
//         still is working); the sum of the idle blocks' durations;
//       both_hands_contact_time_s: ticks at which the right and the left sample of the same seq
//         are both in interaction (stage not kFree), times the servo period (the whole recording).
// A one-handed recording has none of kTwoHandScoreMetrics and its figures are exactly those of
// the one-handed definitions above.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "recording/recording.hpp"
#include "scenarios/scenario.hpp"

namespace lancet::score {

using record::FrameRecord;
using record::Recording;
using record::SceneEvent;

/// Two hands: a block of the task window in which the left hand moved slower than this is idle (m/s).
inline constexpr double kIdleSpeed = 0.005;
/// Two hands: the length of the blocks the idle time is measured in (ns).
inline constexpr std::int64_t kIdleBlockNs = 100'000'000;
/// Two hands: a hand's economy of motion is not measured when it ended less than this far from
/// where it began (m): the ratio would be unbounded.
inline constexpr double kEconomyMinDisplacement = 0.001;

/// Which way a metric improves.
enum class Better : std::uint8_t { kLower, kHigher };

/// A metric's expert band (scenario::ScoreBand) and the pass threshold it implies.
struct MetricBand {
  double mean = 0;   ///< the metric's unit
  double sd = 1;     ///< the metric's unit, > 0
  double k = 2;      ///< scenario::Score::sd_multiple
  double limit = 0;  ///< Better::kLower: passes at value <= mean + k·sd; kHigher: at value >= mean − k·sd
};

/// Whose samples a metric is measured on.
enum class HandScope : std::uint8_t {
  kRight,  ///< the right (dominant) hand's; in a one-handed recording, every sample's
  kLeft,   ///< the left hand's
  kBoth,   ///< both hands' (how they combine: metrics.hpp's header and the description)
  kScene,  ///< the visualizer's frames, not the samples
};
[[nodiscard]] std::string_view hand_scope_key(HandScope h) noexcept;  ///< "right", "left", "both", "scene"

struct Metric {
  std::string name;         ///< snake_case, unit as suffix: one of scenario::kScoreMetrics
  double value = 0;         ///< in `unit`; NaN when it could not be measured
  std::string unit;         ///< "s", "mm", "rad", "ratio", "count", "m/s³", "N", "%", "mm³", "mL"
  Better better = Better::kLower;
  std::string description;  ///< one line: what it is and how it was computed (thresholds included)
  std::optional<MetricBand> band;  ///< when the scenario has a band for it
  bool pass = false;        ///< with a band: the value is within it (NaN never is); without one: false
  HandScope hand = HandScope::kRight;  ///< whose figure it is
};

enum class Verdict : std::uint8_t {
  kNotAssessed,  ///< no metric has a band (no scenario, or a scenario without [score.bands])
  kProficient,   ///< every banded metric passes
  kNotYet,       ///< at least one banded metric fails
};
[[nodiscard]] std::string_view verdict_key(Verdict v) noexcept;  ///< "not_assessed", "proficient", "not_yet"

/// Everything compute_metrics found, with what it was measured against.
struct Metrics {
  /// In scenario::kScoreMetrics order (those the task does not have are left out), then with two
  /// hands scenario::kTwoHandScoreMetrics in theirs.
  std::vector<Metric> metrics;
  std::uint32_t hands = 1;      ///< hands in the recording (2: kTwoHandScoreMetrics are there)
  Verdict verdict = Verdict::kNotAssessed;
  std::size_t banded = 0;       ///< metrics with a band
  std::size_t passed = 0;       ///< of them, passing
  scenario::Score score;        ///< the limits used (the scenario's, or the defaults) and its bands
  // The task as the scenario sets it (has_task false without a scenario).
  bool has_task = false;
  scenario::TaskKind task = scenario::TaskKind::kIncision;
  scenario::IncisionTask incision;  ///< when task == kIncision
  scenario::DrillTask drill;        ///< when task == kDrill
  std::vector<std::string> damaged;  ///< names of the protected structures reached (last frame)
  double window_begin_s = 0;    ///< the task window (of either hand), s after the first sample (NaN: no interaction)
  double window_end_s = 0;
  std::vector<std::string> notes;  ///< what limited the computation, in words
};

/// The metrics of one attempt. `s` may be null: then no task metrics, no bands, default limits,
/// and damaged structures named by their bit ("avoid[2]"). `s` should be the scenario the
/// recording was made with (parse rec.scenario_toml).
[[nodiscard]] Metrics compute_metrics(const Recording& rec, const scenario::Scenario* s);

/// The metric called `name`, or nullptr when it was left out.
[[nodiscard]] const Metric* find_metric(const Metrics& m, std::string_view name) noexcept;

}  // namespace lancet::score
