// ChainMail's cut and groove: the links a cut polyline crosses removed down to a depth, the faces
// of the cut, and the groove opened by moving those faces apart (chainmail.hpp says how).

#include "volume/chainmail.hpp"

#include <algorithm>
#include <cmath>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "text/text.hpp"

namespace lancet::volume {
namespace {

[[noreturn]] void fail(const std::string& what) { throw std::invalid_argument(what); }

std::string num(double v) { return text::format("%.9g", v); }

}  // namespace

namespace {

// One straight piece of a cut's polyline, in the lattice's xy plane.
struct CutSegment {
  double x0, y0, tx, ty, len, arc0;  ///< start, direction × length, length, arc length at the start
};

// The polyline's non-empty segments and its length; throws on a polyline or depth that cannot cut.
std::vector<CutSegment> cut_segments(std::span<const Vec3> polyline, double depth, double& length) {
  if (polyline.size() < 2)
    fail("ChainMail::cut: polyline has " + std::to_string(polyline.size()) + " point(s), at least 2 are needed");
  for (std::size_t p = 0; p < polyline.size(); ++p)
    if (!std::isfinite(polyline[p].x) || !std::isfinite(polyline[p].y))
      fail("ChainMail::cut: polyline[" + std::to_string(p) + "] = (" + num(polyline[p].x) + ", " + num(polyline[p].y) +
           ") m is not finite");
  if (!(std::isfinite(depth) && depth > 0)) fail("ChainMail::cut: depth = " + num(depth) + " m, must be finite and > 0");

  std::vector<CutSegment> segments;
  length = 0;
  for (std::size_t p = 0; p + 1 < polyline.size(); ++p) {
    const double tx = polyline[p + 1].x - polyline[p].x, ty = polyline[p + 1].y - polyline[p].y;
    const double len = std::hypot(tx, ty);
    if (len <= 0) continue;
    segments.push_back({polyline[p].x, polyline[p].y, tx, ty, len, length});
    length += len;
  }
  if (segments.empty()) fail("ChainMail::cut: polyline has zero length (all " + std::to_string(polyline.size()) + " points coincide)");
  return segments;
}

// Away direction along the polyline: the segment's left normal, blended near each interior
// vertex toward the miter of the two normals (reached at the vertex, over half the shorter
// adjacent segment). A blend of n and the miter m keeps dot(·, n) = 1 (m·n = 1), so the opening
// across every removed link, measured along its own segment's normal, is exactly the width, and
// the sponsors' displacements change smoothly around the corner instead of jumping.
std::pair<double, double> away_direction(const std::vector<CutSegment>& segments, std::size_t i, double arc) {
  const auto miter = [](double ax, double ay, double bx, double by) {
    const double c = std::max(1.0 + ax * bx + ay * by, 0.5);  // a turn over 120° is not exact
    return std::pair<double, double>{(ax + bx) / c, (ay + by) / c};
  };
  const auto left_normal = [&](std::size_t k) {
    return std::pair<double, double>{-segments[k].ty / segments[k].len, segments[k].tx / segments[k].len};
  };
  auto [ax, ay] = left_normal(i);
  const CutSegment& g = segments[i];
  if (i > 0) {
    const double t = 0.5 * std::min(segments[i - 1].len, g.len);
    const double into = arc - g.arc0;
    if (into < t) {
      const auto [px, py] = left_normal(i - 1);
      const auto [mx, my] = miter(px, py, ax, ay);
      const double w = std::clamp(into / t, 0.0, 1.0);
      return {mx + (ax - mx) * w, my + (ay - my) * w};
    }
  }
  if (i + 1 < segments.size()) {
    const double t = 0.5 * std::min(segments[i + 1].len, g.len);
    const double left_over = g.arc0 + g.len - arc;
    if (left_over < t) {
      const auto [qx, qy] = left_normal(i + 1);
      const auto [mx, my] = miter(ax, ay, qx, qy);
      const double w = std::clamp(left_over / t, 0.0, 1.0);
      return {mx + (ax - mx) * w, my + (ay - my) * w};
    }
  }
  return {ax, ay};
}

// Each face's depth below the top face of its column (same i, j).
void set_face_depths(std::vector<ChainMailCutFace>& faces, std::uint64_t nx, double dz) {
  std::vector<std::pair<std::uint64_t, int>> columns;  // (j · nx + i, top k)
  columns.reserve(faces.size());
  for (const ChainMailCutFace& f : faces)
    columns.emplace_back(static_cast<std::uint64_t>(f.element[1]) * nx + static_cast<std::uint64_t>(f.element[0]), f.element[2]);
  std::sort(columns.begin(), columns.end(), [](const auto& a, const auto& b) { return a.first != b.first ? a.first < b.first : a.second > b.second; });
  for (ChainMailCutFace& f : faces) {
    const std::uint64_t col = static_cast<std::uint64_t>(f.element[1]) * nx + static_cast<std::uint64_t>(f.element[0]);
    const auto it = std::lower_bound(columns.begin(), columns.end(), col, [](const auto& a, std::uint64_t c) { return a.first < c; });
    f.depth = (it->second - f.element[2]) * dz;
  }
}

}  // namespace


ChainMailCut ChainMail::cut(std::span<const Vec3> polyline, double depth) {
  double length = 0;
  const std::vector<CutSegment> segments = cut_segments(polyline, depth, length);

  const auto& dims = lattice_.dims;
  const Vec3& sp = lattice_.spacing;
  const Vec3& org = lattice_.origin;
  const int k_top = dims[2] - 1;
  const int k_low = std::max(0, k_top - static_cast<int>(std::floor(depth / sp.z + 1e-9)));

  struct Hit {
    std::uint64_t linear;  // k, j, i order
    std::uint32_t segment;
    int side;
    double arc;
  };
  std::vector<Hit> hits;
  ChainMailCut out;
  out.length = length;
  const auto linear_of = [&](int i, int j, int k) {
    return static_cast<std::uint64_t>(i) +
           static_cast<std::uint64_t>(dims[0]) * (static_cast<std::uint64_t>(j) + static_cast<std::uint64_t>(dims[1]) * static_cast<std::uint64_t>(k));
  };

  for (std::size_t si = 0; si < segments.size(); ++si) {
    const CutSegment& g = segments[si];
    const bool last = si + 1 == segments.size();
    const double x1 = g.x0 + g.tx, y1 = g.y0 + g.ty;
    // Index range of the segment's bounding box, one element wider, clamped before the cast.
    const auto index_range = [](double a, double b, double o, double s, int n, int& first, int& final_index) {
      const double lo = std::floor((std::min(a, b) - o) / s) - 1, hi = std::ceil((std::max(a, b) - o) / s) + 1;
      first = static_cast<int>(std::clamp(lo, 0.0, static_cast<double>(n)));
      final_index = static_cast<int>(std::clamp(hi, -1.0, static_cast<double>(n - 1)));
    };
    int i0 = 0, i1 = 0, j0 = 0, j1 = 0;
    index_range(g.x0, x1, org.x, sp.x, dims[0], i0, i1);
    index_range(g.y0, y1, org.y, sp.y, dims[1], j0, j1);
    // Side of a point: left when cross(t, p − p0) >= 0.
    const auto cross_at = [&](int i, int j) { return g.tx * (org.y + j * sp.y - g.y0) - g.ty * (org.x + i * sp.x - g.x0); };
    for (int k = k_low; k <= k_top; ++k)
      for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i)
          for (int axis = 0; axis < 2; ++axis) {
            const int in = i + (axis == 0 ? 1 : 0), jn = j + (axis == 1 ? 1 : 0);
            if (in >= dims[0] || jn >= dims[1]) continue;
            const double ca = cross_at(i, j), cb = cross_at(in, jn);
            if ((ca >= 0) == (cb >= 0)) continue;
            // Where the link crosses the segment's line, as a fraction u of the segment.
            const double lambda = ca / (ca - cb);
            const double px = org.x + (i + lambda * (in - i)) * sp.x, py = org.y + (j + lambda * (jn - j)) * sp.y;
            const double u = ((px - g.x0) * g.tx + (py - g.y0) * g.ty) / (g.len * g.len);
            if (u < 0 || u > 1 || (u == 1 && !last)) continue;
            const Index e{i, j, k}, n{in, jn, k};
            if (!linked(e, axis)) continue;
            unlink(e, n, axis);
            ++out.links_removed;
            const double arc = g.arc0 + u * g.len;
            hits.push_back({linear_of(i, j, k), static_cast<std::uint32_t>(si), ca >= 0 ? 1 : -1, arc});
            hits.push_back({linear_of(in, jn, k), static_cast<std::uint32_t>(si), cb >= 0 ? 1 : -1, arc});
          }
  }

  // One face per element: the side and segment of its first removed link, the mean arc length of
  // its removed links.
  std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) {
    return a.linear != b.linear ? a.linear < b.linear : (a.segment != b.segment ? a.segment < b.segment : a.arc < b.arc);
  });
  const auto nx = static_cast<std::uint64_t>(dims[0]), ny = static_cast<std::uint64_t>(dims[1]);
  for (std::size_t h = 0; h < hits.size();) {
    std::size_t end = h;
    double arc = 0;
    for (; end < hits.size() && hits[end].linear == hits[h].linear; ++end) arc += hits[end].arc;
    ChainMailCutFace f;
    const std::uint64_t lin = hits[h].linear;
    f.element = {static_cast<int>(lin % nx), static_cast<int>((lin / nx) % ny), static_cast<int>(lin / (nx * ny))};
    f.side = hits[h].side;
    f.arc = arc / static_cast<double>(end - h);
    const auto [ax, ay] = away_direction(segments, hits[h].segment, f.arc);
    f.away = {f.side * ax, f.side * ay, 0};
    out.faces.push_back(f);
    h = end;
  }

  set_face_depths(out.faces, nx, sp.z);
  return out;
}

ChainMailStepResult ChainMail::open_groove(const ChainMailCut& cut, double width, const ChainMailRetractor& retractor) {
  if (!(std::isfinite(width) && width > 0)) fail("ChainMail::open_groove: width = " + num(width) + " m, must be finite and > 0");
  if (std::isnan(retractor.from) || std::isnan(retractor.to) || retractor.from > retractor.to)
    fail("ChainMail::open_groove: retractor.from = " + num(retractor.from) + " m, retractor.to = " + num(retractor.to) +
         " m, need from <= to");
  if (!(std::isfinite(retractor.depth) && retractor.depth >= 0))
    fail("ChainMail::open_groove: retractor.depth = " + num(retractor.depth) + " m, must be finite and >= 0");
  groove_sponsors_.clear();
  const double tol = 1e-9 * lattice_.spacing.z;
  for (const ChainMailCutFace& f : cut.faces) {
    if (f.arc < retractor.from || f.arc > retractor.to || f.depth > retractor.depth + tol) continue;
    if (f.away.x == 0 && f.away.y == 0) continue;
    groove_sponsors_.push_back({f.element, rest_position(f.element) + (0.5 * width) * f.away});
  }
  return move(groove_sponsors_);
}

}  // namespace lancet::volume
