#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cassert>
#include <cmath>
#include <limits>
#include <mutex>
#include <utility>

#include "surface/bvh.hpp"
#include "surface/bvh_box.hpp"
#include "volume/build_arrays.hpp"
#include "volume/in_two_halves.hpp"

// TriangleBvh's build, its blocks, its refits and its checks (the queries are in bvh.cpp).

namespace lancet::surface {
namespace {

using bvh_detail::Box;
using bvh_detail::encloses;
using bvh_detail::face_box;
using bvh_detail::vertex;

// Cells a side of the Morton grid (10 bits an axis: 30-bit codes).
constexpr std::uint32_t kMortonCells = 1024;

// The 30-bit Morton code of a point quantised to 1024 cells a side: the bits of the three cell
// indices interleaved (x lowest), so that sorting by code lays the cells out along a Z-order curve
// and every prefix of the code names an octree cell.
std::uint32_t spread_bits(std::uint32_t v) {
  v &= 0x3ffu;
  v = (v | (v << 16)) & 0x030000ffu;
  v = (v | (v << 8)) & 0x0300f00fu;
  v = (v | (v << 4)) & 0x030c30c3u;
  v = (v | (v << 2)) & 0x09249249u;
  return v;
}

// The faces' Morton codes (of their box centres within the box of all centres), from faces
// [begin, end) into code[].
void morton_codes(const MeshView& m, Vec3f lo, const double scale[3], std::uint32_t begin, std::uint32_t end, std::uint32_t* code) {
  const auto cell = [](double q) {
    // NaN and anything below the box go to cell 0; the clamp keeps the top edge in cell 1023.
    return q >= 0 ? static_cast<std::uint32_t>(std::min(q, double{kMortonCells - 1})) : 0u;
  };
  for (std::uint32_t f = begin; f < end; ++f) {
    const Box b = face_box(m, f);
    const double cx = 0.5 * (double{b.lo.x} + b.hi.x), cy = 0.5 * (double{b.lo.y} + b.hi.y), cz = 0.5 * (double{b.lo.z} + b.hi.z);
    code[f] = spread_bits(cell((cx - lo.x) * scale[0])) | spread_bits(cell((cy - lo.y) * scale[1])) << 1 |
              spread_bits(cell((cz - lo.z) * scale[2])) << 2;
  }
}

// Sorts (code, face) pairs by code, stably (equal codes keep their face order): three passes of a
// least-significant-digit radix sort over 10-bit digits. keys/faces are sorted in place; tmp_*
// are scratch of the same size. Each pass counts the digits of each half of the input apart and
// gives half 1's entries of a digit the places after half 0's, so the halves scatter at once (on
// two threads when `two`) and the order is the same either way.
void radix_sort(volume::ScratchVector<std::uint32_t>& keys, std::vector<std::uint32_t>& faces, volume::ScratchVector<std::uint32_t>& tmp_keys,
                std::vector<std::uint32_t>& tmp_faces, bool two) {
  constexpr int kDigit = 10;
  constexpr std::uint32_t kBuckets = 1u << kDigit;
  const std::size_t n = keys.size();
  std::vector<std::uint32_t> count(2 * kBuckets);  // half h's counts, then its next places, at h·kBuckets
  for (int shift = 0; shift < 30; shift += kDigit) {
    std::fill(count.begin(), count.end(), 0u);
    volume::in_two_halves(n, two, [&](std::size_t begin, std::size_t end, int half) {
      std::uint32_t* c = count.data() + half * kBuckets;
      for (std::size_t i = begin; i < end; ++i) ++c[(keys[i] >> shift) & (kBuckets - 1)];
    });
    std::uint32_t sum = 0;
    for (std::uint32_t b = 0; b < kBuckets; ++b)
      for (std::uint32_t half = 0; half < 2; ++half) sum += std::exchange(count[half * kBuckets + b], sum);
    volume::in_two_halves(n, two, [&](std::size_t begin, std::size_t end, int half) {
      std::uint32_t* next = count.data() + half * kBuckets;
      for (std::size_t i = begin; i < end; ++i) {
        const std::uint32_t at = next[(keys[i] >> shift) & (kBuckets - 1)]++;
        tmp_keys[at] = keys[i];
        tmp_faces[at] = faces[i];
      }
    });
    keys.swap(tmp_keys);
    faces.swap(tmp_faces);
  }
}

// The inverse of spread_bits: every third bit of v from bit 0, packed into 10 bits.
std::uint32_t compact_bits(std::uint32_t v) {
  v &= 0x09249249u;
  v = (v | (v >> 2)) & 0x030c30c3u;
  v = (v | (v >> 4)) & 0x0300f00fu;
  v = (v | (v >> 8)) & 0x030000ffu;
  v = (v | (v >> 16)) & 0x3ffu;
  return v;
}

// The Morton grid of a build: the box of the faces' centres, its cells a metre, and each axis's
// largest half size of a face's box.
struct Grid {
  Box centres;
  double cells = 0;
  double half[3] = {0, 0, 0};
  double slack = 0;  // for the rounding of a centre into its cell
};

// A box enclosing every face of a block whose sorted codes run from `first` to `last`: the octree
// cell of their common prefix (every centre lies in it), grown by the largest half size of a face
// (a face's box lies within that of its centre), rounded outwards to floats.
Box block_box(const Grid& g, std::uint32_t first, std::uint32_t last) {
  const std::uint32_t differ = first ^ last;
  const std::uint32_t free_bits = differ == 0 ? 0u : (std::uint32_t{2} << (31 - std::countl_zero(differ))) - 1u;
  const std::uint32_t low = first & ~free_bits, high = first | free_bits;
  const float lo[3] = {g.centres.lo.x, g.centres.lo.y, g.centres.lo.z}, hi[3] = {g.centres.hi.x, g.centres.hi.y, g.centres.hi.z};
  float out_lo[3], out_hi[3];
  for (int a = 0; a < 3; ++a) {
    double x0 = lo[a], x1 = hi[a];
    if (g.cells > 0) {
      const std::uint32_t k0 = compact_bits(low >> a), k1 = compact_bits(high >> a);
      x0 = lo[a] + k0 / g.cells;
      if (k1 + 1 < kMortonCells) x1 = lo[a] + (k1 + 1) / g.cells;  // the last cell also holds what the clamp put there
    }
    x0 -= g.half[a] + g.slack;
    x1 += g.half[a] + g.slack;
    out_lo[a] = std::nextafter(static_cast<float>(x0), -std::numeric_limits<float>::infinity());
    out_hi[a] = std::nextafter(static_cast<float>(x1), std::numeric_limits<float>::infinity());
  }
  Box b;
  b.lo = {out_lo[0], out_lo[1], out_lo[2]};
  b.hi = {out_hi[0], out_hi[1], out_hi[2]};
  return b;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

struct TriangleBvh::Lazy {
  std::mutex mutex;                                    // held while a block is made
  std::unique_ptr<std::atomic<std::uint8_t>[]> made;   // per block: 1 once its nodes are made
};

void TriangleBvh::NodeFree::operator()(Node* p) const noexcept { volume::ZeroedAllocator<Node>().deallocate(p, capacity); }

TriangleBvh::TriangleBvh() = default;
TriangleBvh::~TriangleBvh() = default;
TriangleBvh::TriangleBvh(TriangleBvh&&) noexcept = default;
TriangleBvh& TriangleBvh::operator=(TriangleBvh&&) noexcept = default;

TriangleBvh::TriangleBvh(const TriangleBvh& o)
    : parent_(o.parent_), order_(o.order_), leaf_of_(o.leaf_of_), rank_(o.rank_), code_(o.code_), blocks_(o.blocks_), top_(o.top_),
      made_(o.made_), depth_(o.depth_) {
  if (o.nodes_) {
    allocate_nodes(o.nodes_.get_deleter().capacity);
    o.for_each_made_range([&](std::uint32_t begin, std::uint32_t end) { std::copy(&o.nodes_[begin], &o.nodes_[end], &nodes_[begin]); });
  }
  if (o.lazy_) {
    lazy_ = std::make_unique<Lazy>();
    lazy_->made = std::make_unique<std::atomic<std::uint8_t>[]>(blocks_.size());
    for (std::size_t k = 0; k < blocks_.size(); ++k) lazy_->made[k].store(o.lazy_->made[k].load());
  }
}

TriangleBvh& TriangleBvh::operator=(const TriangleBvh& o) {
  if (this != &o) *this = TriangleBvh(o);
  return *this;
}

void TriangleBvh::allocate_nodes(std::size_t capacity) {
  nodes_ = std::unique_ptr<Node[], NodeFree>(volume::ZeroedAllocator<Node>().allocate(capacity), NodeFree{capacity});
}

void TriangleBvh::build(const MeshView& m, bool threads, bool lazy) {
  *this = TriangleBvh();
  const std::size_t n = m.faces.size();
  assert(n < (std::size_t{1} << 30) && "TriangleBvh::build: too many faces");
  order_.resize(n);
  if (n == 0) return;
  const bool two = threads && volume::worth_two_threads(n);
  const bool in_blocks = lazy && n >= kLazyFrom;

  // 1. Every face's Morton code (its box centre in the box of all centres) and the faces sorted
  //    by it, stably: neighbours in space become neighbours in order_.
  Grid grid;
  Box half_boxes[2];
  double half_sizes[2][3] = {{0, 0, 0}, {0, 0, 0}};
  volume::in_two_halves(n, two, [&](std::size_t begin, std::size_t end, int h) {
    Box& cb = half_boxes[h];
    double* hs = half_sizes[h];
    for (auto f = static_cast<std::uint32_t>(begin); f < end; ++f) {
      const Box b = face_box(m, f);
      cb.grow(Vec3f{0.5f * (b.lo.x + b.hi.x), 0.5f * (b.lo.y + b.hi.y), 0.5f * (b.lo.z + b.hi.z)});
      hs[0] = std::max(hs[0], 0.5 * (double{b.hi.x} - b.lo.x));
      hs[1] = std::max(hs[1], 0.5 * (double{b.hi.y} - b.lo.y));
      hs[2] = std::max(hs[2], 0.5 * (double{b.hi.z} - b.lo.z));
    }
  });
  grid.centres = half_boxes[0];
  grid.centres.grow(half_boxes[1]);
  for (int a = 0; a < 3; ++a) grid.half[a] = std::max(half_sizes[0][a], half_sizes[1][a]);
  const Box& cbox = grid.centres;
  // Cubic cells (one scale for the three axes, from the longest side): with a cell per axis the
  // thin axis of a sheet would be split as often as its long ones, into slabs as wide as the sheet.
  const double longest = std::max({double{cbox.hi.x} - cbox.lo.x, double{cbox.hi.y} - cbox.lo.y, double{cbox.hi.z} - cbox.lo.z});
  grid.cells = longest > 0 ? kMortonCells / longest : 0.0;
  grid.slack = 1e-6 * longest;
  const double scale[3] = {grid.cells, grid.cells, grid.cells};
  volume::ScratchVector<std::uint32_t> code(n), tmp_code(n);  // each written in full before it is read
  std::vector<std::uint32_t> tmp_face(n);
  volume::in_two_halves(n, two, [&](std::size_t begin, std::size_t end, int) {
    morton_codes(m, cbox.lo, scale, static_cast<std::uint32_t>(begin), static_cast<std::uint32_t>(end), code.data());
  });
  for (std::uint32_t f = 0; f < n; ++f) order_[f] = f;
  radix_sort(code, order_, tmp_code, tmp_face, two);

  // 2. The tree over the sorted faces, top down (split()): to the leaves, or to the blocks. The
  //    node array is mapped at its largest size (a leaf of one face is 2 nodes a face; the
  //    blocks' nodes lie past 2·#F), its pages zero until a node on them is made.
  const std::size_t capacity = (in_blocks ? 4 : 2) * n;
  allocate_nodes(capacity);
  parent_.resize(capacity);
  leaf_of_.resize(n);
  std::uint32_t next = 1;
  depth_ = split(0, 0, static_cast<std::uint32_t>(n), 1, in_blocks ? kBlockFaces : 0, next, code.data());
  top_ = next;
  made_ = top_;
  if (!in_blocks) {
    // 3. The boxes, bottom up: the leaves from their faces, with each face's leaf (two threads for
    //    a large mesh), then the internal nodes from their children.
    fit_nodes(m, 0, top_, two);
    return;
  }
  // 3. Blocks: each face's place (to find a face's block), the sorted codes (to split a block),
  //    each block's box from its cell, then the boxes above them.
  rank_.resize(n);
  volume::in_two_halves(n, two, [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t i = begin; i < end; ++i) rank_[order_[i]] = static_cast<std::uint32_t>(i);
  });
  code_ = std::move(code);
  for (const Block& b : blocks_) {
    const Box box = block_box(grid, code_[b.begin], code_[b.end - 1]);
    nodes_[b.node].lo = box.lo;
    nodes_[b.node].hi = box.hi;
  }
  fit_nodes(m, 0, top_, false);
  lazy_ = std::make_unique<Lazy>();
  lazy_->made = std::make_unique<std::atomic<std::uint8_t>[]>(blocks_.size());
}

std::size_t TriangleBvh::split(std::uint32_t root, std::uint32_t begin, std::uint32_t end, std::size_t depth, std::uint32_t block_faces,
                               std::uint32_t& next, const std::uint32_t* code) const {
  // Depth first, the left child first, each node's children side by side: a range splits where
  // its codes' highest differing bit turns on (the octree cell's halves), or at its middle where
  // every code is equal. Each split uses up a bit of 30, and the middle splits halve the count,
  // so depth stays below 30 + log2(n) + 1 (+ 1 for a block's node).
  struct Task {
    std::uint32_t node, begin, end;
    std::size_t depth;
  };
  std::array<Task, kMaxDepth + 2> tasks;  // a pop pushes at most two: never more than depth + 1
  std::size_t top = 0, deepest = 0;
  tasks[top++] = {root, begin, end, depth};
  const auto base = static_cast<std::uint32_t>(2 * order_.size());
  while (top > 0) {
    const Task task = tasks[--top];
    deepest = std::max(deepest, task.depth);
    Node& node = nodes_[task.node];
    const std::uint32_t count = task.end - task.begin;
    if (count <= block_faces) {  // a block: its nodes lie from base + 2·begin on, made on first use
      node.first = static_cast<std::uint32_t>(blocks_.size());
      node.count = kBlockNode;
      blocks_.push_back({task.begin, task.end, task.node, base + 2 * task.begin, 0, static_cast<std::uint32_t>(task.depth)});
      continue;
    }
    if (count <= kMaxLeafFaces) {
      node.first = task.begin;
      node.count = count;
      continue;
    }
    std::uint32_t mid = task.begin + count / 2;
    const std::uint32_t differ = code[task.begin] ^ code[task.end - 1];
    if (differ != 0) {
      const std::uint32_t bit = 1u << (31 - std::countl_zero(differ));
      mid = static_cast<std::uint32_t>(std::partition_point(code + task.begin, code + task.end, [&](std::uint32_t c) { return (c & bit) == 0; }) -
                                       code);
    }
    const std::uint32_t child = next;
    next += 2;
    node.first = child;
    node.count = 0;
    parent_[child] = task.node;
    parent_[child + 1] = task.node;
    assert(top + 2 <= tasks.size() && task.depth < kMaxDepth && "TriangleBvh: tree deeper than the traversal stacks");
    tasks[top++] = {child + 1, mid, task.end, task.depth + 1};
    tasks[top++] = {child, task.begin, mid, task.depth + 1};
  }
  return deepest;
}

void TriangleBvh::fit_nodes(const MeshView& m, std::uint32_t begin, std::uint32_t end, bool two) const {
  volume::in_two_halves(end - begin, two, [&](std::size_t b, std::size_t e, int) {
    for (std::size_t i = begin + b; i < begin + e; ++i)
      if (is_leaf(nodes_[i])) {
        refit_leaf(m, nodes_[i]);
        for (std::uint32_t k = nodes_[i].first; k < nodes_[i].first + nodes_[i].count; ++k) leaf_of_[order_[k]] = static_cast<std::uint32_t>(i);
      }
  });
  // Children come after their parent, so one backward sweep is bottom-up. A made block's node
  // takes its root's box; one not made keeps the box of its cell.
  for (std::uint32_t i = end; i-- > begin;) {
    Node& node = nodes_[i];
    if (node.count == 0 || (node.count == kBlockNode && blocks_[node.first].used > 0)) fit_to_children(node);
  }
}

void TriangleBvh::fit_to_children(Node& node) const {
  if (node.count == kBlockNode) {
    const Node& root = nodes_[blocks_[node.first].root];
    node.lo = root.lo;
    node.hi = root.hi;
    return;
  }
  const Node& l = nodes_[node.first];
  const Node& r = nodes_[node.first + 1];
  node.lo = {std::min(l.lo.x, r.lo.x), std::min(l.lo.y, r.lo.y), std::min(l.lo.z, r.lo.z)};
  node.hi = {std::max(l.hi.x, r.hi.x), std::max(l.hi.y, r.hi.y), std::max(l.hi.z, r.hi.z)};
}

void TriangleBvh::make_block(const MeshView& m, std::uint32_t k) const {
  Block& b = blocks_[k];
  std::uint32_t next = b.root + 1;
  parent_[b.root] = b.node;
  const std::size_t deepest = split(b.root, b.begin, b.end, b.depth + 1, 0, next, code_.data());
  fit_nodes(m, b.root, next, false);
  b.used = next - b.root;
  made_ += b.used;
  depth_ = std::max(depth_, deepest);
}

std::uint32_t TriangleBvh::open(const MeshView& m, std::uint32_t k) const {
  std::atomic<std::uint8_t>& made = lazy_->made[k];
  if (made.load(std::memory_order_acquire) == 0) {
    const std::lock_guard lock(lazy_->mutex);
    if (made.load(std::memory_order_relaxed) == 0) {
      make_block(m, k);
      made.store(1, std::memory_order_release);
    }
  }
  return blocks_[k].root;
}

void TriangleBvh::expand(const MeshView& m) const {
  for (std::uint32_t k = 0; k < blocks_.size(); ++k) open(m, k);
}

template <class Fn>
void TriangleBvh::for_each_made_range(Fn&& fn) const {
  if (top_ > 0) fn(std::uint32_t{0}, top_);
  for (const Block& b : blocks_)
    if (b.used > 0) fn(b.root, b.root + b.used);
}

std::size_t TriangleBvh::node_count() const {
  if (!lazy_) return made_;
  const std::lock_guard lock(lazy_->mutex);
  return made_;
}

std::size_t TriangleBvh::depth() const {
  if (!lazy_) return depth_;
  const std::lock_guard lock(lazy_->mutex);
  return depth_;
}

std::size_t TriangleBvh::blocks_made() const {
  if (!lazy_) return 0;
  const std::lock_guard lock(lazy_->mutex);
  return static_cast<std::size_t>(std::count_if(blocks_.begin(), blocks_.end(), [](const Block& b) { return b.used > 0; }));
}

bool TriangleBvh::same_tree(const TriangleBvh& o) const {
  if (order_ != o.order_ || leaf_of_ != o.leaf_of_ || top_ != o.top_ || made_ != o.made_ || depth_ != o.depth_ || blocks_.size() != o.blocks_.size())
    return false;
  for (std::size_t k = 0; k < blocks_.size(); ++k) {
    const Block &a = blocks_[k], &b = o.blocks_[k];
    if (a.begin != b.begin || a.end != b.end || a.node != b.node || a.root != b.root || a.used != b.used || a.depth != b.depth) return false;
  }
  bool same = true;
  for_each_made_range([&](std::uint32_t begin, std::uint32_t end) {
    for (std::uint32_t i = begin; same && i < end; ++i) {
      const Node &a = nodes_[i], &b = o.nodes_[i];
      same = a.lo == b.lo && a.hi == b.hi && a.first == b.first && a.count == b.count && parent_[i] == o.parent_[i];
    }
  });
  return same;
}

void TriangleBvh::refit_leaf(const MeshView& m, Node& node) const {
  Box b;
  for (std::uint32_t i = node.first; i < node.first + node.count; ++i) b.grow(face_box(m, order_[i]));
  node.lo = b.lo;
  node.hi = b.hi;
}

void TriangleBvh::refit(const MeshView& m) {
  assert(m.faces.size() == order_.size() && "TriangleBvh::refit: face count changed since build");
  // Every block made first (from the boxes of the faces as they are now), then each block's
  // nodes and the top's, bottom up.
  expand(m);
  for (const Block& b : blocks_) fit_nodes(m, b.root, b.root + b.used, false);
  fit_nodes(m, 0, top_, false);
}

void TriangleBvh::refit_up(std::uint32_t i, bool stop_when_unchanged) {
  // Every internal box is the exact union of its children (a made block's node, its root's box),
  // so once a box comes out unchanged its ancestors are unchanged too.
  while (i != 0) {
    i = parent_[i];
    Node& node = nodes_[i];
    const Vec3f lo = node.lo, hi = node.hi;
    fit_to_children(node);
    if (stop_when_unchanged && node.lo == lo && node.hi == hi) break;
  }
}

void TriangleBvh::refit_faces(const MeshView& m, std::span<const std::uint32_t> faces) {
  assert(m.faces.size() == order_.size() && "TriangleBvh::refit_faces: face count changed since build");
  for (std::uint32_t f : faces) {
    assert(f < leaf_of_.size() && "TriangleBvh::refit_faces: face index out of range");
    const std::uint32_t i = leaf_of_[f];
    if (lazy_ && i == 0) {
      // Its block is not made (in a lazy tree node 0 is never a leaf): made now from the faces as
      // they are, and the boxes above its root fitted to it all the way up (the block's node
      // held the box of its cell, which the moved faces may have left).
      const auto block = static_cast<std::uint32_t>(
          std::upper_bound(blocks_.begin(), blocks_.end(), rank_[f], [](std::uint32_t r, const Block& b) { return r < b.begin; }) -
          blocks_.begin() - 1);
      refit_up(open(m, block), false);
      continue;
    }
    Node& leaf = nodes_[i];
    const Vec3f lo = leaf.lo, hi = leaf.hi;
    refit_leaf(m, leaf);
    if (leaf.lo == lo && leaf.hi == hi) continue;
    refit_up(i, true);
  }
}

// ---------------------------------------------------------------------------------------------

bool TriangleBvh::check(const MeshView& m) const {
  const std::size_t n = order_.size();
  if (m.faces.size() != n || leaf_of_.size() != n) return false;
  if (n == 0) return !nodes_ && made_ == 0;
  if (!nodes_ || depth_ > kMaxDepth) return false;
  expand(m);
  std::vector<std::uint8_t> seen(n, 0);
  bool ok = true;
  const auto box_holds = [&](const Node& outer, const Node& inner) { return encloses(outer.lo, outer.hi, inner.lo) && encloses(outer.lo, outer.hi, inner.hi); };
  for_each_made_range([&](std::uint32_t begin, std::uint32_t end) {
    for (std::uint32_t i = begin; ok && i < end; ++i) {
      const Node& node = nodes_[i];
      ok = node.lo.x <= node.hi.x && node.lo.y <= node.hi.y && node.lo.z <= node.hi.z;
      if (!ok) break;
      if (is_leaf(node)) {
        ok = std::size_t{node.first} + node.count <= n;
        for (std::uint32_t k = node.first; ok && k < node.first + node.count; ++k) {
          const std::uint32_t f = order_[k];
          ok = f < n && seen[f]++ == 0 && leaf_of_[f] == i;
          for (std::uint32_t vi : ok ? m.faces[f] : std::array<std::uint32_t, 3>{})
            ok = ok && vi < m.n_vertices && encloses(node.lo, node.hi, vertex(m, vi));
        }
      } else if (node.count == kBlockNode) {
        ok = node.first < blocks_.size() && blocks_[node.first].node == i && parent_[blocks_[node.first].root] == i &&
             box_holds(node, nodes_[blocks_[node.first].root]);
      } else {
        ok = node.count == 0 && node.first > i && node.first + 1 < end;
        for (std::uint32_t c : {node.first, node.first + 1}) ok = ok && parent_[c] == i && box_holds(node, nodes_[c]);
      }
    }
  });
  return ok && std::all_of(seen.begin(), seen.end(), [](std::uint8_t s) { return s == 1; });
}

std::size_t TriangleBvh::size_bytes() const {
  const std::size_t made = node_count();
  return made * (sizeof(Node) + sizeof(std::uint32_t)) + (order_.size() + leaf_of_.size() + rank_.size() + code_.size()) * sizeof(std::uint32_t) +
         blocks_.size() * sizeof(Block);
}

}  // namespace lancet::surface
