// The records' pages' shared pieces (records/svg_chart.hpp).

#include "records/svg_chart.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>

#include "text/text.hpp"

namespace lancet::records::html {
namespace {

constexpr std::string_view kStyle = R"(
body { font: 14px/1.4 system-ui, sans-serif; margin: 24px; color: #222; max-width: 1240px; }
h1 { font-size: 22px; margin: 0 0 4px; } h2 { font-size: 18px; margin: 28px 0 8px; border-bottom: 1px solid #ccc; }
h3 { font-size: 15px; margin: 16px 0 6px; }
table { border-collapse: collapse; margin: 8px 0; } th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
th { background: #f2f2f2; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.next td { background: #fff6d5; font-weight: 600; } tr.stuck td { background: #fde4e4; }
.met { color: #1b7a35; } .notyet { color: #a5401d; } .note { color: #555; font-size: 13px; }
.charts { display: flex; flex-wrap: wrap; gap: 8px 16px; } figure { margin: 0; } figcaption { font-size: 13px; color: #444; }
svg text { font: 11px system-ui, sans-serif; fill: #333; } svg .grid { stroke: #e4e4e4; } svg .frame { fill: none; stroke: #999; }
svg .band { fill: #2e9e4f; fill-opacity: 0.14; } svg .limit { stroke: #2e9e4f; stroke-width: 1.5; fill: none; }
svg .mean { stroke: #2e9e4f; stroke-dasharray: 4 3; fill: none; } svg .curve { stroke: #7a8aa0; fill: none; }
svg .pass { fill: #1b7a35; } svg .fail { fill: #d62728; } svg .noband { fill: #888; }
svg .cusum { stroke: #1f5fbf; stroke-width: 1.8; fill: none; } svg .h1 { stroke: #d62728; stroke-dasharray: 6 3; }
svg .h0 { stroke: #1b7a35; stroke-dasharray: 6 3; } svg .met-at { stroke: #1b7a35; stroke-width: 1.5; }
svg .bar-on { fill: #4a7fc1; } svg .bar-stuck { fill: #d62728; }
)";

// A step of 1, 2 or 5 times a power of ten that cuts `span` into about `parts` parts.
double round_step(double span, double parts) {
  if (!std::isfinite(span) || span <= 0) return 1;
  const double exponent = std::floor(std::log10(span / parts));
  const double unit = std::pow(10.0, exponent);
  const double mantissa = span / parts / unit;  // in [1, 10)
  return unit * (mantissa <= 1 ? 1 : mantissa <= 2 ? 2 : mantissa <= 5 ? 5 : 10);
}

// Bytes a URL path may hold as they are; everything else is percent-encoded.
bool url_safe(unsigned char c) {
  return std::isalnum(c) != 0 || c == '/' || c == '.' || c == '-' || c == '_' || c == '~';
}

}  // namespace

std::string page_head(std::string_view title) {
  return "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>" + text::xml_escape(title) + "</title><style>" +
         std::string(kStyle) + "</style></head>\n<body>\n";
}

std::string page_tail() { return "</body></html>\n"; }

std::string file_href(const std::string& path, const std::string& page_dir) {
  std::filesystem::path p(path);
  if (!page_dir.empty() && p.is_absolute() && std::filesystem::path(page_dir).is_absolute()) {
    p = p.lexically_normal().lexically_relative(std::filesystem::path(page_dir).lexically_normal());
  }
  std::string url;
  for (const char ch : p.generic_string()) {
    const auto c = static_cast<unsigned char>(ch);
    url += url_safe(c) ? std::string(1, ch) : text::format("%%%02X", c);
  }
  return text::xml_escape(url);
}

std::string num(double v, int decimals) { return text::fixed(v, decimals); }

void Chart::pad_y(double pad) {
  if (!(y1 > y0)) {
    y0 -= 1;
    y1 += 1;
    return;
  }
  const double d = (y1 - y0) * pad;
  y0 -= d;
  y1 += d;
}

std::string Chart::open(std::string_view label, std::string_view clip_id, std::string_view x_title, std::string_view y_title,
                        bool whole_x) const {
  const double left = margin_left, right = width - margin_right, top = margin_top, bottom = height - margin_bottom;
  std::string s = "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + num(width, 0) + "\" height=\"" + num(height, 0) + "\" viewBox=\"0 0 " +
                  num(width, 0) + " " + num(height, 0) + "\" role=\"img\" aria-label=\"" + text::xml_escape(label) + "\">\n";
  s += "<defs><clipPath id=\"" + std::string(clip_id) + "\"><rect x=\"" + num(left) + "\" y=\"" + num(top) + "\" width=\"" + num(right - left) +
       "\" height=\"" + num(bottom - top) + "\"/></clipPath></defs>\n";
  double xs = round_step(x1 - x0, 8);
  if (whole_x) xs = std::max(1.0, std::round(xs));
  for (double t = std::ceil(x0 / xs) * xs; t <= x1; t += xs) {
    s += "<line class=\"grid\" x1=\"" + num(sx(t)) + "\" x2=\"" + num(sx(t)) + "\" y1=\"" + num(top) + "\" y2=\"" + num(bottom) + "\"/><text x=\"" +
         num(sx(t)) + "\" y=\"" + num(bottom + 13) + "\" text-anchor=\"middle\">" + text::format("%g", t) + "</text>\n";
  }
  const double ys = round_step(y1 - y0, 5);
  for (double t = std::ceil(y0 / ys) * ys; t <= y1; t += ys) {
    const double shown = std::abs(t) < ys * 1e-6 ? 0.0 : t;
    s += "<line class=\"grid\" x1=\"" + num(left) + "\" x2=\"" + num(right) + "\" y1=\"" + num(sy(t)) + "\" y2=\"" + num(sy(t)) + "\"/><text x=\"" +
         num(left - 4) + "\" y=\"" + num(sy(t) + 4) + "\" text-anchor=\"end\">" + text::format("%g", shown) + "</text>\n";
  }
  s += "<rect class=\"frame\" x=\"" + num(left) + "\" y=\"" + num(top) + "\" width=\"" + num(right - left) + "\" height=\"" + num(bottom - top) + "\"/>\n";
  s += "<text x=\"" + num(0.5 * (left + right)) + "\" y=\"" + num(height - 4) + "\" text-anchor=\"middle\">" + text::xml_escape(x_title) + "</text>\n";
  s += "<text transform=\"translate(12 " + num(0.5 * (top + bottom)) + ") rotate(-90)\" text-anchor=\"middle\">" + text::xml_escape(y_title) +
       "</text>\n";
  return s;
}

std::string Chart::hline(double y, std::string_view css_class, std::string_view label, bool label_above) const {
  const double right = width - margin_right;
  return "<line class=\"" + std::string(css_class) + "\" x1=\"" + num(margin_left) + "\" x2=\"" + num(right) + "\" y1=\"" + num(sy(y)) + "\" y2=\"" +
         num(sy(y)) + "\"/><text x=\"" + num(right - 3) + "\" y=\"" + num(label_above ? sy(y) - 3 : sy(y) + 11) + "\" text-anchor=\"end\">" + text::xml_escape(label) +
         "</text>\n";
}

}  // namespace lancet::records::html
