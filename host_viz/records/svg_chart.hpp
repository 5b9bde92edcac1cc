#pragma once
// What the records' HTML pages (progress_page, cohort_page) share: the page's head and style, a
// link to a file, and a small SVG chart with linear axes. Internal to records/; allocating.

#include <string>
#include <string_view>

namespace lancet::records::html {

/// "<!DOCTYPE html>...<body>": a self-contained page (inline style, no script, no network).
[[nodiscard]] std::string page_head(std::string_view title);
/// "</body></html>".
[[nodiscard]] std::string page_tail();

/// `path` as an href: made relative to `page_dir` when both are absolute, percent-encoded where a
/// URL needs it, then HTML-escaped. Empty `page_dir`: the path as given.
[[nodiscard]] std::string file_href(const std::string& path, const std::string& page_dir);

/// `v` with `decimals` digits after the point, for SVG coordinates and table cells.
[[nodiscard]] std::string num(double v, int decimals = 1);

/// A chart of `width` × `height` pixels: data (x right, y up) in [x0, x1] × [y0, y1] mapped into
/// the area inside the margins.
struct Chart {
  double width = 560, height = 200;
  double margin_left = 52, margin_right = 10, margin_top = 10, margin_bottom = 36;
  double x0 = 0, x1 = 1, y0 = 0, y1 = 1;

  [[nodiscard]] double sx(double x) const { return margin_left + (x - x0) * (width - margin_left - margin_right) / (x1 - x0); }
  [[nodiscard]] double sy(double y) const { return height - margin_bottom - (y - y0) * (height - margin_top - margin_bottom) / (y1 - y0); }

  /// Widens [y0, y1] by `pad` of its span on each side; a zero span becomes ±1 around it.
  void pad_y(double pad);
  /// "<svg ...>" with an aria-label, a clip path `clip_id` for the data area, the grid, the tick
  /// labels (x ticks on whole numbers when `whole_x`) and both axis titles.
  [[nodiscard]] std::string open(std::string_view label, std::string_view clip_id, std::string_view x_title, std::string_view y_title,
                                 bool whole_x) const;
  /// A horizontal line across the data area at `y` with a label at its right end, above the line
  /// or below it.
  [[nodiscard]] std::string hline(double y, std::string_view css_class, std::string_view label, bool label_above = true) const;
};

}  // namespace lancet::records::html
