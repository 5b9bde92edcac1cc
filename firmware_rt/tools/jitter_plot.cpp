#include "tools/jitter_plot.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <string_view>

#include "text/text.hpp"

namespace lancet::tools {
namespace {

// ---------------------------------------------------------------------------------------------
// Text

// Fixed-point number, locale-independent (coordinates must never come out as "12,5"); 0 for
// what is not finite.
std::string num(double v, int decimals = 1) { return text::fixed(std::isfinite(v) ? v : 0.0, decimals); }
using text::xml_escape;

// A latency for people: "0.12 µs", "5.6 µs", "65 µs", "1.80 ms", "13.0 ms", "250 ms", "1.20 s".
std::string fmt_us(double us) {
  if (!std::isfinite(us)) return "?";
  if (us < 1) return num(us, 2) + " µs";
  if (us < 10) return num(us, 1) + " µs";
  if (us < 1e3) return num(us, 0) + " µs";
  if (us < 1e4) return num(us / 1e3, 2) + " ms";
  if (us < 1e5) return num(us / 1e3, 1) + " ms";
  if (us < 1e6) return num(us / 1e3, 0) + " ms";
  return num(us / 1e6, 2) + " s";
}

// A decade tick of the latency axis: 1 µs, 10 µs, 100 µs, 1 ms, ..., 10 s.
std::string decade_us_label(int k) {
  static constexpr const char* kUnits[] = {"µs", "ms", "s"};
  if (k < 0) return num(std::pow(10.0, k), -k) + " µs";
  const int unit = std::min(k / 3, 2);
  return num(std::pow(10.0, k - 3 * unit), 0) + " " + kUnits[unit];
}

// A decade tick of a count axis: 0.01, 0.1, 1, 10, 100, 1k, 10k, 100k, 1M, ...
std::string decade_count_label(int k) {
  if (k < 0) return num(std::pow(10.0, k), -k);
  static constexpr const char* kSuffix[] = {"", "k", "M", "G", "T"};
  const int s = std::min(k / 3, 4);
  return num(std::pow(10.0, k - 3 * s), 0) + kSuffix[s];
}

std::string group_digits(std::uint64_t n) {
  std::string s = std::to_string(n), out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (i != 0 && (s.size() - i) % 3 == 0) out += ' ';
    out += s[i];
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Geometry

constexpr double kWidth = 1100, kHeight = 860;
constexpr double kPlotLeft = 90, kPlotRight = 790;        // both panels
constexpr double kTopY0 = 70, kTopY1 = 440;                // histogram panel
constexpr double kBottomY0 = 530, kBottomY1 = 780;         // time panel
constexpr double kLegendX = 815;
constexpr int kBinsPerDecade = 20;
constexpr double kLinearDecades = 0.5;  // screen width of the linear [0, 1) µs part, in decades

constexpr std::array<const char*, 10> kPalette = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e",
                                                  "#8c564b", "#e377c2", "#17becf", "#7f7f7f", "#bcbd22"};

struct Marker {
  double p;
  const char* label;
  const char* dash;
};
constexpr std::array<Marker, 3> kMarkers = {{{50.0, "p50", "2,3"}, {99.0, "p99", "7,3"}, {99.9, "p99.9", "12,3,2,3"}}};

// Latency axis: x = f(µs), linear over [0, 1) then log10 up to 10^log_hi.
struct LatencyAxis {
  double log_hi = 1;
  [[nodiscard]] double u(double us) const {  // axis units: decades, the linear part below 0
    if (!(us > 0)) return -kLinearDecades;
    if (us < 1) return -kLinearDecades * (1 - us);
    return std::min(std::log10(us), log_hi);
  }
  [[nodiscard]] double x(double us) const {
    return kPlotLeft + (u(us) + kLinearDecades) / (log_hi + kLinearDecades) * (kPlotRight - kPlotLeft);
  }
};

// Log axis of positive values onto [y_bottom, y_top] over decades [lo, hi].
struct LogY {
  int lo = 0, hi = 1;
  double y_bottom = 0, y_top = 0;
  [[nodiscard]] double y(double v) const {
    const double l = v > 0 ? std::clamp(std::log10(v), static_cast<double>(lo), static_cast<double>(hi)) : lo;
    return y_bottom - (l - lo) / (hi - lo) * (y_bottom - y_top);
  }
};

LogY log_y_for(double min_positive, double max_value, double y_bottom, double y_top, int lowest_decade) {
  LogY a;
  a.y_bottom = y_bottom;
  a.y_top = y_top;
  if (!(max_value > 0)) return a;
  // The floor a decade under the smallest value's, so that value (e.g. a single sample) stands
  // above the floor rather than on it.
  a.lo = std::max(lowest_decade, static_cast<int>(std::ceil(std::log10(min_positive) - 1e-9)) - 1);
  a.hi = static_cast<int>(std::floor(std::log10(max_value))) + 1;  // headroom above the largest
  if (a.hi <= a.lo) a.hi = a.lo + 1;
  return a;
}

// The smallest of 1, 2, 5 × 10^k that is >= v.
double nice_ceil(double v) {
  const double e = std::pow(10.0, std::floor(std::log10(v)));
  for (const double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * e >= v * (1 - 1e-12)) return m * e;
  }
  return 10 * e;
}

// Bucket width assumed for the bucket with this lower edge: LatencyHistogram's grid (1 µs below
// 1 ms, then 10, 100, 1000 µs per decade); cyclictest's 1 µs buckets agree below 1 ms, and above
// it the next bucket's edge bounds the width.
double grid_width_us(double edge) {
  return edge < 1e3 ? 1 : edge < 1e4 ? 10 : edge < 1e5 ? 100 : 1000;
}

// Samples per display bin: bin 0 = [0, 1) µs, bin 1 + j = [10^(j/20), 10^((j+1)/20)) µs.
std::vector<double> display_bins(const rt::Distribution& d, int n_log_bins) {
  std::vector<double> bins(static_cast<std::size_t>(n_log_bins) + 1, 0.0);
  auto bin_lo = [](std::size_t b) { return b == 0 ? 0.0 : std::pow(10.0, static_cast<double>(b - 1) / kBinsPerDecade); };
  auto bin_of = [&](double us) -> std::size_t {
    if (us < 1) return 0;
    const auto j = static_cast<long>(std::floor(std::log10(us) * kBinsPerDecade + 1e-9));
    return static_cast<std::size_t>(std::clamp<long>(j, 0, n_log_bins - 1)) + 1;
  };
  for (std::size_t i = 0; i < d.buckets.size(); ++i) {
    const double lo = d.buckets[i].first;
    const auto n = static_cast<double>(d.buckets[i].second);
    if (!std::isfinite(lo) || lo < 0 || n <= 0) continue;
    double width = grid_width_us(lo);
    if (i + 1 < d.buckets.size() && d.buckets[i + 1].first > lo) width = std::min(width, d.buckets[i + 1].first - lo);
    const double hi = lo + width;
    // Spread n evenly over [lo, hi) across the bins it overlaps (from one bin early, against
    // rounding in bin_of).
    for (std::size_t b = bin_of(lo) == 0 ? 0 : bin_of(lo) - 1; b < bins.size(); ++b) {
      const double b_lo = bin_lo(b), b_hi = b + 1 < bins.size() ? bin_lo(b + 1) : INFINITY;
      if (b_lo >= hi) break;
      const double overlap = std::min(hi, b_hi) - std::max(lo, b_lo);
      if (overlap > 0) bins[b] += n * overlap / width;
    }
  }
  return bins;
}

// ---------------------------------------------------------------------------------------------
// Drawing

class Svg {
 public:
  std::ostringstream o;
  void line(double x1, double y1, double x2, double y2, const std::string& stroke, double width = 1,
            const char* dash = nullptr, double opacity = 1) {
    o << "<line x1=\"" << num(x1) << "\" y1=\"" << num(y1) << "\" x2=\"" << num(x2) << "\" y2=\"" << num(y2)
      << "\" stroke=\"" << stroke << "\" stroke-width=\"" << num(width, 2) << '"';
    if (dash != nullptr) o << " stroke-dasharray=\"" << dash << '"';
    if (opacity < 1) o << " stroke-opacity=\"" << num(opacity, 2) << '"';
    o << "/>\n";
  }
  // text is escaped here; anchor: start, middle, end.
  void text(double x, double y, std::string_view s, const char* anchor = "start", double size = 12,
            const std::string& fill = "#222", const char* extra = "") {
    o << "<text x=\"" << num(x) << "\" y=\"" << num(y) << "\" font-size=\"" << num(size, 0) << "\" text-anchor=\""
      << anchor << "\" fill=\"" << fill << '"' << extra << '>' << xml_escape(s) << "</text>\n";
  }
};

void frame(Svg& s, double y0, double y1) {
  s.o << "<rect x=\"" << num(kPlotLeft) << "\" y=\"" << num(y0) << "\" width=\"" << num(kPlotRight - kPlotLeft)
      << "\" height=\"" << num(y1 - y0) << "\" fill=\"none\" stroke=\"#444\" stroke-width=\"1\"/>\n";
}

void log_y_ticks(Svg& s, const LogY& a, bool counts) {
  for (int k = a.lo; k <= a.hi; ++k) {
    const double y = a.y(std::pow(10.0, k));
    if (k > a.lo && k < a.hi) s.line(kPlotLeft, y, kPlotRight, y, "#ddd", 1);
    s.line(kPlotLeft - 5, y, kPlotLeft, y, "#444");
    s.text(kPlotLeft - 8, y + 4, counts ? decade_count_label(k) : decade_us_label(k), "end", 11);
    for (int m = 2; m <= 9 && k < a.hi; ++m) {
      const double ym = a.y(m * std::pow(10.0, k));
      s.line(kPlotLeft - 3, ym, kPlotLeft, ym, "#444", 0.8);
    }
  }
}

void histogram_panel(Svg& s, const std::vector<rt::Distribution>& dists, const std::vector<std::string>& colours) {
  double largest = 10;
  std::uint64_t samples = 0;
  for (const auto& d : dists) {
    if (d.count == 0) continue;
    samples += d.count;
    for (const double v : {d.max_us, d.percentile_us(99.9)}) {
      if (std::isfinite(v)) largest = std::max(largest, v);
    }
    if (!d.buckets.empty() && std::isfinite(d.buckets.back().first)) largest = std::max(largest, d.buckets.back().first + 1);
  }
  largest = std::min(largest, 1e9);  // 1000 s: beyond any sensible run
  LatencyAxis ax;
  ax.log_hi = std::log10(nice_ceil(largest));
  const int n_log_bins = static_cast<int>(std::ceil(ax.log_hi * kBinsPerDecade - 1e-9));

  std::vector<std::vector<double>> bins;
  double lo_pos = INFINITY, hi_val = 0;
  for (const auto& d : dists) {
    bins.push_back(display_bins(d, n_log_bins));
    for (const double v : bins.back()) {
      if (v > 0) {
        lo_pos = std::min(lo_pos, v);
        hi_val = std::max(hi_val, v);
      }
    }
  }
  const LogY ay = log_y_for(lo_pos, hi_val, kTopY1, kTopY0 + 6, -1);

  frame(s, kTopY0, kTopY1);
  // x ticks: 0 at the left, the linear/log seam at 1 µs, decades, unlabelled 2..9 in between.
  s.line(ax.x(0), kTopY1, ax.x(0), kTopY1 + 5, "#444");
  s.text(ax.x(0), kTopY1 + 18, "0", "middle", 11);
  s.line(ax.x(0.5), kTopY1, ax.x(0.5), kTopY1 + 3, "#444", 0.8);
  s.line(ax.x(1), kTopY0, ax.x(1), kTopY1, "#bbb", 1, "1,3");
  const int top_decade = static_cast<int>(std::floor(ax.log_hi + 1e-9));
  for (int k = 0; k <= top_decade; ++k) {
    const double x = ax.x(std::pow(10.0, k));
    if (k > 0) s.line(x, kTopY0, x, kTopY1, "#eee", 1);
    s.line(x, kTopY1, x, kTopY1 + 5, "#444");
    s.text(x, kTopY1 + 18, decade_us_label(k), "middle", 11);
    for (int m = 2; m <= 9; ++m) {
      const double v = m * std::pow(10.0, k);
      if (std::log10(v) > ax.log_hi + 1e-9) break;
      s.line(ax.x(v), kTopY1, ax.x(v), kTopY1 + 3, "#444", 0.8);
    }
  }
  if (ax.log_hi - top_decade > 1e-6) {  // the end of the axis when it is not a decade
    s.line(kPlotRight, kTopY1, kPlotRight, kTopY1 + 5, "#444");
    s.text(kPlotRight, kTopY1 + 18, fmt_us(std::pow(10.0, ax.log_hi)), "middle", 11);
  }
  s.text((kPlotLeft + kPlotRight) / 2, kTopY1 + 38, "wake-up latency (linear below 1 µs, log above)", "middle", 12);
  s.text(22, (kTopY0 + kTopY1) / 2, "samples per bin (20 bins per decade)", "middle", 12, "#222",
         (" transform=\"rotate(-90 22 " + num((kTopY0 + kTopY1) / 2) + ")\"").c_str());

  if (samples == 0) {
    s.text((kPlotLeft + kPlotRight) / 2, (kTopY0 + kTopY1) / 2, "no samples", "middle", 16, "#888");
    return;
  }
  log_y_ticks(s, ay, true);

  // Step lines, from the first to the last non-empty bin, dropping to the floor across empty ones.
  auto bin_x = [&](std::size_t b) { return b == 0 ? ax.x(0) : ax.x(std::pow(10.0, static_cast<double>(b - 1) / kBinsPerDecade)); };
  for (std::size_t i = 0; i < dists.size(); ++i) {
    const auto& v = bins[i];
    const auto first = std::find_if(v.begin(), v.end(), [](double c) { return c > 0; });
    if (first == v.end()) continue;
    const auto last = std::find_if(v.rbegin(), v.rend(), [](double c) { return c > 0; });
    const auto b0 = static_cast<std::size_t>(first - v.begin());
    const auto b1 = static_cast<std::size_t>(v.rend() - last);  // one past the last
    std::string path = "M" + num(bin_x(b0)) + " " + num(kTopY1);
    for (std::size_t b = b0; b < b1; ++b) {
      const double xr = b + 1 < v.size() ? bin_x(b + 1) : kPlotRight;
      path += " V" + num(v[b] > 0 ? ay.y(v[b]) : kTopY1) + " H" + num(xr);
    }
    path += " V" + num(kTopY1);
    s.o << "<path d=\"" << path << "\" fill=\"" << colours[i] << "\" fill-opacity=\"0.07\" stroke=\"" << colours[i]
        << "\" stroke-width=\"1.6\" stroke-linejoin=\"miter\"/>\n";
  }

  // Percentile markers, labelled at the top, staggered so two distributions do not overwrite.
  for (std::size_t i = 0; i < dists.size(); ++i) {
    if (dists[i].count == 0) continue;
    for (std::size_t m = 0; m < kMarkers.size(); ++m) {
      const double x = ax.x(dists[i].percentile_us(kMarkers[m].p));
      s.line(x, kTopY0, x, kTopY1, colours[i], 1.3, kMarkers[m].dash, 0.85);
      const double y = kTopY0 + 12 + 11.0 * static_cast<double>(m + kMarkers.size() * i);
      s.text(x + 3, y, kMarkers[m].label, "start", 10, colours[i]);
    }
  }
}

void time_panel(Svg& s, const std::vector<TimeSeries>& series, const std::vector<std::string>& colours) {
  double t_end = 0, lo_pos = INFINITY, hi_val = 0;
  for (const auto& ts : series) {
    if (!(ts.window_s > 0) || !std::isfinite(ts.window_s)) continue;
    t_end = std::max(t_end, ts.window_s * static_cast<double>(ts.max_us.size()));
    for (const double v : ts.max_us) {
      if (v > 0 && std::isfinite(v)) {
        lo_pos = std::min(lo_pos, v);
        hi_val = std::max(hi_val, v);
      }
    }
  }
  frame(s, kBottomY0, kBottomY1);
  s.text((kPlotLeft + kPlotRight) / 2, kBottomY1 + 38, "time (s)", "middle", 12);
  s.text(22, (kBottomY0 + kBottomY1) / 2, "worst latency per window", "middle", 12, "#222",
         (" transform=\"rotate(-90 22 " + num((kBottomY0 + kBottomY1) / 2) + ")\"").c_str());
  if (!(hi_val > 0) || !(t_end > 0)) {
    s.text((kPlotLeft + kPlotRight) / 2, (kBottomY0 + kBottomY1) / 2, "no time series", "middle", 16, "#888");
    return;
  }
  const LogY ay = log_y_for(lo_pos, hi_val, kBottomY1, kBottomY0 + 6, -3);
  log_y_ticks(s, ay, false);

  // x ticks every 1, 2 or 5 × 10^k s, about 5 to 10 of them.
  const double step = nice_ceil(t_end / 10);
  auto tx = [&](double t) { return kPlotLeft + t / t_end * (kPlotRight - kPlotLeft); };
  const int decimals = step >= 1 ? 0 : static_cast<int>(std::ceil(-std::log10(step) - 1e-9));
  for (int k = 0; k * step <= t_end * (1 + 1e-9); ++k) {
    const double x = tx(k * step);
    if (k > 0) s.line(x, kBottomY0, x, kBottomY1, "#eee", 1);
    s.line(x, kBottomY1, x, kBottomY1 + 5, "#444");
    s.text(x, kBottomY1 + 18, num(k * step, decimals), "middle", 11);
  }

  // One step line per series; a window without a value breaks the line.
  for (std::size_t i = 0; i < series.size(); ++i) {
    const auto& ts = series[i];
    if (!(ts.window_s > 0) || !std::isfinite(ts.window_s)) continue;
    std::string path;
    bool open = false;
    for (std::size_t w = 0; w < ts.max_us.size(); ++w) {
      const double v = ts.max_us[w];
      if (!(v > 0) || !std::isfinite(v)) {
        open = false;
        continue;
      }
      const double x0 = tx(ts.window_s * static_cast<double>(w)), x1 = tx(ts.window_s * static_cast<double>(w + 1));
      path += (open ? " V" + num(ay.y(v)) : (path.empty() ? "M" : " M") + num(x0) + " " + num(ay.y(v))) + " H" + num(x1);
      open = true;
    }
    if (path.empty()) continue;
    s.o << "<path d=\"" << path << "\" fill=\"none\" stroke=\"" << colours[i] << "\" stroke-width=\"1.3\"/>\n";
  }
}

// A percentile for the legend; one whose rank falls among the overflows (where
// Distribution::percentile_us answers max_us) reads "> <range end>".
std::string percentile_text(const rt::Distribution& d, double p) {
  const double rank = std::max(1.0, std::ceil(p / 100.0 * static_cast<double>(d.count)));
  if (d.overflows != 0 && d.overflow_above_us > 0 && rank > static_cast<double>(d.count - d.overflows)) {
    return "> " + fmt_us(d.overflow_above_us);
  }
  return fmt_us(d.percentile_us(p));
}

void legend(Svg& s, const std::vector<rt::Distribution>& dists, const std::vector<std::string>& dist_colours,
            const std::vector<TimeSeries>& series, const std::vector<std::string>& series_colours) {
  double y = kTopY0 + 4;
  for (std::size_t i = 0; i < dists.size(); ++i) {
    const auto& d = dists[i];
    s.line(kLegendX, y, kLegendX + 22, y, dist_colours[i], 3);
    s.text(kLegendX + 28, y + 4, d.name.empty() ? "(unnamed)" : d.name, "start", 13, "#222", " font-weight=\"bold\"");
    y += 17;
    std::vector<std::string> rows;
    if (d.count == 0) {
      rows.emplace_back("no samples");
    } else {
      rows.push_back("n = " + group_digits(d.count) + ", min " + fmt_us(d.min_us));
      rows.push_back("avg " + fmt_us(d.avg_us) + ", max " + fmt_us(d.max_us));
      rows.push_back("p50 " + percentile_text(d, 50) + ", p99 " + percentile_text(d, 99));
      rows.push_back("p99.9 " + percentile_text(d, 99.9));
      if (d.overflows != 0) {
        rows.push_back(group_digits(d.overflows) + " overflow" + (d.overflows == 1 ? "" : "s") +
                       (d.overflow_above_us > 0 ? " (above " + fmt_us(d.overflow_above_us) + ")" : ""));
      }
    }
    for (const auto& r : rows) {
      s.text(kLegendX + 28, y + 4, r, "start", 11, "#333");
      y += 15;
    }
    y += 10;
  }
  // What the marker dashes mean.
  if (!dists.empty()) {
    s.text(kLegendX, y + 4, "markers:", "start", 11, "#333");
    y += 16;
    for (const auto& m : kMarkers) {
      s.line(kLegendX + 4, y, kLegendX + 40, y, "#333", 1.3, m.dash);
      s.text(kLegendX + 46, y + 4, m.label, "start", 11, "#333");
      y += 15;
    }
  }
  // Series, beside the bottom panel.
  y = kBottomY0 + 4;
  for (std::size_t i = 0; i < series.size(); ++i) {
    const auto& ts = series[i];
    double worst = 0;
    for (const double v : ts.max_us) {
      if (std::isfinite(v)) worst = std::max(worst, v);
    }
    s.line(kLegendX, y, kLegendX + 22, y, series_colours[i], 3);
    s.text(kLegendX + 28, y + 4, ts.name.empty() ? "(unnamed)" : ts.name, "start", 13, "#222", " font-weight=\"bold\"");
    y += 17;
    s.text(kLegendX + 28, y + 4, std::to_string(ts.max_us.size()) + " windows of " + fmt_us(ts.window_s * 1e6), "start", 11, "#333");
    y += 15;
    s.text(kLegendX + 28, y + 4, "worst " + fmt_us(worst), "start", 11, "#333");
    y += 25;
  }
}

}  // namespace

std::string jitter_svg(const std::vector<rt::Distribution>& dists, const std::vector<TimeSeries>& series,
                       const std::string& title) {
  // One colour per name, in order of first appearance, so a series shares its distribution's.
  std::map<std::string, std::string> by_name;
  auto colour_of = [&](const std::string& name) {
    auto it = by_name.find(name);
    if (it == by_name.end()) it = by_name.emplace(name, kPalette[by_name.size() % kPalette.size()]).first;
    return it->second;
  };
  std::vector<std::string> dist_colours, series_colours;
  for (const auto& d : dists) dist_colours.push_back(colour_of(d.name));
  for (const auto& t : series) series_colours.push_back(colour_of(t.name));

  Svg s;
  s.o << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << num(kWidth, 0) << "\" height=\"" << num(kHeight, 0)
      << "\" viewBox=\"0 0 " << num(kWidth, 0) << " " << num(kHeight, 0)
      << "\" font-family=\"DejaVu Sans, Helvetica, Arial, sans-serif\">\n"
      << "<title>" << xml_escape(title) << "</title>\n"
      << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  s.text(kPlotLeft, 32, title, "start", 18, "#111", " font-weight=\"bold\"");
  s.text(kPlotLeft, kTopY0 - 10, "wake-up latency distribution", "start", 13, "#333");
  s.text(kPlotLeft, kBottomY0 - 10, "worst wake-up latency over time", "start", 13, "#333");
  histogram_panel(s, dists, dist_colours);
  time_panel(s, series, series_colours);
  legend(s, dists, dist_colours, series, series_colours);
  s.o << "</svg>\n";
  return s.o.str();
}

bool write_jitter_svg(const std::string& path, const std::vector<rt::Distribution>& dists,
                      const std::vector<TimeSeries>& series, const std::string& title, std::string* error) {
  const std::string svg = jitter_svg(dists, series, title);
  errno = 0;
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (f) f.write(svg.data(), static_cast<std::streamsize>(svg.size()));
  if (f) f.close();
  if (!f) {
    if (error != nullptr) *error = "cannot write " + path + ": " + (errno != 0 ? std::strerror(errno) : "write failed");
    return false;
  }
  return true;
}

}  // namespace lancet::tools
