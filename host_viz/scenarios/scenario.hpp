#pragma once
// Scenario: one training exercise as data, loaded from a TOML file in host_viz/scenarios/ (schema:
// host_viz/scenarios/README.md). Which tissue (the built-in phantom, the procedural block or a
// CT file), which isosurface the trainee touches, the tools offered, where the camera starts, the
// task (an incision line or a drill window), the structures not to damage and how a recorded
// attempt is scored (the force limit, the movement threshold, the experts' bands).
//
// The file states its units in its key names (line_mm, tolerance_mm, yaw_deg, skin_iso_hu, ...);
// everything here is SI (m, rad) except isovalues (HU). World frame: z up, the tissue's top
// surface at z = 0, x along the limb.
//
// Loading validates the whole file and reports every problem at once, one per line, as
// "file:line:col: field: expected ..., found ...": unknown keys (with a did-you-mean), missing
// required keys, wrong types, values out of range, sections that disagree with each other.
// Configure time only (allocating, throws nothing: toml++'s exceptions stay inside the loader).
// incision_progress() and touches() are cheap pure functions, safe on any thread.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "lancet/shared_model/geometry.hpp"  // Vec3 (double x,y,z) and helpers
#include "lancet/shared_model/messages.hpp"  // ToolMode, tool_from_name, tool_name, kToolNames
#include "lancet/shared_model/result.hpp"    // Result<T>, Error, ErrorCode

namespace lancet::scenario {

/// The schema_version this loader reads.
inline constexpr int kSchemaVersion = 1;

enum class TissueSource : std::uint8_t { kBlock, kPhantom, kFile };
enum class SurfaceKind : std::uint8_t { kSkin, kBone };  // which isosurface the trainee touches and cuts

struct Tissue {
  TissueSource source = TissueSource::kPhantom;
  std::string volume_path;          ///< kFile: resolved against the scenario file's folder; empty: must come from --volume
  float skin_iso = -300;            ///< HU (key skin_iso_hu)
  float bone_iso = 300;             ///< HU (key bone_iso_hu), > skin_iso
  SurfaceKind surface = SurfaceKind::kSkin;
  double cut_depth = 0.006;         ///< m (key cut_depth_mm, range (0, 30] mm): how deep the scalpel's cut reaches into the volume
  /// kFile only (key axes, e.g. ["x", "-z", "y"]): world axis a runs along the volume's axis
  /// axis[a] (0 = i/x, 1 = j/y, 2 = k/z), in the direction sign[a] (+1 or -1). A permutation.
  std::array<int, 3> axis{0, 1, 2};
  std::array<int, 3> sign{1, 1, 1};
};

/// Where the orbit camera starts: rad, rad, m, m (keys yaw_deg, pitch_deg, distance_mm, target_mm).
struct Camera {
  double yaw = 0.6;        ///< rad about +z
  double pitch = 0.55;     ///< rad above the surface plane, (-90°, 90°)
  double distance = 0.26;  ///< m from the target, > 0
  Vec3 target{};           ///< m, the point the camera orbits and looks at
};

enum class TaskKind : std::uint8_t { kIncision, kDrill };

/// Cut along a polyline on the surface. Only x and y count: the line is projected onto the surface.
struct IncisionTask {
  std::vector<Vec3> line;   ///< m; >= 2 points, nonzero length in x-y
  double tolerance = 0.003; ///< m, the largest x-y distance from the line that still counts as on it
};

/// Open a window into the surface: a disc of `radius` about `centre`, `depth` deep.
struct DrillTask {
  Vec3 centre{};         ///< m, on (or near) the surface being drilled
  double radius = 0.005; ///< m
  double depth = 0.004;  ///< m below the surface at the centre
};

enum class ShapeKind : std::uint8_t { kLabel, kCapsule, kSphere };

/// A structure not to damage.
struct Structure {
  std::string name;
  ShapeKind kind = ShapeKind::kLabel;
  std::uint8_t label = 0;  ///< kLabel: volume material label (0..255; the phantom's PhantomMaterial)
  Vec3 a{}, b{};           ///< kCapsule: segment ends (m); kSphere: centre a
  double radius = 0;       ///< kCapsule/kSphere (m)
};

/// A metric a [score.bands] table may name: what score/metrics.hpp computes, its unit in its
/// name's suffix, and the tasks it applies to.
struct ScoreMetricInfo {
  std::string_view name;
  bool incision = true;  ///< computed for kind = "incision"
  bool drill = true;     ///< computed for kind = "drill"
};
/// Every metric a band may be set for, in the order the report lists them.
inline constexpr std::array<ScoreMetricInfo, 16> kScoreMetrics{{
    {"task_time_s", true, true},
    {"path_length_mm", true, true},
    {"angular_path_rad", true, true},
    {"economy_of_motion_ratio", true, true},
    {"movement_count", true, true},
    {"jerk_rms_m_s3", true, true},
    {"force_mean_n", true, true},
    {"force_peak_n", true, true},
    {"time_above_force_limit_s", true, true},
    {"incision_deviation_mean_mm", true, false},
    {"incision_deviation_max_mm", true, false},
    {"incision_coverage_pct", true, false},
    {"drill_progress_pct", false, true},
    {"damaged_structures_count", true, true},
    {"drilled_outside_mm3", false, true},
    {"blood_loss_ml", true, true},
}};
/// The metrics of a two-handed recording only (Recording::hands == 2), in the order the report
/// lists them, after kScoreMetrics. A band for one of them is checked on two-handed attempts and
/// ignored on one-handed ones (the metric is not there).
inline constexpr std::array<ScoreMetricInfo, 6> kTwoHandScoreMetrics{{
    {"right_path_length_mm", true, true},
    {"left_path_length_mm", true, true},
    {"right_economy_of_motion_ratio", true, true},
    {"left_economy_of_motion_ratio", true, true},
    {"left_idle_time_s", true, true},
    {"both_hands_contact_time_s", true, true},
}};

/// An expert band for one metric (key [score.bands], `name = { mean = x, sd = y }`): the mean and
/// standard deviation of experts' values, in the metric's own unit (its name's suffix: mm, s, N,
/// ...; not converted to SI).
struct ScoreBand {
  std::string metric;  ///< one of kScoreMetrics, applying to the scenario's task
  double mean = 0;     ///< finite
  double sd = 1;       ///< > 0
};

/// How a recorded attempt is scored (key [score]); these defaults when the section is absent.
/// With k = sd_multiple a lower-is-better metric passes at value <= mean + k·sd, a
/// higher-is-better one at value >= mean - k·sd (score/metrics.hpp).
struct Score {
  double force_limit = 3.0;        ///< N (key force_limit_n, > 0): the time above it is counted
  double movement_speed = 0.020;   ///< m/s (key movement_speed_mm_s, > 0): a movement is an upward crossing of it
  double movement_filter_hz = 10;  ///< Hz (key movement_filter_hz, (0, 500]): low-pass cut-off applied before counting
  double sd_multiple = 2;          ///< k (key sd_multiple, (0, 10])
  std::vector<ScoreBand> bands;    ///< in kScoreMetrics then kTwoHandScoreMetrics order, at most one per metric
};

/// The band for `metric`, or nullptr when the score has none.
[[nodiscard]] const ScoreBand* find_band(const Score& score, std::string_view metric) noexcept;

struct Scenario {
  std::string name, description;
  std::string file;  ///< the path it was loaded from (parse_scenario: the source name)
  Tissue tissue;
  std::vector<ToolMode> tools;             ///< offered to the right hand (and to a single hand), no duplicates, non-empty, in file order
  ToolMode start_tool = ToolMode::kProbe;  ///< among tools
  std::vector<ToolMode> left_tools;        ///< offered to the left hand (key left_tools; default: tools)
  ToolMode left_start_tool = ToolMode::kProbe;  ///< among left_tools (key left_start_tool; default: its first)
  Camera camera;
  TaskKind task = TaskKind::kIncision;
  IncisionTask incision;  ///< when task == kIncision
  DrillTask drill;        ///< when task == kDrill
  std::vector<Structure> avoid;
  Score score;  ///< key [score]: how a recording of this scenario is scored (lancet-report)
};

/// Name of each enum value as the file writes it ("phantom", "bone", "drill", "capsule", ...).
[[nodiscard]] std::string_view source_key(TissueSource s) noexcept;
[[nodiscard]] std::string_view surface_key(SurfaceKind s) noexcept;
[[nodiscard]] std::string_view task_key(TaskKind k) noexcept;
[[nodiscard]] std::string_view shape_key(ShapeKind k) noexcept;

/// Parses and validates; every problem reported at once in Error::message (ErrorCode::kInvalid),
/// one per line, sorted by position, as
///   "<source_name>:<line>:<col>: <dotted.field>: expected <...>, found <...>"
/// (unknown keys: "...: unknown key "x" (did you mean "y"?); known keys here: ..."; missing keys:
/// "...: required key is missing; expected ..."; a TOML syntax error: "<source_name>:<line>:<col>:
/// TOML syntax error: ...", the only line, as the parse stops there). A relative tissue.path is
/// resolved against the folder of `source_name`. Sets Scenario::file to `source_name`.
[[nodiscard]] Result<Scenario> parse_scenario(std::string_view text, const std::string& source_name);
/// A scenario file's text, unparsed (a recording keeps it). Errors: "<path>: cannot open:
/// <strerror>" (kNotFound or kSystem), or a file too large to be a scenario (kInvalid).
[[nodiscard]] Result<std::string> read_scenario_text(const std::string& path);
/// Reads the file (as read_scenario_text) and parses it; sets Scenario::file.
[[nodiscard]] Result<Scenario> load_scenario(const std::string& path);

/// How far along an incision task the trainee is, from the cuts made so far (each a polyline on the surface, m).
struct IncisionProgress {
  double covered = 0;        ///< fraction of the task line (in x-y) within tolerance of some cut, 0..1
  double max_deviation = 0;  ///< m, the largest x-y distance of any cut point from the task line
  double outside = 0;        ///< fraction of the cuts' total length farther than tolerance from the line
};
/// Only x and y count. `covered` samples the task line every tolerance / 4 (at most 4096 samples)
/// and counts a sample as covered when some cut passes within tolerance of it; `outside` splits
/// each cut segment the same way. Cuts of one point count for max_deviation only. Empty cuts: all 0.
[[nodiscard]] IncisionProgress incision_progress(const IncisionTask& task, const std::vector<std::vector<Vec3>>& cuts);

/// True when a sphere (centre, radius, m) touches the shape (kCapsule/kSphere; kLabel: always
/// false — labels are checked by the caller against the volume). Touching includes contact.
[[nodiscard]] bool touches(const Structure& s, Vec3 centre, double radius);

/// x-y distance (m) from p to the polyline (z ignored); +inf for an empty line.
[[nodiscard]] double xy_distance_to_polyline(Vec3 p, const std::vector<Vec3>& line);

}  // namespace lancet::scenario
