#pragma once
// A straightforward Enhanced ChainMail for chainmail_test.cpp to compare against: the rules that
// host_viz/volume/chainmail.hpp states, written plainly (dense arrays, a std::priority_queue of
// every check that finds a violation, no bricks, no marks), run on the same lattice (its links
// read from the ChainMail under test, so cuts count) with the same sponsors. Sponsors are placed
// in order, a conflict counted when a neighbour already final on an axis disagrees; then
// (element, axis) candidates are taken largest violation first in quanta of eps/4 (ties first in,
// first out), each settled once to the nearest point of the intersection of its final
// neighbours' intervals (their middle when empty: a conflict), then its other neighbours checked.

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <queue>
#include <utility>
#include <vector>

#include "volume/chainmail.hpp"

namespace lancet::volume {

struct ChainMailReference {
  using Index = ChainMail::Index;
  std::array<int, 3> dims{};
  Vec3 spacing{};
  std::vector<ChainMailMaterial> mats;
  std::vector<std::uint8_t> ids;   // empty: all materials[0]
  std::vector<std::uint8_t> links;  // bit d: link in direction d (2·axis + negative)
  std::vector<Vec3> u;              // m, displacement
  std::uint64_t step = 0;
  bool valid = true;                // for the tests: no step had a conflict (every link is valid)

  ChainMailReference(const ChainMail& cm, std::vector<ChainMailMaterial> m, std::vector<std::uint8_t> material_ids)
      : dims(cm.lattice().dims), spacing(cm.lattice().spacing), mats(std::move(m)), ids(std::move(material_ids)),
        links(count(), 0), u(count()) {
    read_links(cm);
  }
  std::size_t count() const { return static_cast<std::size_t>(dims[0]) * static_cast<std::size_t>(dims[1]) * static_cast<std::size_t>(dims[2]); }
  std::size_t at(const Index& e) const { return static_cast<std::size_t>(e[0] + dims[0] * (e[1] + dims[1] * e[2])); }
  Index index_of(std::size_t i) const {
    const int n = static_cast<int>(i);
    return {n % dims[0], (n / dims[0]) % dims[1], n / (dims[0] * dims[1])};
  }
  bool inside(const Index& e) const {
    return e[0] >= 0 && e[1] >= 0 && e[2] >= 0 && e[0] < dims[0] && e[1] < dims[1] && e[2] < dims[2];
  }
  static Index neighbour(Index e, int d) {
    e[static_cast<std::size_t>(d / 2)] += d % 2 == 0 ? 1 : -1;
    return e;
  }
  // The displacements of `cm`: the reference goes on from the state under test.
  void sync(const ChainMail& cm) {
    for (std::size_t i = 0; i < count(); ++i) u[i] = cm.displacement(index_of(i));
  }
  void read_links(const ChainMail& cm) {  // after a cut
    for (std::size_t i = 0; i < count(); ++i) {
      const Index e = index_of(i);
      links[i] = 0;
      for (int d = 0; d < 6; ++d) {
        const Index n = neighbour(e, d);
        const bool live = d % 2 == 0 ? cm.linked(e, d / 2) : inside(n) && cm.linked(n, d / 2);
        if (live) links[i] = static_cast<std::uint8_t>(links[i] | (1u << d));
      }
    }
  }
  const ChainMailMaterial& mat(std::size_t i) const { return mats[ids.empty() ? 0 : ids[i]]; }
  // The interval of (neighbour − element) displacement on axis b for the link in direction d.
  std::pair<double, double> box(std::size_t e, std::size_t n, int d, int b) const {
    const int a = d / 2;
    const ChainMailAxisLimits& A = mat(e).axis[static_cast<std::size_t>(a)];
    const ChainMailAxisLimits& B = mat(n).axis[static_cast<std::size_t>(a)];
    if (b != a) {
      const double shear = 0.5 * (A.max_shear + B.max_shear);
      return {-shear, shear};
    }
    const double s = a == 0 ? spacing.x : (a == 1 ? spacing.y : spacing.z);
    const double dlo = 0.5 * (A.min_length + B.min_length) - s, dhi = 0.5 * (A.max_length + B.max_length) - s;
    return d % 2 == 0 ? std::pair{dlo, dhi} : std::pair{-dhi, -dlo};
  }
  static double& comp(Vec3& v, int a) { return a == 0 ? v.x : (a == 1 ? v.y : v.z); }

  ChainMailStepResult move(const std::vector<ChainMailSponsor>& sponsors, const ChainMail& cm) {
    const double eps = 1e-9 * std::min({spacing.x, spacing.y, spacing.z}), inv_quantum = 4 / eps;
    ++step;
    std::vector<std::array<bool, 3>> final_on(count(), {false, false, false});
    std::vector<bool> sponsor(count(), false), moved(count(), false);
    struct Entry {
      std::uint64_t key, seq;
      std::size_t element;
      int axis;
      bool operator<(const Entry& o) const { return key != o.key ? key > o.key : seq > o.seq; }  // smallest key, then oldest, on top
    };
    std::priority_queue<Entry> queue;
    std::uint64_t seq = 0, last = 0;
    ChainMailStepResult r;
    const auto check = [&](std::size_t e, int d, int b) {  // queue neighbour n of e on axis b when outside e's box
      const std::size_t n = at(neighbour(index_of(e), d));
      if (final_on[n][static_cast<std::size_t>(b)] || sponsor[n]) return;
      const auto [lo, hi] = box(e, n, d, b);
      const double ue = comp(u[e], b), un = comp(u[n], b);
      const double violation = std::max(ue + lo - un, un - (ue + hi));
      if (!(violation > eps)) return;
      const std::uint64_t key = std::max(~static_cast<std::uint64_t>(std::min(violation * inv_quantum, 0x1p62)), last);
      queue.push({key, seq++, n, b});
    };
    for (const ChainMailSponsor& s : sponsors) sponsor[at(s.element)] = true;
    for (const ChainMailSponsor& s : sponsors) {
      const std::size_t e = at(s.element);
      Vec3 target = s.position - cm.rest_position(s.element);
      bool conflict = false;
      for (int d = 0; d < 6; ++d) {
        if (((links[e] >> d) & 1u) == 0) continue;
        const std::size_t n = at(neighbour(index_of(e), d));
        for (int b = 0; b < 3; ++b) {
          if (!final_on[n][static_cast<std::size_t>(b)]) continue;
          const auto [lo, hi] = box(e, n, d, b);
          const double rel = comp(u[n], b) - comp(target, b);
          if (rel < lo - eps || rel > hi + eps) conflict = true;
        }
      }
      r.conflicts += conflict ? 1u : 0u;
      if (!(target == u[e])) {
        u[e] = target;
        moved[e] = true;
        ++r.moved;
      }
      final_on[e] = {true, true, true};
      ++r.processed;
      for (int d = 0; d < 6; ++d)
        if (((links[e] >> d) & 1u) != 0)
          for (int b = 0; b < 3; ++b) check(e, d, b);
    }
    while (!queue.empty()) {
      const Entry top = queue.top();
      queue.pop();
      last = top.key;
      const std::size_t e = top.element;
      const int a = top.axis;
      if (final_on[e][static_cast<std::size_t>(a)]) continue;
      double lo = -std::numeric_limits<double>::infinity(), hi = std::numeric_limits<double>::infinity();
      for (int d = 0; d < 6; ++d) {
        if (((links[e] >> d) & 1u) == 0) continue;
        const std::size_t n = at(neighbour(index_of(e), d));
        if (!final_on[n][static_cast<std::size_t>(a)]) continue;
        const auto [blo, bhi] = box(e, n, d, a);
        lo = std::max(lo, comp(u[n], a) - bhi);
        hi = std::min(hi, comp(u[n], a) - blo);
      }
      const double before = comp(u[e], a);
      double v = std::min(std::max(before, lo), hi);
      if (lo > hi) {
        if (lo - hi > eps) ++r.conflicts;
        v = 0.5 * (lo + hi);
      }
      if (v != before) {
        comp(u[e], a) = v;
        if (!moved[e]) ++r.moved;
        moved[e] = true;
      }
      final_on[e][static_cast<std::size_t>(a)] = true;
      ++r.processed;
      for (int d = 0; d < 6; ++d)
        if (((links[e] >> d) & 1u) != 0) check(e, d, a);
    }
    return r;
  }

  // open_groove's sponsors, as its doc says.
  std::vector<ChainMailSponsor> groove(const ChainMail& cm, const ChainMailCut& cut, double width, const ChainMailRetractor& ret) const {
    std::vector<ChainMailSponsor> s;
    for (const ChainMailCutFace& f : cut.faces) {
      if (f.arc < ret.from || f.arc > ret.to || f.depth > ret.depth + 1e-9 * spacing.z || (f.away.x == 0 && f.away.y == 0)) continue;
      s.push_back({f.element, cm.rest_position(f.element) + (0.5 * width) * f.away});
    }
    return s;
  }
};

}  // namespace lancet::volume
