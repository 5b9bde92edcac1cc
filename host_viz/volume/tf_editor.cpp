#include "volume/tf_editor.hpp"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>

namespace lancet::volume {

std::vector<float> Histogram::log_heights() const {
  std::vector<float> h(counts.size(), 0.0f);
  const std::uint64_t most = counts.empty() ? 0 : *std::max_element(counts.begin(), counts.end());
  if (most == 0) return h;
  const double top = std::log1p(static_cast<double>(most));
  for (std::size_t i = 0; i < counts.size(); ++i) h[i] = static_cast<float>(std::log1p(static_cast<double>(counts[i])) / top);
  return h;
}

Histogram histogram(const Volume& v, float lo, float hi, int bins) {
  Histogram h;
  h.lo = lo;
  h.hi = hi > lo ? hi : lo + 1;
  h.counts.assign(static_cast<std::size_t>(std::max(bins, 1)), 0);
  const float scale = static_cast<float>(h.counts.size()) / (h.hi - h.lo);
  const int last = static_cast<int>(h.counts.size()) - 1;
  for (float x : v.data) {
    if (!std::isfinite(x)) continue;
    const float f = (x - h.lo) * scale;
    const int b = f <= 0.0f ? 0 : f >= static_cast<float>(last) ? last : static_cast<int>(f);
    ++h.counts[static_cast<std::size_t>(b)];
  }
  return h;
}

TfEditor::TfEditor(TfSpec spec) : spec_(std::move(spec)) {
  if (!(spec_.hi > spec_.lo)) spec_.hi = spec_.lo + 1;
  std::sort(spec_.points.begin(), spec_.points.end(), [](const TfPoint& a, const TfPoint& b) { return a.value < b.value; });
  if (spec_.points.size() < 2) spec_.points = {{spec_.lo, 0, 0, 0, 0}, {spec_.hi, 1, 1, 1, 0}};
}

TransferFunction TfEditor::table() const { return spec_.table(); }

int TfEditor::pick(float x, float y, float rx, float ry) const noexcept {
  int best = -1;
  float best_d = 1.0f;  // inside the ellipse: d < 1
  for (std::size_t i = 0; i < spec_.points.size(); ++i) {
    const float dx = (x_of(spec_.points[i].value) - x) / rx, dy = (spec_.points[i].a - y) / ry;
    const float d = dx * dx + dy * dy;
    if (d <= best_d) {
      best_d = d;
      best = static_cast<int>(i);
    }
  }
  return best;
}

bool TfEditor::press(float x, float y, float rx, float ry) noexcept {
  selected_ = pick(x, y, rx, ry);
  held_ = selected_ >= 0;
  return held_;
}

bool TfEditor::drag_to(float x, float y) noexcept {
  if (!held_ || selected_ < 0 || selected_ >= static_cast<int>(spec_.points.size())) return false;
  TfPoint& p = spec_.points[static_cast<std::size_t>(selected_)];
  p.a = std::clamp(y, 0.0f, 1.0f);
  const std::size_t i = static_cast<std::size_t>(selected_);
  if (i > 0 && i + 1 < spec_.points.size()) {
    // Strictly between the neighbours (a point on a neighbour's value would make a step that the
    // next drag could not separate again), by a thousandth of the range.
    const float gap = (spec_.hi - spec_.lo) * 1e-3f;
    const float lo = spec_.points[i - 1].value + gap, hi = spec_.points[i + 1].value - gap;
    if (lo <= hi) p.value = std::clamp(value_at(x), lo, hi);
  }
  return true;
}

int TfEditor::add(float x, float y) {
  const float value = value_at(x);
  if (!(value > spec_.points.front().value && value < spec_.points.back().value)) return -1;
  const auto at = std::lower_bound(spec_.points.begin(), spec_.points.end(), value,
                                   [](const TfPoint& p, float v) { return p.value < v; });
  const float gap = (spec_.hi - spec_.lo) * 1e-3f;
  if (at->value - value < gap || value - std::prev(at)->value < gap) return -1;
  // Coloured as the table is there, so adding a point changes nothing until it is moved.
  const TfPoint& a = *std::prev(at);
  const TfPoint& b = *at;
  const float f = (value - a.value) / (b.value - a.value);
  const TfPoint p{value, a.r + (b.r - a.r) * f, a.g + (b.g - a.g) * f, a.b + (b.b - a.b) * f, std::clamp(y, 0.0f, 1.0f)};
  const std::ptrdiff_t index = at - spec_.points.begin();
  spec_.points.insert(spec_.points.begin() + index, p);
  selected_ = static_cast<int>(index);
  held_ = false;
  return selected_;
}

bool TfEditor::remove(int i) {
  if (i <= 0 || i + 1 >= static_cast<int>(spec_.points.size())) return false;
  spec_.points.erase(spec_.points.begin() + i);
  if (selected_ == i) {
    selected_ = -1;
    held_ = false;
  } else if (selected_ > i) {
    --selected_;
  }
  return true;
}

void TfEditor::set_colour(int i, float r, float g, float b) noexcept {
  if (i < 0 || i >= static_cast<int>(spec_.points.size())) return;
  TfPoint& p = spec_.points[static_cast<std::size_t>(i)];
  p.r = std::clamp(r, 0.0f, 1.0f);
  p.g = std::clamp(g, 0.0f, 1.0f);
  p.b = std::clamp(b, 0.0f, 1.0f);
}

}  // namespace lancet::volume
