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
  const auto named = [&](const scenario::ScoreMetricInfo& m) { return m.name == name; };
  return std::any_of(scenario::kScoreMetrics.begin(), scenario::kScoreMetrics.end(), named) ||
         std::any_of(scenario::kTwoHandScoreMetrics.begin(), scenario::kTwoHandScoreMetrics.end(), named);
}

void add(Metrics& out, std::string_view name, double value, std::string unit, Better better, std::string description,
         HandScope hand = HandScope::kRight) {
  assert(has_metric(name) && "compute_metrics: every metric must be listed in scenario::kScoreMetrics or kTwoHandScoreMetrics");
  Metric m;
  m.name = name;
  m.value = value;
  m.unit = std::move(unit);
  m.better = better;
  m.description = std::move(description);
  m.hand = hand;
  out.metrics.push_back(std::move(m));
}

// ---- the hands ---------------------------------------------------------------------------------

// Each hand's samples, in tick order. A recording whose samples are all the right hand's (every
// one-handed recording) is used as it is, not copied.
class HandStreams {
 public:
  explicit HandStreams(const Recording& rec) : rec_(&rec) {
    const bool all_right = std::all_of(rec.samples.begin(), rec.samples.end(), [](const ToolSample& t) { return t.hand == Hand::kRight; });
    two_ = rec.hands >= 2 || !all_right;
    if (all_right) return;
    copied_ = true;
    for (const ToolSample& t : rec.samples) {
      const std::size_t h = hand_index(t.hand);
      if (h < kHandCount) {
        split_[h].push_back(t);
      } else {
        ++no_hand_;
      }
    }
  }
  /// The recording has two hands.
  [[nodiscard]] bool two() const { return two_; }
  /// Samples that named no hand (left out).
  [[nodiscard]] std::size_t no_hand() const { return no_hand_; }
  [[nodiscard]] const std::vector<ToolSample>& of(Hand h) const {
    return h == Hand::kRight && !copied_ ? rec_->samples : split_[hand_index(h)];
  }

 private:
  const Recording* rec_;
  bool two_ = false;
  bool copied_ = false;
  std::size_t no_hand_ = 0;
  std::vector<ToolSample> split_[kHandCount];
};

// Whose figure a metric is, for its description: nothing in a one-handed recording.
std::string whose(bool two, HandScope h) {
  if (!two) return "";
  switch (h) {
    case HandScope::kRight: return " [right (dominant) hand]";
    case HandScope::kLeft: return " [left hand]";
    case HandScope::kBoth: return " [both hands]";
    case HandScope::kScene: return "";
  }
  return "";
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

// The task window in time (ns), of either hand.
struct Span {
  std::int64_t begin_ns = 0, end_ns = -1;
  [[nodiscard]] bool empty() const { return begin_ns > end_ns; }
};

Span span_of(const std::vector<ToolSample>& s, const Window& w) {
  return w.empty() ? Span{} : Span{s[w.first].t_ns, s[w.last].t_ns};
}

Span span_union(Span a, Span b) {
  if (a.empty()) return b;
  if (b.empty()) return a;
  return Span{std::min(a.begin_ns, b.begin_ns), std::max(a.end_ns, b.end_ns)};
}

// A hand's ticks within the span: from its first tick at or after the beginning to its last at
// or before the end.
Window window_in(const std::vector<ToolSample>& s, const Span& span) {
  Window w;
  if (span.empty()) return w;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i].t_ns < span.begin_ns || s[i].t_ns > span.end_ns) continue;
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

// The distance the tool tip travelled over the window's ticks (m; unfiltered). Steps with a
// non-finite end are left out.
double path_length(const std::vector<ToolSample>& s, const Window& w) {
  double path = 0;
  for (std::size_t i = w.first + 1; !w.empty() && i <= w.last; ++i) {
    const Vec3 a = s[i - 1].tool.position, b = s[i].tool.position;
    if (is_finite(a) && is_finite(b)) path += norm(b - a);
  }
  return path;
}

// `s` is the right hand's samples, `w` its ticks in the task window `span` (both hands').
void add_motion(Metrics& out, const std::vector<ToolSample>& s, const Window& w, const Span& span, const scenario::Scenario* sc,
                bool two) {
  const scenario::Score& score = out.score;
  const bool none = w.empty();
  const std::string right = whose(two, HandScope::kRight);

  add(out, "task_time_s", span.empty() ? kNaN : seconds(span.end_ns - span.begin_ns), "s", Better::kLower,
      "time from the first to the last tick of tool-tissue interaction (any stage but free)" + whose(two, HandScope::kBoth),
      two ? HandScope::kBoth : HandScope::kRight);

  const double path = path_length(s, w);
  double angle = 0;
  for (std::size_t i = w.first + 1; !none && i <= w.last; ++i) {
    const double da = rotation_angle(s[i - 1].tool.orientation, s[i].tool.orientation);
    if (std::isfinite(da)) angle += da;
  }
  add(out, "path_length_mm", none ? kNaN : path * 1e3, "mm", Better::kLower,
      "distance travelled by the tool tip over the task window (sum over the 1 kHz ticks, unfiltered)" + right);
  add(out, "angular_path_rad", none ? kNaN : angle, "rad", Better::kLower,
      "total rotation of the tool over the task window (sum of the angles between successive orientations)" + right);

  if (sc != nullptr) {
    const bool incision = sc->task == scenario::TaskKind::kIncision;
    const double ideal_mm = incision ? xy_length(sc->incision.line) * 1e3 : 2 * sc->drill.depth * 1e3;
    add(out, "economy_of_motion_ratio", none || !(ideal_mm > 0) ? kNaN : path * 1e3 / ideal_mm, "ratio", Better::kLower,
        "path length / ideal path: " +
            (incision ? "the task line's x-y length (" + num_g(ideal_mm) + " mm)"
                      : "twice the window's depth, down and back (" + num_g(ideal_mm) + " mm)") + right);
  }

  const Filtered f = filter_motion(s, score.movement_filter_hz);
  const double threshold = score.movement_speed;
  double movements = 0;
  for (std::size_t i = std::max<std::size_t>(w.first, 1); !none && i <= w.last; ++i) {
    if (f.speed[i - 1] < threshold && f.speed[i] >= threshold) ++movements;
  }
  add(out, "movement_count", none ? kNaN : movements, "count", Better::kLower,
      "upward crossings of " + num_g(threshold * 1e3) + " mm/s by the tool-tip speed, low-passed at " +
          num_g(score.movement_filter_hz) + " Hz (first order), in the task window" + right);

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
          num_g(score.movement_filter_hz) + " Hz low-pass), in the task window" + right);
}

// ---- force -------------------------------------------------------------------------------------

std::int64_t period_of(const Recording& rec) { return rec.period_ns > 0 ? rec.period_ns : 1'000'000; }

// The mean force is the right hand's (its samples `right`); the peak and the time above the limit
// are both hands' (every sample; with two hands a tick, all samples of one seq in a row, counts
// once when either hand's force is above the limit).
void add_force(Metrics& out, const Recording& rec, const std::vector<ToolSample>& right, bool two) {
  const double limit = out.score.force_limit;
  double sum = 0, peak = 0;
  std::size_t contact = 0;
  for (const ToolSample& t : right) {
    const double f = norm(t.force);
    if (!std::isfinite(f) || !in_contact(t)) continue;
    sum += f;
    ++contact;
  }
  std::int64_t above = 0;
  bool tick_above = false;
  for (std::size_t i = 0; i < rec.samples.size(); ++i) {
    const ToolSample& t = rec.samples[i];
    const double f = norm(t.force);
    if (std::isfinite(f)) {
      peak = std::max(peak, f);
      tick_above |= f > limit;
    }
    const bool tick_ends = !two || i + 1 == rec.samples.size() || rec.samples[i + 1].seq != t.seq;
    if (tick_ends) {
      if (tick_above) ++above;
      tick_above = false;
    }
  }
  const HandScope both = two ? HandScope::kBoth : HandScope::kRight;
  add(out, "force_mean_n", contact == 0 ? kNaN : sum / static_cast<double>(contact), "N", Better::kLower,
      "mean force magnitude on the hand over the interaction ticks" + whose(two, HandScope::kRight));
  add(out, "force_peak_n", rec.samples.empty() ? kNaN : peak, "N", Better::kLower,
      std::string(two ? "largest force magnitude on either hand" : "largest force magnitude on the hand") + whose(two, both), both);
  add(out, "time_above_force_limit_s", rec.samples.empty() ? kNaN : seconds(above * period_of(rec)), "s", Better::kLower,
      std::string(two ? "ticks with a force above " + num_g(limit) + " N on either hand (each tick once)"
                      : "ticks with a force above " + num_g(limit) + " N") +
          ", times the servo period" + whose(two, both),
      both);
}

// ---- the incision ------------------------------------------------------------------------------

void add_incision(Metrics& out, const Recording& rec, const scenario::IncisionTask& task, bool two) {
  // The cuts as the servo reported them: each rupture starts a cut at its position; every cut
  // progress event (each 0.5 mm of cut) adds the proxy's position to the current one. Each hand
  // has its own current cut, so a rupture by one hand never splits the other's.
  std::vector<std::vector<Vec3>> cuts;
  std::vector<Vec3> cut[kHandCount];
  double sum = 0, max = 0;
  std::size_t points = 0;
  for (const ToolSample& t : rec.samples) {
    const std::size_t h = hand_index(t.hand);
    if (h >= kHandCount) continue;
    const Vec3 p = t.payload.position;
    if ((t.events & event::kRupture) != 0) {
      if (!cut[h].empty()) cuts.push_back(std::exchange(cut[h], {}));
      if (is_finite(p)) cut[h].push_back(p);
    }
    if ((t.events & event::kCutProgress) != 0 && is_finite(p)) {
      cut[h].push_back(p);
      const double d = scenario::xy_distance_to_polyline(p, task.line);
      sum += d;
      max = std::max(max, d);
      ++points;
    }
  }
  for (auto& c : cut) {
    if (!c.empty()) cuts.push_back(std::move(c));
  }
  const HandScope both = two ? HandScope::kBoth : HandScope::kRight;
  const std::string per = "x-y distance of the cut progress points (every 0.5 mm of cut) to the incision line" + whose(two, both);
  add(out, "incision_deviation_mean_mm", points == 0 ? kNaN : sum / static_cast<double>(points) * 1e3, "mm", Better::kLower,
      "mean " + per, both);
  add(out, "incision_deviation_max_mm", points == 0 ? kNaN : max * 1e3, "mm", Better::kLower, "largest " + per, both);
  const scenario::IncisionProgress progress = scenario::incision_progress(task, cuts);
  add(out, "incision_coverage_pct", 100 * progress.covered, "%", Better::kHigher,
      "share of the incision line within " + num_g(task.tolerance * 1e3) +
          " mm of a cut (cuts from the cut progress points, a new cut at each rupture" + (two ? " of the same hand)" : ")") +
          whose(two, both),
      both);
}

// ---- the frames' figures -----------------------------------------------------------------------

void add_frames(Metrics& out, const Recording& rec, const scenario::Scenario* sc) {
  const FrameRecord* last = rec.frames.empty() ? nullptr : &rec.frames.back();
  const bool drill = sc != nullptr && sc->task == scenario::TaskKind::kDrill;
  if (drill) {
    add(out, "drill_progress_pct", last ? 100 * last->task_progress : kNaN, "%", Better::kHigher,
        "share of the window's bone removed at the end (the last frame)", HandScope::kScene);
  }
  if (last != nullptr) {
    for (unsigned bit = 0; bit < 32; ++bit) {
      if ((last->damaged >> bit & 1u) == 0) continue;
      out.damaged.push_back(sc != nullptr && bit < sc->avoid.size() ? sc->avoid[bit].name : "avoid[" + std::to_string(bit) + "]");
    }
  }
  add(out, "damaged_structures_count", last ? static_cast<double>(std::popcount(last->damaged)) : kNaN, "count", Better::kLower,
      "protected structures (the scenario's avoid list) reached by the end", HandScope::kScene);
  if (drill) {
    add(out, "drilled_outside_mm3", last ? last->drilled_outside_mm3 : kNaN, "mm³", Better::kLower,
        "bone removed outside the drill window by the end", HandScope::kScene);
  }
  add(out, "blood_loss_ml", last ? last->blood_lost_ml : kNaN, "mL", Better::kLower, "blood lost from all sources by the end",
      HandScope::kScene);
}

// ---- two hands ---------------------------------------------------------------------------------

// The left hand's idle time (s) over its ticks `w` in the task window `span` (metrics.hpp).
double idle_time(const std::vector<ToolSample>& s, const Window& w, const Span& span) {
  double idle = 0;
  std::int64_t block = -1, block_ns = 0;
  Vec3 from{}, to{};
  bool touching = false;  // a tick of the block in interaction: holding tissue still is work, not idleness
  const auto close_block = [&] {
    if (block < 0 || block_ns <= 0 || touching) return;
    const double speed = norm(to - from) / seconds(block_ns);
    if (std::isfinite(speed) && speed < kIdleSpeed) idle += seconds(block_ns);
  };
  for (std::size_t i = w.first + 1; !w.empty() && i <= w.last; ++i) {
    const std::int64_t dt = s[i].t_ns - s[i - 1].t_ns;
    if (dt <= 0) continue;  // out of order: no step
    // The step from tick i − 1 to tick i is in the block its later tick falls in: block k holds
    // the ticks in (begin + k·block, begin + (k + 1)·block].
    const std::int64_t k = (s[i].t_ns - span.begin_ns - 1) / kIdleBlockNs;
    if (k != block) {
      close_block();
      block = k;
      block_ns = 0;
      touching = false;
      from = s[i - 1].tool.position;
    }
    block_ns += dt;
    to = s[i].tool.position;
    touching = touching || s[i].stage != Stage::kFree;
  }
  close_block();
  return idle;
}

// Ticks (runs of samples with one seq) at which both hands' samples are in interaction, times the
// servo period (s).
double both_in_contact_time(const Recording& rec) {
  std::int64_t ticks = 0;
  bool contact[kHandCount] = {false, false};
  for (std::size_t i = 0; i < rec.samples.size(); ++i) {
    const ToolSample& t = rec.samples[i];
    const std::size_t h = hand_index(t.hand);
    if (h < kHandCount) contact[h] |= in_contact(t);
    if (i + 1 == rec.samples.size() || rec.samples[i + 1].seq != t.seq) {
      if (contact[0] && contact[1]) ++ticks;
      contact[0] = contact[1] = false;
    }
  }
  return seconds(ticks * period_of(rec));
}

void add_two_hands(Metrics& out, const Recording& rec, const HandStreams& hands, const Span& span) {
  const std::string idle_rule = text::format("%g mm/s over %g ms blocks", kIdleSpeed * 1e3, static_cast<double>(kIdleBlockNs) / 1e6);
  double path[kHandCount], economy[kHandCount];
  for (std::size_t h = 0; h < kHandCount; ++h) {
    const std::vector<ToolSample>& s = hands.of(static_cast<Hand>(h));
    const Window w = window_in(s, span);
    path[h] = economy[h] = kNaN;
    if (w.empty()) continue;
    path[h] = path_length(s, w);
    const double straight = norm(s[w.last].tool.position - s[w.first].tool.position);
    economy[h] = std::isfinite(straight) && straight >= kEconomyMinDisplacement ? path[h] / straight : kNaN;
  }
  const std::string path_text = "distance travelled by the tool tip over the task window (sum over the 1 kHz ticks, unfiltered)";
  const std::string economy_text = "path length over the task window / straight distance between the tool tip at the window's first "
                                   "and last ticks (not measured when under " + num_g(kEconomyMinDisplacement * 1e3) + " mm)";
  add(out, "right_path_length_mm", path[0] * 1e3, "mm", Better::kLower, path_text + whose(true, HandScope::kRight), HandScope::kRight);
  add(out, "left_path_length_mm", path[1] * 1e3, "mm", Better::kLower, path_text + whose(true, HandScope::kLeft), HandScope::kLeft);
  add(out, "right_economy_of_motion_ratio", economy[0], "ratio", Better::kLower, economy_text + whose(true, HandScope::kRight),
      HandScope::kRight);
  add(out, "left_economy_of_motion_ratio", economy[1], "ratio", Better::kLower, economy_text + whose(true, HandScope::kLeft),
      HandScope::kLeft);

  const std::vector<ToolSample>& left = hands.of(Hand::kLeft);
  const Window lw = window_in(left, span);
  add(out, "left_idle_time_s", lw.empty() ? kNaN : idle_time(left, lw, span), "s", Better::kLower,
      "time in the task window in which the left hand neither touched the tissue nor moved faster than " + idle_rule +
          " (net displacement over each block from the window's start / its duration; a block with a tick in contact is not idle)" + whose(true, HandScope::kLeft),
      HandScope::kLeft);
  add(out, "both_hands_contact_time_s", rec.samples.empty() ? kNaN : both_in_contact_time(rec), "s", Better::kHigher,
      "ticks at which both tools interact with the tissue at once (the right and the left sample of one seq both in a stage "
      "other than free), times the servo period" + whose(true, HandScope::kBoth),
      HandScope::kBoth);
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

std::string_view hand_scope_key(HandScope h) noexcept {
  switch (h) {
    case HandScope::kRight: return "right";
    case HandScope::kLeft: return "left";
    case HandScope::kBoth: return "both";
    case HandScope::kScene: return "scene";
  }
  return "?";
}

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
  // The samples split by hand; the task window: the right hand's interaction, with two hands
  // widened to the left's, and the right hand's ticks in it.
  const HandStreams hands(rec);
  const bool two = hands.two();
  out.hands = two ? 2 : 1;
  const std::vector<ToolSample>& right = hands.of(Hand::kRight);
  Window w = task_window(right);
  Span span = span_of(right, w);
  if (two) {
    const std::vector<ToolSample>& left = hands.of(Hand::kLeft);
    span = span_union(span, span_of(left, task_window(left)));
    w = window_in(right, span);
  }
  if (span.empty()) {
    out.window_begin_s = out.window_end_s = kNaN;
    out.notes.emplace_back("no tool-tissue interaction: task time, path, movements, jerk and mean force are not measured");
  } else {
    const std::int64_t t0 = rec.samples.front().t_ns;
    out.window_begin_s = seconds(span.begin_ns - t0);
    out.window_end_s = seconds(span.end_ns - t0);
  }
  if (two) {
    out.notes.push_back("two hands: task time, peak force, time above the force limit and the incision are both hands'; path, angle, "
                        "economy of motion, movements, jerk and mean force are the right (dominant) hand's; each hand's own figures "
                        "are under Two hands");
  }
  if (hands.no_hand() > 0) {
    out.notes.push_back(std::to_string(hands.no_hand()) + " samples name no hand and are left out of the per-hand figures");
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

  add_motion(out, right, w, span, s, two);
  add_force(out, rec, right, two);
  if (s != nullptr && s->task == scenario::TaskKind::kIncision) add_incision(out, rec, s->incision, two);
  add_frames(out, rec, s);
  if (two) add_two_hands(out, rec, hands, span);
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
