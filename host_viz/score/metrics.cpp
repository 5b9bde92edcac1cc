// The skill metrics: one small function per group (time and motion, force, the incision, the
// frames' figures), each appending to Metrics in scenario::kScoreMetrics order; bands and the
// verdict are applied last. Definitions are in metrics.hpp and in each metric's description.

#include "score/metrics.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <utility>

#include "text/text.hpp"

namespace lancet::score {

namespace {

std::string num_g(double v) { return text::format("%g", v); }

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();


double seconds(std::int64_t ns) { return static_cast<double>(ns) / 1e9; }

bool in_contact(const ToolSample& s) { return s.stage != Stage::kFree; }

[[maybe_unused]] bool has_metric(std::string_view name) {
  return std::any_of(scenario::kScoreMetrics.begin(), scenario::kScoreMetrics.end(),
                     [&](const scenario::ScoreMetricInfo& m) { return m.name == name; });
}

void add(Metrics& out, std::string_view name, double value, std::string unit, Better better, std::string description) {
  assert(has_metric(name) && "compute_metrics: every metric must be listed in scenario::kScoreMetrics");
  Metric m;
  m.name = name;
  m.value = value;
  m.unit = std::move(unit);
  m.better = better;
  m.description = std::move(description);
  out.metrics.push_back(std::move(m));
}

// The task window: first and last interaction tick (first > last when there is none).
struct Window {
  std::size_t first = 1, last = 0;
  [[nodiscard]] bool empty() const { return first > last; }
};

Window task_window(const std::vector<ToolSample>& s) {
  Window w;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (!in_contact(s[i])) continue;
    if (w.empty()) w.first = i;
    w.last = i;
  }
  if (w.empty()) w = Window{};
  return w;
}

// The motion filter's output for every tick: the low-passed tip speed (m/s) and position (m).
struct Filtered {
  std::vector<double> speed;
  std::vector<Vec3> position;
};

Filtered filter_motion(const std::vector<ToolSample>& s, double cutoff_hz) {
  Filtered f;
  f.speed.assign(s.size(), 0.0);
  f.position.assign(s.size(), Vec3{});
  if (s.empty()) return f;
  const double rc = 1.0 / (2 * std::numbers::pi * cutoff_hz);
  double v = 0;
  Vec3 p = s[0].tool.position;
  if (!is_finite(p)) p = Vec3{};
  f.position[0] = p;
  for (std::size_t i = 1; i < s.size(); ++i) {
    const double dt = seconds(s[i].t_ns - s[i - 1].t_ns);
    const Vec3 a = s[i - 1].tool.position, b = s[i].tool.position;
    // A tick out of order or a non-finite position holds the filter where it was.
    if (dt > 0 && is_finite(a) && is_finite(b)) {
      const double alpha = dt / (dt + rc);
      v += alpha * (norm(b - a) / dt - v);
      p += alpha * (b - p);
    }
    f.speed[i] = v;
    f.position[i] = p;
  }
  return f;
}

// Angle (rad) of the rotation from a to b; neither needs to be normalised.
double rotation_angle(Quat a, Quat b) {
  // conj(a) * b
  const double w = a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z;
  const double x = a.w * b.x - a.x * b.w - a.y * b.z + a.z * b.y;
  const double y = a.w * b.y + a.x * b.z - a.y * b.w - a.z * b.x;
  const double z = a.w * b.z - a.x * b.y + a.y * b.x - a.z * b.w;
  return 2 * std::atan2(std::sqrt(x * x + y * y + z * z), std::abs(w));
}

double xy_length(const std::vector<Vec3>& line) {
  double len = 0;
  for (std::size_t i = 1; i < line.size(); ++i) len += std::hypot(line[i].x - line[i - 1].x, line[i].y - line[i - 1].y);
  return len;
}

// ---- time and motion ---------------------------------------------------------------------------

void add_motion(Metrics& out, const Recording& rec, const Window& w, const scenario::Scenario* sc) {
  const auto& s = rec.samples;
  const scenario::Score& score = out.score;
  const bool none = w.empty();

  add(out, "task_time_s", none ? kNaN : seconds(s[w.last].t_ns - s[w.first].t_ns), "s", Better::kLower,
      "time from the first to the last tick of tool-tissue interaction (any stage but free)");

  double path = 0, angle = 0;
  for (std::size_t i = w.first + 1; !none && i <= w.last; ++i) {
    const Vec3 a = s[i - 1].tool.position, b = s[i].tool.position;
    if (is_finite(a) && is_finite(b)) path += norm(b - a);
    const double da = rotation_angle(s[i - 1].tool.orientation, s[i].tool.orientation);
    if (std::isfinite(da)) angle += da;
  }
  add(out, "path_length_mm", none ? kNaN : path * 1e3, "mm", Better::kLower,
      "distance travelled by the tool tip over the task window (sum over the 1 kHz ticks, unfiltered)");
  add(out, "angular_path_rad", none ? kNaN : angle, "rad", Better::kLower,
      "total rotation of the tool over the task window (sum of the angles between successive orientations)");

  if (sc != nullptr) {
    const bool incision = sc->task == scenario::TaskKind::kIncision;
    const double ideal_mm = incision ? xy_length(sc->incision.line) * 1e3 : 2 * sc->drill.depth * 1e3;
    add(out, "economy_of_motion_ratio", none || !(ideal_mm > 0) ? kNaN : path * 1e3 / ideal_mm, "ratio", Better::kLower,
        "path length / ideal path: " +
            (incision ? "the task line's x-y length (" + num_g(ideal_mm) + " mm)"
                      : "twice the window's depth, down and back (" + num_g(ideal_mm) + " mm)"));
  }

  const Filtered f = filter_motion(s, score.movement_filter_hz);
  const double threshold = score.movement_speed;
  double movements = 0;
  for (std::size_t i = std::max<std::size_t>(w.first, 1); !none && i <= w.last; ++i) {
    if (f.speed[i - 1] < threshold && f.speed[i] >= threshold) ++movements;
  }
  add(out, "movement_count", none ? kNaN : movements, "count", Better::kLower,
      "upward crossings of " + num_g(threshold * 1e3) + " mm/s by the tool-tip speed, low-passed at " +
          num_g(score.movement_filter_hz) + " Hz (first order), in the task window");

  // Third differences of the filtered position over four consecutive ticks (no seq gap).
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t i = std::max<std::size_t>(w.first + 3, 3); !none && i <= w.last; ++i) {
    if (s[i].seq - s[i - 3].seq != 3) continue;
    const double h = seconds(s[i].t_ns - s[i - 3].t_ns) / 3;
    if (!(h > 0)) continue;
    const Vec3 d3 = f.position[i] - 3.0 * f.position[i - 1] + 3.0 * f.position[i - 2] - f.position[i - 3];
    const double j = norm(d3) / (h * h * h);
    sum += j * j;
    ++n;
  }
  add(out, "jerk_rms_m_s3", n == 0 ? kNaN : std::sqrt(sum / static_cast<double>(n)), "m/s³", Better::kLower,
      "RMS of the third derivative of the tool-tip position (third differences of the 1 kHz ticks after the " +
          num_g(score.movement_filter_hz) + " Hz low-pass), in the task window");
}

// ---- force -------------------------------------------------------------------------------------

void add_force(Metrics& out, const Recording& rec) {
  const double limit = out.score.force_limit;
  double sum = 0, peak = 0;
  std::size_t contact = 0;
  std::int64_t above = 0;
  for (const ToolSample& t : rec.samples) {
    const double f = norm(t.force);
    if (!std::isfinite(f)) continue;
    peak = std::max(peak, f);
    if (f > limit) ++above;
    if (in_contact(t)) {
      sum += f;
      ++contact;
    }
  }
  const std::int64_t period_ns = rec.period_ns > 0 ? rec.period_ns : 1'000'000;
  add(out, "force_mean_n", contact == 0 ? kNaN : sum / static_cast<double>(contact), "N", Better::kLower,
      "mean force magnitude on the hand over the interaction ticks");
  add(out, "force_peak_n", rec.samples.empty() ? kNaN : peak, "N", Better::kLower, "largest force magnitude on the hand");
  add(out, "time_above_force_limit_s", rec.samples.empty() ? kNaN : seconds(above * period_ns), "s", Better::kLower,
      "ticks with a force above " + num_g(limit) + " N, times the servo period");
}

// ---- the incision ------------------------------------------------------------------------------

void add_incision(Metrics& out, const Recording& rec, const scenario::IncisionTask& task) {
  // The cuts as the servo reported them: each rupture starts a cut at its position; every cut
  // progress event (each 0.5 mm of cut) adds the proxy's position to the current one.
  std::vector<std::vector<Vec3>> cuts;
  std::vector<Vec3> cut;
  double sum = 0, max = 0;
  std::size_t points = 0;
  for (const ToolSample& t : rec.samples) {
    const Vec3 p = t.payload.position;
    if ((t.events & event::kRupture) != 0) {
      if (!cut.empty()) cuts.push_back(std::exchange(cut, {}));
      if (is_finite(p)) cut.push_back(p);
    }
    if ((t.events & event::kCutProgress) != 0 && is_finite(p)) {
      cut.push_back(p);
      const double d = scenario::xy_distance_to_polyline(p, task.line);
      sum += d;
      max = std::max(max, d);
      ++points;
    }
  }
  if (!cut.empty()) cuts.push_back(std::move(cut));
  const std::string per = "x-y distance of the cut progress points (every 0.5 mm of cut) to the incision line";
  add(out, "incision_deviation_mean_mm", points == 0 ? kNaN : sum / static_cast<double>(points) * 1e3, "mm", Better::kLower,
      "mean " + per);
  add(out, "incision_deviation_max_mm", points == 0 ? kNaN : max * 1e3, "mm", Better::kLower, "largest " + per);
  const scenario::IncisionProgress progress = scenario::incision_progress(task, cuts);
  add(out, "incision_coverage_pct", 100 * progress.covered, "%", Better::kHigher,
      "share of the incision line within " + num_g(task.tolerance * 1e3) + " mm of a cut (cuts from the cut progress points, a new cut at each rupture)");
}

// ---- the frames' figures -----------------------------------------------------------------------

void add_frames(Metrics& out, const Recording& rec, const scenario::Scenario* sc) {
  const FrameRecord* last = rec.frames.empty() ? nullptr : &rec.frames.back();
  const bool drill = sc != nullptr && sc->task == scenario::TaskKind::kDrill;
  if (drill) {
    add(out, "drill_progress_pct", last ? 100 * last->task_progress : kNaN, "%", Better::kHigher,
        "share of the window's bone removed at the end (the last frame)");
  }
  if (last != nullptr) {
    for (unsigned bit = 0; bit < 32; ++bit) {
      if ((last->damaged >> bit & 1u) == 0) continue;
      out.damaged.push_back(sc != nullptr && bit < sc->avoid.size() ? sc->avoid[bit].name : "avoid[" + std::to_string(bit) + "]");
    }
  }
  add(out, "damaged_structures_count", last ? static_cast<double>(std::popcount(last->damaged)) : kNaN, "count", Better::kLower,
      "protected structures (the scenario's avoid list) reached by the end");
  if (drill) {
    add(out, "drilled_outside_mm3", last ? last->drilled_outside_mm3 : kNaN, "mm³", Better::kLower,
        "bone removed outside the drill window by the end");
  }
  add(out, "blood_loss_ml", last ? last->blood_lost_ml : kNaN, "mL", Better::kLower, "blood lost from all sources by the end");
}

void apply_bands(Metrics& out) {
  const scenario::Score& score = out.score;
  for (Metric& m : out.metrics) {
    const scenario::ScoreBand* b = scenario::find_band(score, m.name);
    if (b == nullptr) continue;
    MetricBand band{b->mean, b->sd, score.sd_multiple, 0};
    band.limit = m.better == Better::kLower ? b->mean + score.sd_multiple * b->sd : b->mean - score.sd_multiple * b->sd;
    m.band = band;
    m.pass = m.better == Better::kLower ? m.value <= band.limit : m.value >= band.limit;  // NaN: false
    ++out.banded;
    if (m.pass) ++out.passed;
  }
  out.verdict = out.banded == 0 ? Verdict::kNotAssessed : out.passed == out.banded ? Verdict::kProficient : Verdict::kNotYet;
}

}  // namespace

std::string_view verdict_key(Verdict v) noexcept {
  switch (v) {
    case Verdict::kNotAssessed: return "not_assessed";
    case Verdict::kProficient: return "proficient";
    case Verdict::kNotYet: return "not_yet";
  }
  return "?";
}

Metrics compute_metrics(const Recording& rec, const scenario::Scenario* s) {
  Metrics out;
  if (s != nullptr) {
    out.score = s->score;
    out.has_task = true;
    out.task = s->task;
    out.incision = s->incision;
    out.drill = s->drill;
  }
  const Window w = task_window(rec.samples);
  if (w.empty()) {
    out.window_begin_s = out.window_end_s = kNaN;
    out.notes.emplace_back("no tool-tissue interaction: task time, path, movements, jerk and mean force are not measured");
  } else {
    const std::int64_t t0 = rec.samples.front().t_ns;
    out.window_begin_s = seconds(rec.samples[w.first].t_ns - t0);
    out.window_end_s = seconds(rec.samples[w.last].t_ns - t0);
  }
  if (rec.frames.empty()) out.notes.emplace_back("no visualizer frames: damage, blood loss and drill progress are not measured");
  if (rec.samples_lost > 0) {
    out.notes.push_back(std::to_string(rec.samples_lost) + " ticks missing from the recording (" + std::to_string(rec.gaps) +
                        " gaps): sums over ticks undercount");
  }
  if (rec.cut_short) {
    out.notes.push_back("the recording was cut short (the recorder never finished it: the viz was killed or the power lost): "
                        "scored up to where the file ends, " + std::to_string(rec.samples.size()) + " ticks");
  }
  if (s == nullptr) out.notes.emplace_back("no scenario: no task metrics and no bands");

  add_motion(out, rec, w, s);
  add_force(out, rec);
  if (s != nullptr && s->task == scenario::TaskKind::kIncision) add_incision(out, rec, s->incision);
  add_frames(out, rec, s);
  apply_bands(out);
  return out;
}

const Metric* find_metric(const Metrics& m, std::string_view name) noexcept {
  for (const Metric& x : m.metrics) {
    if (x.name == name) return &x;
  }
  return nullptr;
}

}  // namespace lancet::score
