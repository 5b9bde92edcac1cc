// The HTML and JSON reports. Layout: text helpers (escaping, number formats), the two SVG plots
// (a Plot maps data to pixels and draws the axes), the page's parts, the JSON writer.

#include "score/report.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>
#include <string_view>

#include "text/text.hpp"

namespace lancet::score {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- text --------------------------------------------------------------------------------------



// A value for people: 3 significant digits, whole numbers from 1000 up; "—" when not measured.
std::string shown(double v, std::string_view unit = {}) {
  if (!std::isfinite(v)) return "\u2014";
  if (unit == "count") return text::format("%.0f", v);
  return std::abs(v) >= 1000 ? text::format("%.0f", v) : text::format("%.3g", v);
}

std::string band_text(const Metric& m) {
  if (!m.band) return "";
  const MetricBand& b = *m.band;
  const bool lower = m.better == Better::kLower;
  return std::string(lower ? "\u2264 " : "\u2265 ") + shown(b.limit) + " (" + shown(b.mean) + (lower ? " + " : " \u2212 ") +
         shown(b.k) + "\u00d7" + shown(b.sd) + ")";
}

std::string_view stage_name(Stage s) {
  switch (s) {
    case Stage::kFree: return "free";
    case Stage::kDeform: return "touching";
    case Stage::kRupture: return "rupture";
    case Stage::kCutting: return "cutting";
    case Stage::kPulling: return "pulling";
    case Stage::kDrilling: return "drilling";
  }
  return "?";
}

const char* stage_colour(Stage s) {
  switch (s) {
    case Stage::kFree: return "#9e9e9e";
    case Stage::kDeform: return "#1e88e5";
    case Stage::kRupture:
    case Stage::kCutting: return "#d81b60";
    case Stage::kPulling: return "#43a047";
    case Stage::kDrilling: return "#fb8c00";
  }
  return "#000000";
}

// Which stage a downsampled point shows when its bucket holds several: cutting and drilling
// first, free last, so a short cut is never lost between free ticks.
int stage_rank(Stage s) {
  switch (s) {
    case Stage::kFree: return 0;
    case Stage::kDeform: return 1;
    case Stage::kPulling: return 2;
    case Stage::kRupture: return 3;
    case Stage::kCutting: return 4;
    case Stage::kDrilling: return 4;
  }
  return 0;
}

// ---- hands -------------------------------------------------------------------------------------

// Each hand's colour: the right steel blue, the left amber (as lancet-viz draws the tools).
const char* hand_colour(Hand h) { return h == Hand::kLeft ? "#f29926" : "#4d80f2"; }

bool two_hands(const ReportInput& in) { return in.metrics.hands >= 2; }

// One hand's samples in tick order (a copy).
std::vector<ToolSample> samples_of(const Recording& rec, Hand h) {
  std::vector<ToolSample> out;
  for (const ToolSample& t : rec.samples) {
    if (t.hand == h) out.push_back(t);
  }
  return out;
}

bool is_two_hand_metric(std::string_view name) {
  return std::any_of(scenario::kTwoHandScoreMetrics.begin(), scenario::kTwoHandScoreMetrics.end(),
                     [&](const scenario::ScoreMetricInfo& m) { return m.name == name; });
}

// ---- plots -------------------------------------------------------------------------------------

// A "nice" tick step (1, 2 or 5 times a power of ten) giving about `ticks` ticks over `range`.
double tick_step(double range, int ticks) {
  if (!(range > 0) || !std::isfinite(range)) return 1;
  const double raw = range / ticks;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  for (const double m : {1.0, 2.0, 5.0}) {
    if (m * mag >= raw) return m * mag;
  }
  return 10 * mag;
}

// Maps data (x right, y up) into an SVG of w × h pixels with margins for the axes.
struct Plot {
  double w = 560, h = 400;
  double left = 56, right = 12, top = 12, bottom = 44;
  double x0 = 0, x1 = 1, y0 = 0, y1 = 1;  // data range shown

  [[nodiscard]] double px(double x) const { return left + (x - x0) / (x1 - x0) * (w - left - right); }
  [[nodiscard]] double py(double y) const { return h - bottom - (y - y0) / (y1 - y0) * (h - top - bottom); }
  [[nodiscard]] double scale_x() const { return (w - left - right) / (x1 - x0); }

  // Widens one axis so that a data unit is as long on x as on y.
  void equal_aspect() {
    const double sx = (x1 - x0) / (w - left - right), sy = (y1 - y0) / (h - top - bottom);
    const double s = std::max(sx, sy);
    const double cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
    const double hw = 0.5 * s * (w - left - right), hh = 0.5 * s * (h - top - bottom);
    x0 = cx - hw;
    x1 = cx + hw;
    y0 = cy - hh;
    y1 = cy + hh;
  }

  [[nodiscard]] std::string open(const std::string& label) const {
    return "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + text::format("%.0f", w) + "\" height=\"" + text::format("%.0f", h) +
           "\" viewBox=\"0 0 " + text::format("%.0f", w) + " " + text::format("%.0f", h) + "\" role=\"img\" aria-label=\"" + text::xml_escape(label) + "\">\n";
  }

  // Frame, grid, tick labels and axis titles.
  [[nodiscard]] std::string axes(const std::string& x_title, const std::string& y_title) const {
    std::string s;
    const double sx = tick_step(x1 - x0, 7), sy = tick_step(y1 - y0, 6);
    for (double t = std::ceil(x0 / sx) * sx; t <= x1 + 1e-9 * sx; t += sx) {
      const double x = px(t);
      s += "<line class=\"grid\" x1=\"" + text::format("%.1f", x) + "\" y1=\"" + text::format("%.1f", top) + "\" x2=\"" + text::format("%.1f", x) +
           "\" y2=\"" + text::format("%.1f", h - bottom) + "\"/>";
      s += "<text class=\"tick\" x=\"" + text::format("%.1f", x) + "\" y=\"" + text::format("%.1f", h - bottom + 14) +
           "\" text-anchor=\"middle\">" + text::format("%g", std::abs(t) < 1e-9 * sx ? 0.0 : t) + "</text>\n";
    }
    for (double t = std::ceil(y0 / sy) * sy; t <= y1 + 1e-9 * sy; t += sy) {
      const double y = py(t);
      s += "<line class=\"grid\" x1=\"" + text::format("%.1f", left) + "\" y1=\"" + text::format("%.1f", y) + "\" x2=\"" + text::format("%.1f", w - right) +
           "\" y2=\"" + text::format("%.1f", y) + "\"/>";
      s += "<text class=\"tick\" x=\"" + text::format("%.1f", left - 5) + "\" y=\"" + text::format("%.1f", y + 4) + "\" text-anchor=\"end\">" +
           text::format("%g", std::abs(t) < 1e-9 * sy ? 0.0 : t) + "</text>\n";
    }
    s += "<rect class=\"frame\" x=\"" + text::format("%.1f", left) + "\" y=\"" + text::format("%.1f", top) + "\" width=\"" +
         text::format("%.1f", w - left - right) + "\" height=\"" + text::format("%.1f", h - top - bottom) + "\"/>\n";
    s += "<text class=\"title\" x=\"" + text::format("%.1f", 0.5 * (left + w - right)) + "\" y=\"" + text::format("%.1f", h - 8) +
         "\" text-anchor=\"middle\">" + text::xml_escape(x_title) + "</text>\n";
    s += "<text class=\"title\" transform=\"translate(14 " + text::format("%.1f", 0.5 * (top + h - bottom)) +
         ") rotate(-90)\" text-anchor=\"middle\">" + text::xml_escape(y_title) + "</text>\n";
    return s;
  }

  // A clip rectangle for the data area, named `id`.
  [[nodiscard]] std::string clip(const std::string& id) const {
    return "<defs><clipPath id=\"" + id + "\"><rect x=\"" + text::format("%.1f", left) + "\" y=\"" + text::format("%.1f", top) + "\" width=\"" +
           text::format("%.1f", w - left - right) + "\" height=\"" + text::format("%.1f", h - top - bottom) + "\"/></clipPath></defs>\n";
  }

  [[nodiscard]] std::string point(double x, double y) const { return text::format("%.1f", px(x)) + "," + text::format("%.1f", py(y)) + " "; }
};

struct PathPoint {
  double x = 0, y = 0;  // mm
  Stage stage = Stage::kFree;
};

// The tool tip's path in x-y (mm), at most kMax points (by default kMaxPlotPoints / 2: each run of
// a stage repeats the point before it, so the plot draws at most kMaxPlotPoints), each showing the
// most significant stage of its bucket.
std::vector<PathPoint> path_points(const std::vector<ToolSample>& s, std::size_t kMax = kMaxPlotPoints / 2) {
  std::vector<PathPoint> out;
  if (s.empty()) return out;
  const std::size_t bucket = (s.size() + kMax - 2) / (kMax - 1);  // leaves room for the last tick
  for (std::size_t b = 0; b < s.size(); b += bucket) {
    const std::size_t end = std::min(s.size(), b + bucket);
    Stage stage = s[b].stage;
    for (std::size_t i = b + 1; i < end; ++i) {
      if (stage_rank(s[i].stage) > stage_rank(stage)) stage = s[i].stage;
    }
    const Vec3 p = s[b].tool.position;
    if (is_finite(p)) out.push_back(PathPoint{p.x * 1e3, p.y * 1e3, stage});
  }
  const Vec3 last = s.back().tool.position;
  if ((s.size() - 1) % bucket != 0 && is_finite(last)) out.push_back(PathPoint{last.x * 1e3, last.y * 1e3, s.back().stage});
  return out;
}

// The tool tip's path seen from above: one hand's (paths[0]) coloured by stage, the view on the
// task and the interaction; or with `by_hand` each hand's (paths[h], by Hand) in its colour, the
// view on the task and the whole of both paths.
std::string path_svg(const ReportInput& in, const std::string& id, const std::vector<std::vector<PathPoint>>& paths, bool by_hand) {
  const Metrics& m = in.metrics;
  Plot plot;
  // The view: the task and the interaction (the approach from afar is clipped); everything
  // when there is neither.
  double x0 = kInf, x1 = -kInf, y0 = kInf, y1 = -kInf;
  const auto grow = [&](double x, double y, double r) {
    x0 = std::min(x0, x - r);
    x1 = std::max(x1, x + r);
    y0 = std::min(y0, y - r);
    y1 = std::max(y1, y + r);
  };
  if (m.has_task && m.task == scenario::TaskKind::kIncision) {
    for (const Vec3& p : m.incision.line) grow(p.x * 1e3, p.y * 1e3, m.incision.tolerance * 1e3);
  } else if (m.has_task) {
    grow(m.drill.centre.x * 1e3, m.drill.centre.y * 1e3, m.drill.radius * 1e3);
  }
  // (Each hand's path: all of it, the free motion too.)
  for (const auto& pts : paths) {
    for (const PathPoint& p : pts) {
      if (by_hand || p.stage != Stage::kFree) grow(p.x, p.y, 0);
    }
  }
  if (!std::isfinite(x0)) {
    for (const auto& pts : paths) {
      for (const PathPoint& p : pts) grow(p.x, p.y, 0);
    }
  }
  if (!std::isfinite(x0)) grow(0, 0, 10);
  const double pad = std::max({0.08 * (x1 - x0), 0.08 * (y1 - y0), 2.0});
  plot.x0 = x0 - pad;
  plot.x1 = x1 + pad;
  plot.y0 = y0 - pad;
  plot.y1 = y1 + pad;
  plot.equal_aspect();

  std::string s = plot.open(by_hand ? "both hands' tool paths seen from above" : "tool path seen from above");
  s += plot.clip(id);
  s += plot.axes("x (mm)", "y (mm)");
  s += "<g clip-path=\"url(#" + id + ")\">\n";
  // The task under the path.
  if (m.has_task && m.task == scenario::TaskKind::kIncision && m.incision.line.size() >= 2) {
    std::string line;
    for (const Vec3& p : m.incision.line) line += plot.point(p.x * 1e3, p.y * 1e3);
    s += "<polyline class=\"tolerance\" points=\"" + line + "\" stroke-width=\"" +
         text::format("%.1f", 2 * m.incision.tolerance * 1e3 * plot.scale_x()) + "\"/>\n";
    s += "<polyline class=\"task\" points=\"" + line + "\"/>\n";
  } else if (m.has_task && m.task == scenario::TaskKind::kDrill) {
    const double cx = plot.px(m.drill.centre.x * 1e3), cy = plot.py(m.drill.centre.y * 1e3);
    s += "<circle class=\"task\" cx=\"" + text::format("%.1f", cx) + "\" cy=\"" + text::format("%.1f", cy) + "\" r=\"" +
         text::format("%.1f", m.drill.radius * 1e3 * plot.scale_x()) + "\"/>\n";
    s += "<path class=\"task\" d=\"M" + text::format("%.1f", cx - 5) + " " + text::format("%.1f", cy) + "h10M" + text::format("%.1f", cx) + " " +
         text::format("%.1f", cy - 5) + "v10\"/>\n";
  }
  if (by_hand) {
    // Each hand's path, one polyline in its colour.
    for (std::size_t h = 0; h < paths.size() && h < kHandCount; ++h) {
      std::string line;
      for (const PathPoint& p : paths[h]) line += plot.point(p.x, p.y);
      if (line.empty()) continue;
      s += std::string("<polyline class=\"hand\" stroke=\"") + hand_colour(static_cast<Hand>(h)) + "\" points=\"" + line + "\"/>\n";
    }
    return s + "</g>\n</svg>\n";
  }
  // The path, one polyline per run of the same stage, each starting where the last ended.
  const std::vector<PathPoint>& pts = paths.front();
  for (std::size_t i = 0; i < pts.size();) {
    std::size_t j = i;
    while (j + 1 < pts.size() && pts[j + 1].stage == pts[i].stage) ++j;
    std::string line = i > 0 ? plot.point(pts[i - 1].x, pts[i - 1].y) : std::string();
    for (std::size_t k = i; k <= j; ++k) line += plot.point(pts[k].x, pts[k].y);
    s += std::string("<polyline class=\"") + (pts[i].stage == Stage::kFree ? "free" : "contact") + "\" stroke=\"" +
         stage_colour(pts[i].stage) + "\" points=\"" + line + "\"/>\n";
    i = j + 1;
  }
  s += "</g>\n</svg>\n";
  return s;
}

// The force magnitude of `smp` (one hand's samples, or a one-handed recording's) as polyline
// points, at most 2 · pairs: each bucket keeps its smallest and largest force, in time order, so
// peaks are drawn.
std::string force_line(const Plot& plot, const std::vector<ToolSample>& smp, std::int64_t t0, std::size_t pairs) {
  const auto t_of = [&](std::size_t i) { return static_cast<double>(smp[i].t_ns - t0) / 1e9; };
  std::string line;
  const std::size_t bucket = std::max<std::size_t>(1, (smp.size() + pairs - 1) / pairs);
  for (std::size_t b = 0; b < smp.size(); b += bucket) {
    const std::size_t end = std::min(smp.size(), b + bucket);
    std::size_t lo = b, hi = b;
    double flo = kInf, fhi = -kInf;
    for (std::size_t i = b; i < end; ++i) {
      const double f = norm(smp[i].force);
      if (!std::isfinite(f)) continue;
      if (f < flo) {
        flo = f;
        lo = i;
      }
      if (f > fhi) {
        fhi = f;
        hi = i;
      }
    }
    if (!std::isfinite(flo)) continue;
    if (lo == hi) {
      line += plot.point(t_of(lo), flo);
    } else if (lo < hi) {
      line += plot.point(t_of(lo), flo) + plot.point(t_of(hi), fhi);
    } else {
      line += plot.point(t_of(hi), fhi) + plot.point(t_of(lo), flo);
    }
  }
  return line;
}

// The force on the hand over time; with two hands one line per hand in its colour.
std::string force_svg(const ReportInput& in, const std::string& id) {
  const Recording& rec = *in.recording;
  const Metrics& m = in.metrics;
  const auto& smp = rec.samples;
  Plot plot;
  plot.h = 280;
  const std::int64_t t0 = smp.empty() ? 0 : smp.front().t_ns;
  const auto t_of = [&](std::size_t i) { return static_cast<double>(smp[i].t_ns - t0) / 1e9; };
  double peak = 0;
  for (const ToolSample& t : smp) {
    const double f = norm(t.force);
    if (std::isfinite(f)) peak = std::max(peak, f);
  }
  const double limit = m.score.force_limit;
  plot.x0 = 0;
  plot.x1 = smp.size() > 1 ? std::max(t_of(smp.size() - 1), 1e-3) : 1;
  plot.y0 = 0;
  plot.y1 = std::max({peak, limit, 0.5}) * 1.1;

  std::string s = plot.open("force magnitude over time");
  s += plot.clip(id);
  if (std::isfinite(m.window_begin_s) && std::isfinite(m.window_end_s)) {
    s += "<rect class=\"window\" x=\"" + text::format("%.1f", plot.px(m.window_begin_s)) + "\" y=\"" + text::format("%.1f", plot.top) +
         "\" width=\"" + text::format("%.1f", std::max(1.0, plot.px(m.window_end_s) - plot.px(m.window_begin_s))) + "\" height=\"" +
         text::format("%.1f", plot.h - plot.top - plot.bottom) + "\"/>\n";
  }
  s += plot.axes("time (s)", "force (N)");
  s += "<g clip-path=\"url(#" + id + ")\">\n";
  if (two_hands(in)) {
    for (const Hand h : {Hand::kRight, Hand::kLeft}) {
      s += std::string("<polyline class=\"force\" stroke=\"") + hand_colour(h) + "\" points=\"" +
           force_line(plot, samples_of(rec, h), t0, kMaxPlotPoints / 4) + "\"/>\n";
    }
  } else {
    s += "<polyline class=\"force\" points=\"" + force_line(plot, smp, t0, kMaxPlotPoints / 2) + "\"/>\n";
  }
  s += "</g>\n";
  const double ly = plot.py(limit);
  s += "<line class=\"limit\" x1=\"" + text::format("%.1f", plot.left) + "\" y1=\"" + text::format("%.1f", ly) + "\" x2=\"" +
       text::format("%.1f", plot.w - plot.right) + "\" y2=\"" + text::format("%.1f", ly) + "\"/>\n";
  s += "<text class=\"limit-label\" x=\"" + text::format("%.1f", plot.w - plot.right - 4) + "\" y=\"" + text::format("%.1f", ly - 4) +
       "\" text-anchor=\"end\">limit " + text::xml_escape(shown(limit)) + " N</text>\n";
  s += "</svg>\n";
  return s;
}

// ---- the page ----------------------------------------------------------------------------------

constexpr const char* kStyle = R"(
body { font-family: "DejaVu Sans", Arial, Helvetica, sans-serif; color: #212121; margin: 24px; max-width: 1180px; }
h1 { font-size: 24px; margin: 0 0 4px; }
h2 { font-size: 19px; margin: 28px 0 8px; border-bottom: 1px solid #ccc; padding-bottom: 4px; }
p.sub, p.meta { color: #555; margin: 4px 0; font-size: 13px; }
.verdict { display: inline-block; padding: 6px 14px; border-radius: 4px; font-weight: bold; margin: 8px 0; }
.verdict.pass, td.pass { background: #e8f5e9; color: #1b5e20; }
.verdict.fail, td.fail { background: #ffebee; color: #b71c1c; }
.verdict.na, td.na { background: #f0f0f0; color: #555; }
table { border-collapse: collapse; font-size: 13px; margin: 8px 0; }
th, td { border: 1px solid #d0d0d0; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #f5f5f5; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.desc { color: #555; max-width: 460px; }
.plots { display: flex; flex-wrap: wrap; gap: 16px; align-items: flex-start; }
figure { margin: 0; }
figcaption { font-size: 12px; color: #555; max-width: 560px; }
svg { background: #fff; }
svg .grid { stroke: #eeeeee; stroke-width: 1; }
svg .frame { fill: none; stroke: #9e9e9e; stroke-width: 1; }
svg .tick { font-size: 11px; fill: #616161; }
svg .title { font-size: 12px; fill: #212121; }
svg .free { fill: none; stroke-width: 1; stroke-opacity: 0.7; }
svg .contact { fill: none; stroke-width: 2.2; stroke-linejoin: round; }
svg .task { fill: none; stroke: #3949ab; stroke-width: 1.5; stroke-dasharray: 6 4; }
svg .tolerance { fill: none; stroke: #c5cae9; stroke-opacity: 0.6; stroke-linecap: round; stroke-linejoin: round; }
svg .window { fill: #f3f3f3; }
svg .force { fill: none; stroke: #1e88e5; stroke-width: 1.2; }
svg .limit { stroke: #e53935; stroke-width: 1.2; stroke-dasharray: 5 3; }
svg .limit-label { font-size: 11px; fill: #e53935; }
.swatch { display: inline-block; width: 14px; height: 4px; margin: 0 4px 2px 10px; vertical-align: middle; }
ul.notes { font-size: 13px; color: #555; }
svg .hand { fill: none; stroke-width: 1.8; stroke-linejoin: round; }
h3 { font-size: 16px; margin: 20px 0 6px; }
)";

std::string verdict_html(const Metrics& m) {
  switch (m.verdict) {
    case Verdict::kProficient:
      return "<div class=\"verdict pass\">Proficient: all " + std::to_string(m.banded) + " banded metrics within the experts' bands</div>";
    case Verdict::kNotYet: {
      std::string failed;
      for (const Metric& x : m.metrics) {
        if (x.band && !x.pass) failed += (failed.empty() ? "" : ", ") + x.name;
      }
      return "<div class=\"verdict fail\">Not yet proficient: " + std::to_string(m.banded - m.passed) + " of " +
             std::to_string(m.banded) + " banded metrics outside their bands (" + text::xml_escape(failed) + ")</div>";
    }
    case Verdict::kNotAssessed: break;
  }
  return "<div class=\"verdict na\">Not assessed: no metric has an experts' band (the scenario has no [score.bands])</div>";
}

std::string result_cell(const Metric& m) {
  if (!m.band) return "<td class=\"na\">no band</td>";
  return m.pass ? "<td class=\"pass\">pass</td>" : "<td class=\"fail\">fail</td>";
}

// The metrics table: with `two_hand_metrics` false the shared metrics (with two hands a Hand
// column says whose each is), with it true kTwoHandScoreMetrics, each marked in its hand's colour.
std::string metrics_table(const Metrics& m, bool two_hand_metrics) {
  const bool two = m.hands >= 2;
  std::string s = std::string("<table class=\"") + (two_hand_metrics ? "two-hands" : "metrics") + "\">\n<tr><th>Metric</th>" +
                  (two ? "<th>Hand</th>" : "") + "<th>Value</th><th>Unit</th><th>Band</th><th>Result</th><th>Better</th><th>How it is measured</th></tr>\n";
  for (const Metric& x : m.metrics) {
    if (is_two_hand_metric(x.name) != two_hand_metrics) continue;
    const std::string_view hand = hand_scope_key(x.hand);
    // The name cell is marked in the hand's colour (grey for both).
    const std::string mark = x.hand == HandScope::kRight ? hand_colour(Hand::kRight) : x.hand == HandScope::kLeft ? hand_colour(Hand::kLeft) : "#9e9e9e";
    s += "<tr><td" + (two_hand_metrics ? " style=\"border-left: 5px solid " + mark + "\"" : std::string()) + "><code>" + text::xml_escape(x.name) +
         "</code></td>" + (two ? "<td>" + std::string(hand) + "</td>" : std::string()) + "<td class=\"num\">" +
         text::xml_escape(shown(x.value, x.unit)) + "</td><td>" + text::xml_escape(x.unit) + "</td><td class=\"num\">" +
         text::xml_escape(band_text(x)) + "</td>" + result_cell(x) + "<td>" + (x.better == Better::kLower ? "lower" : "higher") +
         "</td><td class=\"desc\">" + text::xml_escape(x.description) + "</td></tr>\n";
  }
  return s + "</table>\n";
}

// The "Two hands" section: each hand's path from above in its colour, the two-hand metrics, and
// which hand the shared metrics are measured on. Empty for a one-handed recording.
std::string two_hands_html(const ReportInput& in, const std::string& id) {
  if (!two_hands(in)) return "";
  const Recording& rec = *in.recording;
  std::vector<std::vector<PathPoint>> paths;
  for (const Hand h : {Hand::kRight, Hand::kLeft}) paths.push_back(path_points(samples_of(rec, h), kMaxPlotPoints / 2));
  const std::string swatch_right = std::string("<span class=\"swatch\" style=\"background:") + hand_colour(Hand::kRight) + "\"></span>";
  const std::string swatch_left = std::string("<span class=\"swatch\" style=\"background:") + hand_colour(Hand::kLeft) + "\"></span>";
  std::string s = "<section class=\"two-hands\">\n<h3>Two hands</h3>\n";
  s += "<p class=\"meta\">" + swatch_right + "right (dominant) hand" + swatch_left +
       "left hand. In the table above, task time, peak force, time above the force limit and the incision are both hands'; path, "
       "angle, economy of motion, movements, jerk and mean force are the right hand's; damage, blood and drilling are the scene's. "
       "Idle: the left tool tip slower than " +
       text::xml_escape(shown(kIdleSpeed * 1e3)) + " mm/s over " + text::xml_escape(shown(static_cast<double>(kIdleBlockNs) / 1e6)) +
       " ms blocks of the task window.</p>\n";
  s += "<div class=\"plots\">\n<figure>" + path_svg(in, id, paths, true) + "<figcaption>" + swatch_right + "right" + swatch_left +
       "left: each hand's tool tip from above over the whole recording. Axes in mm (world frame).</figcaption></figure>\n</div>\n";
  s += metrics_table(in.metrics, true);
  return s + "</section>\n";
}

std::string comparison_table(const std::vector<ReportInput>& attempts) {
  std::string s = "<h2>Comparison</h2>\n<table class=\"compare\">\n<tr><th>Metric</th><th>Band</th>";
  for (std::size_t i = 0; i < attempts.size(); ++i) {
    s += "<th>" + std::to_string(i + 1) + ": " + text::xml_escape(attempts[i].file) + "</th>";
  }
  s += "</tr>\n<tr><th>verdict</th><td></td>";
  for (const ReportInput& a : attempts) {
    const Verdict v = a.metrics.verdict;
    s += std::string("<td class=\"") + (v == Verdict::kProficient ? "pass" : v == Verdict::kNotYet ? "fail" : "na") + "\">" +
         (v == Verdict::kProficient ? "proficient" : v == Verdict::kNotYet ? "not yet" : "not assessed") + "</td>";
  }
  s += "</tr>\n";
  std::vector<scenario::ScoreMetricInfo> rows(scenario::kScoreMetrics.begin(), scenario::kScoreMetrics.end());
  rows.insert(rows.end(), scenario::kTwoHandScoreMetrics.begin(), scenario::kTwoHandScoreMetrics.end());
  for (const scenario::ScoreMetricInfo& info : rows) {
    const Metric* first = nullptr;
    for (const ReportInput& a : attempts) {
      if (const Metric* x = find_metric(a.metrics, info.name); x != nullptr && first == nullptr) first = x;
    }
    if (first == nullptr) continue;
    // The band column shows one band when all attempts share it.
    std::set<std::string> bands;
    for (const ReportInput& a : attempts) {
      if (const Metric* x = find_metric(a.metrics, info.name)) bands.insert(band_text(*x));
    }
    s += "<tr><td><code>" + text::xml_escape(info.name) + "</code> (" + text::xml_escape(first->unit) + ")</td><td class=\"num\">" +
         text::xml_escape(bands.size() == 1 ? *bands.begin() : "varies") + "</td>";
    for (const ReportInput& a : attempts) {
      const Metric* x = find_metric(a.metrics, info.name);
      if (x == nullptr) {
        s += "<td class=\"na\"></td>";
        continue;
      }
      const char* cls = !x->band ? "na num" : x->pass ? "pass num" : "fail num";
      s += std::string("<td class=\"") + cls + "\">" + text::xml_escape(shown(x->value, x->unit)) + "</td>";
    }
    s += "</tr>\n";
  }
  return s + "</table>\n";
}

// The stages the recording has (free always), each with its colour.
std::string legend(const std::vector<ToolSample>& samples) {
  bool seen[6] = {true, false, false, false, false, false};
  for (const ToolSample& t : samples) {
    const auto i = static_cast<std::size_t>(t.stage);
    if (i < 6) seen[i] = true;
  }
  seen[static_cast<std::size_t>(Stage::kCutting)] |= seen[static_cast<std::size_t>(Stage::kRupture)];  // one colour
  std::string s = "Tool tip from above, coloured by stage:";
  for (const Stage st : {Stage::kFree, Stage::kDeform, Stage::kCutting, Stage::kPulling, Stage::kDrilling}) {
    if (!seen[static_cast<std::size_t>(st)]) continue;
    s += std::string("<span class=\"swatch\" style=\"background:") + stage_colour(st) + "\"></span>" + std::string(stage_name(st));
  }
  return s;
}

std::string attempt_html(const ReportInput& in, std::size_t index, bool several) {
  const Recording& rec = *in.recording;
  const Metrics& m = in.metrics;
  const std::string id = "a" + std::to_string(index);
  std::string s = "<section class=\"attempt\">\n<h2>" +
                  (several ? "Attempt " + std::to_string(index + 1) + ": " : std::string("Attempt: ")) + text::xml_escape(in.file) + "</h2>\n";
  s += verdict_html(m) + "\n";
  const double duration = rec.samples.size() > 1 ? static_cast<double>(rec.samples.back().t_ns - rec.samples.front().t_ns) / 1e9 : 0;
  const bool two = two_hands(in);
  s += "<p class=\"meta\">Scenario " + text::xml_escape(rec.scenario_name.empty() ? "(none)" : rec.scenario_name) + " \u00b7 recorded " +
       text::xml_escape(rec.created.empty() ? "(unknown)" : rec.created) + " \u00b7 " + text::xml_escape(shown(duration)) + " s, " +
       std::to_string(rec.samples.size()) + (two ? " samples of two hands, " : " ticks, ") + std::to_string(rec.frames.size()) +
       " frames \u00b7 lancet " +
       text::xml_escape(rec.lancet_version.empty() ? "(unknown)" : rec.lancet_version) + "</p>\n";
  s += "<p class=\"meta\">Task window " +
       (std::isfinite(m.window_begin_s) ? text::xml_escape(shown(m.window_begin_s)) + "\u2013" + text::xml_escape(shown(m.window_end_s)) + " s"
                                        : std::string("none (no interaction)")) +
       " \u00b7 force limit " + text::xml_escape(shown(m.score.force_limit)) + " N \u00b7 movements: speed above " +
       text::xml_escape(shown(m.score.movement_speed * 1e3)) + " mm/s after a first-order low-pass at " + text::xml_escape(shown(m.score.movement_filter_hz)) +
       " Hz \u00b7 bands: mean \u00b1 " + text::xml_escape(shown(m.score.sd_multiple)) + " sd, one-sided by direction";
  if (!m.damaged.empty()) {
    std::string names;
    for (const auto& n : m.damaged) names += (names.empty() ? "" : ", ") + text::xml_escape(n);
    s += " \u00b7 <strong>damaged: " + names + "</strong>";
  }
  s += "</p>\n";
  std::string task_caption = "no task (no scenario)";
  if (m.has_task && m.task == scenario::TaskKind::kIncision) {
    task_caption = "dashed: the planned incision line, shaded: its tolerance (\u00b1" + shown(m.incision.tolerance * 1e3) + " mm)";
  } else if (m.has_task) {
    task_caption = "dashed: the drill window (" + shown(2 * m.drill.radius * 1e3) + " mm across)";
  }
  // With two hands the stage-coloured path is the right hand's; both are drawn under Two hands.
  const std::vector<ToolSample> right = two ? samples_of(rec, Hand::kRight) : std::vector<ToolSample>();
  const std::vector<ToolSample>& path_samples = two ? right : rec.samples;
  s += "<div class=\"plots\">\n<figure>" + path_svg(in, id + "-path", {path_points(path_samples)}, false) + "<figcaption>" +
       (two ? "Right hand. " : "") + legend(path_samples) + ". " + text::xml_escape(task_caption) +
       ". Axes in mm (world frame, x along the limb).</figcaption></figure>\n";
  s += "<figure>" + force_svg(in, id + "-force") + "<figcaption>Force magnitude on the hand" +
       (two ? std::string(" (each hand in its colour: <span class=\"swatch\" style=\"background:") + hand_colour(Hand::kRight) +
                  "\"></span>right<span class=\"swatch\" style=\"background:" + hand_colour(Hand::kLeft) + "\"></span>left)"
            : std::string()) +
       "; dashed red: the force limit; grey: the task window.</figcaption></figure>\n</div>\n";
  s += metrics_table(m, false);
  s += two_hands_html(in, id + "-hands");
  if (!m.notes.empty()) {
    s += "<ul class=\"notes\">\n";
    for (const auto& n : m.notes) s += "<li>" + text::xml_escape(n) + "</li>\n";
    s += "</ul>\n";
  }
  return s + "</section>\n";
}

// ---- JSON --------------------------------------------------------------------------------------



// The "two_hands" object (null for one hand): each hand's figures by hand, both hands' contact
// time, the colours and the idle rule. The same values are in "metrics".
std::string json_two_hands(const Metrics& m) {
  if (m.hands < 2) return "null";
  const auto value = [&](std::string_view name) {
    const Metric* x = find_metric(m, name);
    return text::json_number(x ? x->value : std::numeric_limits<double>::quiet_NaN());
  };
  return "{\"dominant\": \"right\", \"right\": {\"colour\": \"" + std::string(hand_colour(Hand::kRight)) +
         "\", \"path_length_mm\": " + value("right_path_length_mm") + ", \"economy_of_motion_ratio\": " +
         value("right_economy_of_motion_ratio") + "}, \"left\": {\"colour\": \"" + hand_colour(Hand::kLeft) + "\", \"path_length_mm\": " +
         value("left_path_length_mm") + ", \"economy_of_motion_ratio\": " + value("left_economy_of_motion_ratio") +
         ", \"idle_time_s\": " + value("left_idle_time_s") + "}, \"both_hands_contact_time_s\": " + value("both_hands_contact_time_s") +
         ", \"idle_speed_mm_s\": " + text::json_number(kIdleSpeed * 1e3) +
         ", \"idle_block_ms\": " + text::json_number(static_cast<double>(kIdleBlockNs) / 1e6) + "}";
}

std::string json_attempt(const ReportInput& in) {
  const Recording& rec = *in.recording;
  const Metrics& m = in.metrics;
  const double duration = rec.samples.size() > 1 ? static_cast<double>(rec.samples.back().t_ns - rec.samples.front().t_ns) / 1e9 : 0;
  std::string s = "    {\n";
  s += "      \"file\": " + text::json_string(in.file) + ",\n";
  s += "      \"scenario\": " + text::json_string(rec.scenario_name) + ",\n";
  s += "      \"created\": " + text::json_string(rec.created) + ",\n";
  s += "      \"lancet_version\": " + text::json_string(rec.lancet_version) + ",\n";
  s += "      \"task\": " + (m.has_task ? text::json_string(scenario::task_key(m.task)) : std::string("null")) + ",\n";
  s += "      \"duration_s\": " + text::json_number(duration) + ",\n";
  s += "      \"samples\": " + std::to_string(rec.samples.size()) + ",\n";
  s += "      \"hands\": " + std::to_string(m.hands) + ",\n";
  s += "      \"frames\": " + std::to_string(rec.frames.size()) + ",\n";
  s += "      \"samples_lost\": " + std::to_string(rec.samples_lost) + ",\n";
  s += std::string("      \"cut_short\": ") + (rec.cut_short ? "true" : "false") + ",\n";
  s += "      \"window_s\": [" + text::json_number(m.window_begin_s) + ", " + text::json_number(m.window_end_s) + "],\n";
  s += "      \"settings\": {\"force_limit_n\": " + text::json_number(m.score.force_limit) +
       ", \"movement_speed_mm_s\": " + text::json_number(m.score.movement_speed * 1e3) +
       ", \"movement_filter_hz\": " + text::json_number(m.score.movement_filter_hz) +
       ", \"sd_multiple\": " + text::json_number(m.score.sd_multiple) + "},\n";
  s += "      \"verdict\": " + text::json_string(verdict_key(m.verdict)) + ",\n";
  s += "      \"proficient\": " + std::string(m.verdict == Verdict::kProficient ? "true" : "false") + ",\n";
  s += "      \"banded\": " + std::to_string(m.banded) + ",\n";
  s += "      \"passed\": " + std::to_string(m.passed) + ",\n";
  s += "      \"damaged\": [";
  for (std::size_t i = 0; i < m.damaged.size(); ++i) s += (i ? ", " : "") + text::json_string(m.damaged[i]);
  s += "],\n      \"notes\": [";
  for (std::size_t i = 0; i < m.notes.size(); ++i) s += (i ? ", " : "") + text::json_string(m.notes[i]);
  s += "],\n      \"metrics\": {";
  for (std::size_t i = 0; i < m.metrics.size(); ++i) {
    const Metric& x = m.metrics[i];
    s += std::string(i ? "," : "") + "\n        " + text::json_string(x.name) + ": {\"value\": " + text::json_number(x.value) +
         ", \"unit\": " + text::json_string(x.unit) + ", \"better\": " + (x.better == Better::kLower ? "\"lower\"" : "\"higher\"") +
         ", \"band\": ";
    if (x.band) {
      s += "{\"mean\": " + text::json_number(x.band->mean) + ", \"sd\": " + text::json_number(x.band->sd) + ", \"k\": " +
           text::json_number(x.band->k) + ", \"limit\": " + text::json_number(x.band->limit) + "}, \"pass\": " + (x.pass ? "true" : "false");
    } else {
      s += "null, \"pass\": null";
    }
    s += ", \"hand\": " + text::json_string(hand_scope_key(x.hand));
    s += ", \"description\": " + text::json_string(x.description) + "}";
  }
  s += "\n      },\n      \"two_hands\": " + json_two_hands(m) + "\n    }";
  return s;
}

}  // namespace

std::string report_html(const std::vector<ReportInput>& attempts) {
  assert(!attempts.empty() && "report_html: no attempts");
  for ([[maybe_unused]] const ReportInput& a : attempts) assert(a.recording != nullptr && "report_html: null recording");
  // The title names each scenario once and the first recording's date.
  std::string scenarios;
  std::set<std::string> seen;
  for (const ReportInput& a : attempts) {
    const std::string n = a.recording->scenario_name.empty() ? std::string("no scenario") : a.recording->scenario_name;
    if (seen.insert(n).second) scenarios += (scenarios.empty() ? "" : ", ") + n;
  }
  const std::string& created = attempts.front().recording->created;
  const std::string date = created.size() >= 10 ? created.substr(0, 10) : created;
  const std::string title = "Lancet report: " + scenarios + (date.empty() ? "" : ", " + date);

  std::string s = "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>" + text::xml_escape(title) +
                  "</title>\n<style>" + kStyle + "</style>\n</head>\n<body>\n";
  s += "<h1>" + text::xml_escape(title) + "</h1>\n";
  s += "<p class=\"sub\">" + std::to_string(attempts.size()) + (attempts.size() == 1 ? " attempt" : " attempts") +
       ". A metric passes when it is on the good side of mean \u00b1 k\u00b7sd of its experts' band (the scenario's "
       "[score.bands]; see the scenario file for where its bands come from); proficient means every banded metric passes.</p>\n";
  if (attempts.size() > 1) s += comparison_table(attempts);
  for (std::size_t i = 0; i < attempts.size(); ++i) s += attempt_html(attempts[i], i, attempts.size() > 1);
  s += "<p class=\"sub\">Written by lancet-report.</p>\n</body>\n</html>\n";
  return s;
}

std::string report_json(const std::vector<ReportInput>& attempts) {
  std::string s = "{\n  \"format\": \"lancet-report\",\n  \"version\": 1,\n  \"attempts\": [";
  for (std::size_t i = 0; i < attempts.size(); ++i) {
    assert(attempts[i].recording != nullptr && "report_json: null recording");
    s += std::string(i ? ",\n" : "\n") + json_attempt(attempts[i]);
  }
  s += attempts.empty() ? "]\n}\n" : "\n  ]\n}\n";
  return s;
}

}  // namespace lancet::score
