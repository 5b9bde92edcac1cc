#include "volume/chainmail.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <utility>

#include "text/text.hpp"

namespace lancet::volume {
namespace {

constexpr int kBrickShift = 3;                       // bricks of 8 × 8 × 8 elements
constexpr int kBrickEdge = 1 << kBrickShift;
constexpr std::uint32_t kBrickElements = 512;
constexpr std::uint32_t kLocalBits = 9;              // ref = brick << 11 | axis << 9 | local
constexpr std::uint32_t kRefBrickShift = 11;
constexpr std::uint32_t kMaxBricks = 1u << (32 - kRefBrickShift);
// Mark, one 64-bit word per element: everything a step reads about an element but its
// displacement. step << 32 | material << 24 | links << 16 | key axis << 8 | moved << 6 | 2 bits
// of state per axis (0 untouched, 1 queued, 2 final). Step, key axis, moved and states belong to
// the step in the high bits (a mark from an earlier step reads as untouched); links (bit d: the
// link in direction d is live) and material belong to the lattice.
constexpr int kTagShift = 32;
constexpr int kKeyAxisShift = 8, kLinksShift = 16, kMatShift = 24;
constexpr std::uint64_t kMovedBit = 1u << 6;
constexpr std::uint64_t kQueued = 1, kFinal = 2;
constexpr std::uint64_t kSponsorKey = 4;  // key axis of a sponsor, besides 0..2
constexpr std::uint64_t kLatticeBits = 0xFFFFull << kLinksShift;  // links and material
constexpr std::uint64_t kStepBits = ~std::uint64_t{0} << kTagShift;
constexpr std::uint64_t kMaxStep = 0xFFFFFFFFull;                 // then every mark's step is cleared
constexpr std::uint64_t kEmptyKey = ~std::uint64_t{0};
constexpr int kMaxDim = 1 << 24;
constexpr double kInf = std::numeric_limits<double>::infinity();

// Directions d = 2·axis + (1 for the negative side); the opposite of d is d ^ 1.
constexpr int kAxisOf[6] = {0, 0, 1, 1, 2, 2};
constexpr int kStep[6] = {1, -1, 1, -1, 1, -1};

double& comp(Vec3& v, int a) noexcept { return a == 0 ? v.x : (a == 1 ? v.y : v.z); }

const char* axis_name(int a) noexcept { return a == 0 ? "x" : (a == 1 ? "y" : "z"); }

std::string num(double v) { return text::format("%.9g", v); }

std::string index_text(const ChainMail::Index& e) {
  return "(" + std::to_string(e[0]) + ", " + std::to_string(e[1]) + ", " + std::to_string(e[2]) + ")";
}

[[noreturn]] void fail(const std::string& what) { throw std::invalid_argument(what); }

std::uint64_t brick_key(std::int64_t bx, std::int64_t by, std::int64_t bz) noexcept {
  return static_cast<std::uint64_t>(bx) | (static_cast<std::uint64_t>(by) << 21) | (static_cast<std::uint64_t>(bz) << 42);
}

std::size_t hash_slot(std::uint64_t key, std::size_t mask) noexcept {
  key *= 0x9E3779B97F4A7C15ull;
  return static_cast<std::size_t>(key ^ (key >> 29)) & mask;
}

unsigned links_of(std::uint64_t mark) noexcept { return static_cast<unsigned>(mark >> kLinksShift) & 63u; }
std::size_t mat_of(std::uint64_t mark) noexcept { return static_cast<std::size_t>((mark >> kMatShift) & 0xFFu); }
}  // namespace

// A brick's elements as arrays (structure of arrays): a step settling one axis reads only that
// axis's displacements and the marks, 16 of the 40 bytes per element, so the cache holds 2.5
// times the region it would with whole elements; an x-row of 8 elements shares a cache line.
struct alignas(64) ChainMail::Brick {
  std::array<std::array<double, kBrickElements>, 3> u;  // m, displacement from rest per axis
  std::array<std::uint64_t, kBrickElements> mark;        // see kTagShift
  std::array<double, kBrickElements> key;                // m, the violation it is queued with on its key axis
  std::array<std::int32_t, 6> nbr;    // brick index in direction d, -1 none yet
  std::array<Brick*, 6> nbrp;         // the same bricks (stable: each brick is its own allocation)
  std::array<std::int32_t, 3> coord;  // brick coordinates
  std::int32_t uniform;               // the material of every element it links and of its neighbours, -1 when mixed

  [[nodiscard]] Vec3 displacement(std::uint32_t l) const noexcept { return {u[0][l], u[1][l], u[2][l]}; }
};

namespace {

// State of axis a in a mark, for the step `step`.
std::uint64_t axis_state(std::uint64_t mark, std::uint64_t step, int a) noexcept {
  return (mark >> kTagShift) == step ? (mark >> (2 * a)) & 3u : 0;
}
// Heap key of a violation: larger violations give smaller keys. Violations are counted in
// quanta (a quarter of the tolerance), so that equal violations reached along different paths
// (equal but for rounding) tie, and ties are taken in the order that keeps the step local.
std::uint64_t heap_key(double violation, double inv_quantum) noexcept {
  const double q = std::min(violation * inv_quantum, 0x1p62);  // > 0: a violation is > eps
  return ~static_cast<std::uint64_t>(static_cast<std::int64_t>(q));
}
// Whether coordinate A of an element (its mark and key) must be (re-)queued with `violation` in
// the step whose mark bits are `tag`; if so, marks it queued and records the violation. An element
// keeps one key: while another axis of it holds it, re-queueing is not filtered (a stale
// duplicate costs one skipped pop). Sponsors are never queued.
template <int A>
[[gnu::always_inline]] inline bool queue_state(std::uint64_t& mark_ref, double& key, std::uint64_t tag, double violation) noexcept {
  std::uint64_t mark = mark_ref;
  if ((mark & kStepBits) != tag) {  // untouched in this step
    mark_ref = tag | (mark & kLatticeBits) | (std::uint64_t{A} << kKeyAxisShift) | (kQueued << (2 * A));
    key = violation;
    return true;
  }
  const auto key_axis = static_cast<unsigned>(mark >> kKeyAxisShift) & 7u;
  if (key_axis == kSponsorKey) return false;
  const std::uint64_t state = (mark >> (2 * A)) & 3u;
  if (state == kFinal) return false;
  if (state == kQueued && key_axis == A && violation <= key) return false;  // already queued at least this high
  if (key_axis == A || ((mark >> (2 * key_axis)) & 3u) != kQueued) {
    key = violation;
    mark = (mark & ~(std::uint64_t{7} << kKeyAxisShift)) | (std::uint64_t{A} << kKeyAxisShift);
  }
  mark_ref = (mark & ~(std::uint64_t{3} << (2 * A))) | (kQueued << (2 * A));
  return true;
}

template <int A>
double& at(Vec3& v) noexcept {
  if constexpr (A == 0) return v.x;
  else if constexpr (A == 1) return v.y;
  else return v.z;
}
template <int A>
double at(const Vec3& v) noexcept {
  if constexpr (A == 0) return v.x;
  else if constexpr (A == 1) return v.y;
  else return v.z;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Model

ChainMailMaterial ChainMailMaterial::relative(Vec3 spacing, double compression, double stretch, double shear) {
  ChainMailMaterial m;
  for (int a = 0; a < 3; ++a) {
    const double s = comp(spacing, a);
    m.axis[static_cast<std::size_t>(a)] = {(1.0 - compression) * s, (1.0 + stretch) * s, shear * s};
  }
  return m;
}

ChainMailMaterial ChainMailMaterial::air() {
  ChainMailMaterial m;
  m.present = false;
  return m;
}

ChainMailLattice ChainMailLattice::of(const Volume& v) { return {v.dims, v.spacing, v.origin}; }

ChainMail::ChainMail(const ChainMailLattice& lattice, std::vector<ChainMailMaterial> materials,
                     std::span<const std::uint8_t> material_ids)
    : lattice_(lattice), materials_(std::move(materials)), ids_(material_ids) {
  const char* kWho = "ChainMail: ";
  for (int a = 0; a < 3; ++a) {
    const int n = lattice_.dims[static_cast<std::size_t>(a)];
    if (n < 1 || n > kMaxDim)
      fail(std::string(kWho) + "lattice.dims[" + std::to_string(a) + "] = " + std::to_string(n) + ", must be 1.." +
           std::to_string(kMaxDim));
    const double s = comp(lattice_.spacing, a);
    if (!(std::isfinite(s) && s > 0))
      fail(std::string(kWho) + "lattice.spacing." + axis_name(a) + " = " + num(s) + " m, must be finite and > 0");
    const double o = comp(lattice_.origin, a);
    if (!std::isfinite(o)) fail(std::string(kWho) + "lattice.origin." + axis_name(a) + " = " + num(o) + " m, must be finite");
  }
  if (materials_.empty() || materials_.size() > 256)
    fail(std::string(kWho) + "materials has " + std::to_string(materials_.size()) + " entries, must be 1..256");
  for (std::size_t m = 0; m < materials_.size(); ++m) {
    if (!materials_[m].present) continue;
    for (int a = 0; a < 3; ++a) {
      const ChainMailAxisLimits& L = materials_[m].axis[static_cast<std::size_t>(a)];
      const std::string field = std::string(kWho) + "materials[" + std::to_string(m) + "].axis[" + std::to_string(a) + "] (" +
                                axis_name(a) + "): ";
      if (!std::isfinite(L.min_length) || L.min_length < 0)
        fail(field + "min_length = " + num(L.min_length) + " m, must be finite and >= 0");
      if (!std::isfinite(L.max_length)) fail(field + "max_length = " + num(L.max_length) + " m, must be finite");
      if (!std::isfinite(L.max_shear) || L.max_shear < 0)
        fail(field + "max_shear = " + num(L.max_shear) + " m, must be finite and >= 0");
      if (L.min_length > L.max_length)
        fail(field + "min_length = " + num(L.min_length) + " m > max_length = " + num(L.max_length) + " m");
      const double s = comp(lattice_.spacing, a);
      if (s < L.min_length || s > L.max_length)
        fail(field + "rest spacing " + num(s) + " m is outside [min_length, max_length] = [" + num(L.min_length) + ", " +
             num(L.max_length) + "] m, so the rest state would be invalid");
    }
  }
  if (!ids_.empty()) {
    std::size_t voxels = 0;
    const bool overflow = __builtin_mul_overflow(static_cast<std::size_t>(lattice_.dims[0]), static_cast<std::size_t>(lattice_.dims[1]), &voxels) ||
                          __builtin_mul_overflow(voxels, static_cast<std::size_t>(lattice_.dims[2]), &voxels);
    if (overflow || ids_.size() != voxels)
      fail(std::string(kWho) + "material_ids has " + std::to_string(ids_.size()) + " entries, expected nx*ny*nz = " +
           std::to_string(voxels) + " (or none)");
    const auto it = std::find_if(ids_.begin(), ids_.end(), [&](std::uint8_t v) { return v >= materials_.size(); });
    if (it != ids_.end())
      fail(std::string(kWho) + "material_ids[" + std::to_string(it - ids_.begin()) + "] = " + std::to_string(*it) +
           ", but there are only " + std::to_string(materials_.size()) + " materials");
  }

  // Link boxes for every pair of materials: the mean of both materials' limits, in displacement
  // form (the neighbour's displacement minus the element's).
  n_materials_ = materials_.size();
  for (auto& boxes : axis_boxes_) boxes.assign(n_materials_ * n_materials_ * 6, AxisBox{});
  for (std::size_t m1 = 0; m1 < n_materials_; ++m1)
    for (std::size_t m2 = 0; m2 < n_materials_; ++m2) {
      if (!materials_[m1].present || !materials_[m2].present) continue;
      for (int d = 0; d < 6; ++d) {
        const int a = kAxisOf[d];
        const ChainMailAxisLimits& A = materials_[m1].axis[static_cast<std::size_t>(a)];
        const ChainMailAxisLimits& B = materials_[m2].axis[static_cast<std::size_t>(a)];
        const double s = comp(lattice_.spacing, a);
        const double dlo = 0.5 * (A.min_length + B.min_length) - s;  // <= 0
        const double dhi = 0.5 * (A.max_length + B.max_length) - s;  // >= 0
        const double shear = 0.5 * (A.max_shear + B.max_shear);
        const std::size_t box = (m1 * n_materials_ + m2) * 6 + static_cast<std::size_t>(d);
        for (int b = 0; b < 3; ++b) axis_boxes_[static_cast<std::size_t>(b)][box] = {-shear, shear};
        axis_boxes_[static_cast<std::size_t>(a)][box] = {kStep[d] > 0 ? dlo : -dhi, kStep[d] > 0 ? dhi : -dlo};
      }
    }
  const double smin = std::min({lattice_.spacing.x, lattice_.spacing.y, lattice_.spacing.z});
  eps_ = 1e-9 * smin;
  inv_quantum_ = 4 / eps_;
}

ChainMail::~ChainMail() = default;
ChainMail::ChainMail(ChainMail&&) noexcept = default;
ChainMail& ChainMail::operator=(ChainMail&&) noexcept = default;

// ---------------------------------------------------------------------------------------------
// Lattice and bricks

std::uint8_t ChainMail::material_at(std::int64_t i, std::int64_t j, std::int64_t k) const noexcept {
  if (ids_.empty()) return 0;
  const auto nx = static_cast<std::size_t>(lattice_.dims[0]), ny = static_cast<std::size_t>(lattice_.dims[1]);
  return ids_[static_cast<std::size_t>(i) + nx * (static_cast<std::size_t>(j) + ny * static_cast<std::size_t>(k))];
}

bool ChainMail::present_at(std::int64_t i, std::int64_t j, std::int64_t k) const noexcept {
  if (i < 0 || j < 0 || k < 0 || i >= lattice_.dims[0] || j >= lattice_.dims[1] || k >= lattice_.dims[2]) return false;
  return materials_[material_at(i, j, k)].present;
}

std::int32_t ChainMail::find_brick(std::int64_t bx, std::int64_t by, std::int64_t bz) const noexcept {
  if (hash_keys_.empty() || bx < 0 || by < 0 || bz < 0) return -1;
  const std::uint64_t key = brick_key(bx, by, bz);
  const std::size_t mask = hash_keys_.size() - 1;
  for (std::size_t s = hash_slot(key, mask);; s = (s + 1) & mask) {
    if (hash_keys_[s] == key) return hash_vals_[s];
    if (hash_keys_[s] == kEmptyKey) return -1;
  }
}

namespace {
// Sets the lattice bits of a brick's marks from the lattice: material, and link bit d set when the
// element and its neighbour in direction d are both present (presence read once into a 10³ halo).
// The step bits are kept. Returns the material of every present element of the brick and of the
// halo around it when they all have the same one (then every link of the brick joins two elements
// of that material), else -1.
template <class PresentAt, class MaterialAt>
std::int32_t fill_brick_links(std::array<std::uint64_t, kBrickElements>& marks,
                      const std::array<std::int32_t, 3>& coord, const std::array<int, 3>& dims, PresentAt present_at,
                      MaterialAt material_at) {
  std::array<bool, 1000> pres{};
  const std::int64_t i0 = std::int64_t{coord[0]} * kBrickEdge, j0 = std::int64_t{coord[1]} * kBrickEdge,
                     k0 = std::int64_t{coord[2]} * kBrickEdge;
  std::int32_t uniform = -2;  // -2: no present element yet
  for (int hz = 0; hz < 10; ++hz)
    for (int hy = 0; hy < 10; ++hy)
      for (int hx = 0; hx < 10; ++hx) {
        const std::int64_t i = i0 + hx - 1, j = j0 + hy - 1, k = k0 + hz - 1;
        const bool p = present_at(i, j, k);
        pres[static_cast<std::size_t>(hx + 10 * (hy + 10 * hz))] = p;
        if (!p) continue;
        const std::int32_t m = material_at(i, j, k);
        uniform = uniform == -2 || uniform == m ? m : -1;
      }
  constexpr int kHaloStep[6] = {1, -1, 10, -10, 100, -100};
  for (std::uint32_t l = 0; l < kBrickElements; ++l) {
    const int lx = static_cast<int>(l & 7u), ly = static_cast<int>((l >> 3) & 7u), lz = static_cast<int>(l >> 6);
    const std::int64_t i = i0 + lx, j = j0 + ly, k = k0 + lz;
    const bool inside = i < dims[0] && j < dims[1] && k < dims[2];
    const std::uint64_t mat = inside ? material_at(i, j, k) : std::uint8_t{0};
    const int h = (lx + 1) + 10 * ((ly + 1) + 10 * (lz + 1));
    std::uint64_t bits = 0;
    if (pres[static_cast<std::size_t>(h)])
      for (int d = 0; d < 6; ++d)
        if (pres[static_cast<std::size_t>(h + kHaloStep[d])]) bits |= 1u << d;
    marks[l] = (marks[l] & ~kLatticeBits) | (mat << kMatShift) | (bits << kLinksShift);
  }
  return std::max(uniform, std::int32_t{-1});
}
}  // namespace

std::int32_t ChainMail::materialise_brick(std::int64_t bx, std::int64_t by, std::int64_t bz) {
  if (const std::int32_t found = find_brick(bx, by, bz); found >= 0) return found;
  if (bricks_.size() >= kMaxBricks) throw std::length_error("ChainMail: more than 2^21 bricks materialised");
  auto brick = std::make_unique<Brick>();
  Brick& B = *brick;
  B.coord = {static_cast<std::int32_t>(bx), static_cast<std::int32_t>(by), static_cast<std::int32_t>(bz)};
  B.nbr.fill(-1);
  B.nbrp.fill(nullptr);
  for (auto& axis : B.u) axis.fill(0.0);
  B.mark.fill(0);
  B.key.fill(0.0);
  B.uniform = fill_brick_links(
      B.mark, B.coord, lattice_.dims,
      [this](std::int64_t i, std::int64_t j, std::int64_t k) { return present_at(i, j, k); },
      [this](std::int64_t i, std::int64_t j, std::int64_t k) { return material_at(i, j, k); });
  const auto index = static_cast<std::int32_t>(bricks_.size());
  bricks_.push_back(std::move(brick));

  // Insert into the hash (load <= 1/2).
  if ((hash_count_ + 1) * 2 > hash_keys_.size()) {
    const std::size_t cap = std::max<std::size_t>(64, hash_keys_.size() * 2);
    std::vector<std::uint64_t> keys(cap, kEmptyKey);
    std::vector<std::int32_t> vals(cap, -1);
    for (std::size_t s = 0; s < hash_keys_.size(); ++s) {
      if (hash_keys_[s] == kEmptyKey) continue;
      std::size_t t = hash_slot(hash_keys_[s], cap - 1);
      while (keys[t] != kEmptyKey) t = (t + 1) & (cap - 1);
      keys[t] = hash_keys_[s];
      vals[t] = hash_vals_[s];
    }
    hash_keys_.swap(keys);
    hash_vals_.swap(vals);
  }
  const std::uint64_t key = brick_key(bx, by, bz);
  std::size_t s = hash_slot(key, hash_keys_.size() - 1);
  while (hash_keys_[s] != kEmptyKey) s = (s + 1) & (hash_keys_.size() - 1);
  hash_keys_[s] = key;
  hash_vals_[s] = index;
  ++hash_count_;

  // Link the 6 neighbour bricks both ways, so that the step never hashes.
  for (int d = 0; d < 6; ++d) {
    std::int64_t c[3] = {bx, by, bz};
    c[kAxisOf[d]] += kStep[d];
    const std::int32_t other = find_brick(c[0], c[1], c[2]);
    if (other < 0) continue;
    Brick& O = *bricks_[static_cast<std::size_t>(other)];
    B.nbr[static_cast<std::size_t>(d)] = other;
    B.nbrp[static_cast<std::size_t>(d)] = &O;
    O.nbr[static_cast<std::size_t>(d ^ 1)] = index;
    O.nbrp[static_cast<std::size_t>(d ^ 1)] = &B;
  }
  return index;
}

std::uint32_t ChainMail::materialise_element(const Index& e) {
  const std::int32_t b = materialise_brick(e[0] >> kBrickShift, e[1] >> kBrickShift, e[2] >> kBrickShift);
  const auto local = static_cast<std::uint32_t>((e[0] & 7) | ((e[1] & 7) << 3) | ((e[2] & 7) << 6));
  return (static_cast<std::uint32_t>(b) << kRefBrickShift) | local;
}

bool ChainMail::present(const Index& e) const noexcept { return present_at(e[0], e[1], e[2]); }

bool ChainMail::linked(const Index& e, int axis) const noexcept {
  if (axis < 0 || axis > 2) return false;
  Index n = e;
  ++n[static_cast<std::size_t>(axis)];
  if (!present(e) || !present(n)) return false;
  const std::int32_t b = find_brick(e[0] >> kBrickShift, e[1] >> kBrickShift, e[2] >> kBrickShift);
  if (b < 0) return true;  // cut links always live in materialised bricks
  const auto local = static_cast<std::uint32_t>((e[0] & 7) | ((e[1] & 7) << 3) | ((e[2] & 7) << 6));
  return ((links_of(bricks_[static_cast<std::size_t>(b)]->mark[local]) >> (2 * axis)) & 1u) != 0;
}

Vec3 ChainMail::rest_position(const Index& e) const noexcept {
  return lattice_.origin + Vec3{e[0] * lattice_.spacing.x, e[1] * lattice_.spacing.y, e[2] * lattice_.spacing.z};
}

Vec3 ChainMail::displacement(const Index& e) const noexcept {
  if (e[0] < 0 || e[1] < 0 || e[2] < 0 || e[0] >= lattice_.dims[0] || e[1] >= lattice_.dims[1] || e[2] >= lattice_.dims[2])
    return {};
  const std::int32_t b = find_brick(e[0] >> kBrickShift, e[1] >> kBrickShift, e[2] >> kBrickShift);
  if (b < 0) return {};
  const auto local = static_cast<std::uint32_t>((e[0] & 7) | ((e[1] & 7) << 3) | ((e[2] & 7) << 6));
  return bricks_[static_cast<std::size_t>(b)]->displacement(local);
}

void ChainMail::check_element(const Index& e, const char* what) const {
  for (std::size_t a = 0; a < 3; ++a)
    if (e[a] < 0 || e[a] >= lattice_.dims[a])
      fail(std::string(what) + " element " + index_text(e) + " is outside the lattice (dims " +
           index_text(lattice_.dims) + ")");
  if (!present(e)) fail(std::string(what) + " element " + index_text(e) + " is not present (its material is air)");
}

// ---------------------------------------------------------------------------------------------
// Queue: a radix heap (Ahuja et al. 1990) on heap_key(violation), with radix 16: exact
// largest-first, O(1) push, pop amortised O(entries moved), each entry moved at most once per
// hexadecimal digit of the key range (usually once or twice); valid because no push is larger
// than the last pop. Bucket 1 + 16 p + v holds the keys whose highest hexadecimal digit that
// differs from the last popped key is digit p, with value v there; so a bucket of a higher index
// holds only larger keys. Keys equal to the last popped one (ties) are in bucket ties_, taken
// first in, first out: bucket 0, or the bucket that held the least key when all its keys were
// equal (then nothing is moved: a wavefront of equal violations is taken where it was queued).

namespace {
[[gnu::always_inline]] inline std::size_t heap_bucket(std::uint64_t key, std::uint64_t last, std::size_t ties) noexcept {
  const std::uint64_t x = key ^ last;
  const int p = (std::bit_width(x | 1u) - 1) >> 2;  // highest differing digit (when x != 0)
  return x == 0 ? ties : static_cast<std::size_t>(1 + 16 * p + static_cast<int>((key >> (4 * p)) & 15u));
}
}  // namespace

[[gnu::always_inline]] inline void ChainMail::push(std::uint64_t key, std::uint32_t ref, std::uint64_t last, std::size_t ties) {
  key = std::max(key, last);  // larger only after an invalid earlier state: taken next
  const std::size_t b = heap_bucket(key, last, ties);
  heap_[b].push_back({key, ref});
  heap_nonempty_[b >> 6] |= std::uint64_t{1} << (b & 63u);
}

// The ties are used up: the least key of the next non-empty bucket becomes the last popped one,
// and that bucket becomes the ties (all its keys are equal) or is spread over the lower ones.
// False when the heap is empty.
bool ChainMail::refill() {
  heap_[heap_ties_].clear();
  heap_nonempty_[heap_ties_ >> 6] &= ~(std::uint64_t{1} << (heap_ties_ & 63u));
  heap_head_ = 0;
  std::size_t i = 0;
  for (std::size_t w = 0;; ++w) {
    if (w == heap_nonempty_.size()) return false;
    if (heap_nonempty_[w] != 0) {
      i = 64 * w + static_cast<std::size_t>(std::countr_zero(heap_nonempty_[w]));
      break;
    }
  }
  std::vector<HeapEntry>& src = heap_[i];
  std::uint64_t least = src.front().key, most = least;
  for (const HeapEntry& h : src) {
    least = std::min(least, h.key);
    most = std::max(most, h.key);
  }
  heap_last_ = least;
  if (least == most) {  // all ties: taken where they are
    heap_ties_ = i;
    return true;
  }
  heap_ties_ = 0;
  heap_nonempty_[i >> 6] &= ~(std::uint64_t{1} << (i & 63u));
  for (const HeapEntry& h : src) {
    const std::size_t b = heap_bucket(h.key, least, 0);
    heap_[b].push_back(h);
    heap_nonempty_[b >> 6] |= std::uint64_t{1} << (b & 63u);
  }
  src.clear();
  return true;
}

// ---------------------------------------------------------------------------------------------
// The step

namespace {
// For each local element and direction: the neighbour's local index, and whether it lies in the
// neighbour brick across a face (bit d of cross).
struct NeighbourTable {
  std::array<std::array<std::uint16_t, 6>, kBrickElements> local{};
  std::array<std::uint8_t, kBrickElements> cross{};
};
constexpr NeighbourTable make_neighbour_table() {
  NeighbourTable t;
  for (std::uint32_t l = 0; l < kBrickElements; ++l) {
    const int c[3] = {static_cast<int>(l & 7u), static_cast<int>((l >> 3) & 7u), static_cast<int>(l >> 6)};
    for (int d = 0; d < 6; ++d) {
      int n[3] = {c[0], c[1], c[2]};
      n[kAxisOf[d]] += kStep[d];
      if (n[kAxisOf[d]] < 0 || n[kAxisOf[d]] >= kBrickEdge) {
        t.cross[l] = static_cast<std::uint8_t>(t.cross[l] | (1u << d));
        n[kAxisOf[d]] = (n[kAxisOf[d]] + kBrickEdge) % kBrickEdge;
      }
      t.local[l][static_cast<std::size_t>(d)] = static_cast<std::uint16_t>(n[0] | (n[1] << 3) | (n[2] << 6));
    }
  }
  return t;
}
constexpr NeighbourTable kNeighbours = make_neighbour_table();

// The neighbour of local element l of brick b in direction d: in the same brick or across a face
// (brick index -1 when that brick is not materialised).
inline void neighbour_of(const std::array<std::int32_t, 6>& nbr, std::uint32_t b, std::uint32_t l, int d, std::int32_t& nb,
                         std::uint32_t& nl) noexcept {
  nl = kNeighbours.local[l][static_cast<std::size_t>(d)];
  nb = ((static_cast<unsigned>(kNeighbours.cross[l]) >> d) & 1u) != 0 ? nbr[static_cast<std::size_t>(d)] : static_cast<std::int32_t>(b);
}
}  // namespace

std::uint8_t ChainMail::neighbour_material(const Brick& B, std::uint32_t l, int d) const noexcept {
  std::int64_t c[3] = {std::int64_t{B.coord[0]} * kBrickEdge + (l & 7u), std::int64_t{B.coord[1]} * kBrickEdge + ((l >> 3) & 7u),
                       std::int64_t{B.coord[2]} * kBrickEdge + (l >> 6)};
  c[kAxisOf[d]] += kStep[d];
  return material_at(c[0], c[1], c[2]);
}

// Queues coordinate A of a neighbour that lies outside the box [lo, hi] (its displacement on A
// is un; brick nb, -1 when not materialised yet), or raises its priority.
template <int A>
void ChainMail::check_neighbour(std::int32_t nb, std::uint32_t nl, std::int32_t from_brick, int d, double lo, double hi, double un,
                                ChainMailStepResult& r) {
  const double violation = std::max(lo - un, un - hi);
  if (!(violation > eps_)) return;
  if (nb < 0) {
    const std::array<std::int32_t, 3> c0 = bricks_[static_cast<std::size_t>(from_brick)]->coord;
    std::int64_t c[3] = {c0[0], c0[1], c0[2]};
    c[kAxisOf[d]] += kStep[d];
    nb = materialise_brick(c[0], c[1], c[2]);
    r.materialised += kBrickElements;
  }
  Brick& N = *bricks_[static_cast<std::size_t>(nb)];
  if (!queue_state<A>(N.mark[nl], N.key[nl], step_ << kTagShift, violation)) return;
  push(heap_key(violation, inv_quantum_), (static_cast<std::uint32_t>(nb) << kRefBrickShift) | (std::uint32_t{A} << kLocalBits) | nl,
       heap_last_, heap_ties_);
}

// What the queue loop of a step keeps in registers. As members they would be reloaded after
// every store to a mark (std::uint64_t) or a displacement (double), which may alias them.
struct ChainMail::Hot {
  std::uint64_t tag;   // step_ << kTagShift
  std::uint64_t last;  // heap_last_
  std::size_t ties;    // heap_ties_
  double eps;          // eps_
  double inv_quantum;  // inv_quantum_
  std::uint64_t processed = 0, moved = 0, conflicts = 0;
};

// Settles coordinate A of one element: to the nearest point of the intersection of the intervals
// that its neighbours already final on A allow (the middle where they do not intersect: a
// conflict); then checks its other neighbours on A. The hot loop of a step.
template <int A, bool Uniform>
[[gnu::always_inline]] inline void ChainMail::settle(Hot& h, Brick& B, std::uint32_t b, std::uint32_t l, ChainMailStepResult& r) {
  const std::uint64_t self = B.mark[l];
  const unsigned links = links_of(self);
  const std::size_t mat = mat_of(self);
  const AxisBox* row = axis_boxes_[A].data() + mat * n_materials_ * 6;
  const unsigned cross = kNeighbours.cross[l];
  const std::array<std::uint16_t, 6>& nls = kNeighbours.local[l];
  // Pass 1: the bounds of the final neighbours, and what the others need in pass 2. Selects
  // instead of branches (whether a neighbour is final does not predict well): a neighbour that is
  // not final gives the bounds ±inf (x − (±inf)), a final one x − 0 = x (even for x = −0).
  static constexpr double kLoPad[2] = {kInf, 0.0}, kHiPad[2] = {-kInf, 0.0};
  std::array<Brick*, 6> np;  // read only for the bits of `open`, all written
  std::array<double, 6> blo, bhi, un;
  unsigned open = 0;  // bit d: a linked neighbour that is not final on A
  double lo = -kInf, hi = kInf;
  // Final on A in this step: the step bits and A's state bits match.
  constexpr std::uint64_t final_mask = kStepBits | (std::uint64_t{3} << (2 * A));
  const std::uint64_t final_value = h.tag | (kFinal << (2 * A));
#pragma GCC unroll 6
  for (int d = 0; d < 6; ++d) {
    if (((links >> d) & 1u) == 0) continue;
    const auto di = static_cast<std::size_t>(d);
    Brick* NB = ((cross >> d) & 1u) != 0 ? B.nbrp[di] : &B;
    if (NB == nullptr) [[unlikely]] {  // its brick is not materialised: at rest, not final
      const AxisBox& bx = row[static_cast<std::size_t>(neighbour_material(B, l, d)) * 6 + di];
      np[di] = nullptr;
      blo[di] = bx.lo;
      bhi[di] = bx.hi;
      un[di] = 0;
      open |= 1u << d;
      continue;
    }
    const std::uint32_t nl = nls[di];
    const std::uint64_t m = NB->mark[nl];
    const AxisBox& bx = row[(Uniform ? mat : mat_of(m)) * 6 + di];
    const auto fin = static_cast<std::size_t>((m & final_mask) == final_value);
    const double u = NB->u[A][nl], lo_d = bx.lo, hi_d = bx.hi;
    lo = std::max(lo, (u - hi_d) - kLoPad[fin]);
    hi = std::min(hi, (u - lo_d) - kHiPad[fin]);
    np[di] = NB;
    blo[di] = lo_d;
    bhi[di] = hi_d;
    un[di] = u;
    open |= static_cast<unsigned>(fin ^ 1u) << d;
  }
  // Place the coordinate.
  double& uself = B.u[A][l];
  const double before = uself;
  double v;
  if (lo > hi) [[unlikely]] {
    if (lo - hi > h.eps) ++h.conflicts;
    v = 0.5 * (lo + hi);
  } else {
    v = std::min(std::max(before, lo), hi);
  }
  std::uint64_t mark = (self & ~(std::uint64_t{3} << (2 * A))) | (kFinal << (2 * A));  // queued: self is of this step
  if (v != before) {
    uself = v;
    h.moved += (mark & kMovedBit) == 0 ? 1u : 0u;
    mark |= kMovedBit;
  }
  B.mark[l] = mark;
  ++h.processed;
  // Pass 2: queue the neighbours that are outside the interval this coordinate now allows them.
  for (unsigned m = open; m != 0; m &= m - 1) {
    const int d = std::countr_zero(m);
    const auto di = static_cast<std::size_t>(d);
    const double violation = std::max(v + blo[di] - un[di], un[di] - (v + bhi[di]));
    if (!(violation > h.eps)) continue;
    const std::uint32_t nl = nls[di];
    if (np[di] == nullptr) [[unlikely]] {
      check_neighbour<A>(-1, nl, static_cast<std::int32_t>(b), d, v + blo[di], v + bhi[di], un[di], r);
      continue;
    }
    if (!queue_state<A>(np[di]->mark[nl], np[di]->key[nl], h.tag, violation)) continue;
    const std::uint32_t nb = ((cross >> d) & 1u) != 0 ? static_cast<std::uint32_t>(B.nbr[di]) : b;
    push(heap_key(violation, h.inv_quantum), (nb << kRefBrickShift) | (std::uint32_t{A} << kLocalBits) | nl, h.last, h.ties);
  }
}

// Candidates (element, axis), largest violation first, until the queue is empty; stale entries
// (re-queued higher, already final) are skipped.
void ChainMail::drain(ChainMailStepResult& r) {
  Hot h{step_ << kTagShift, heap_last_, heap_ties_, eps_, inv_quantum_};
  std::size_t head = heap_head_;
  for (;;) {
    if (head == heap_[h.ties].size()) {
      if (!refill()) break;
      head = 0;
      h.last = heap_last_;
      h.ties = heap_ties_;
    }
    const std::vector<HeapEntry>& ties = heap_[h.ties];
    const std::uint32_t ref = ties[head++].ref;
    const std::uint32_t b = ref >> kRefBrickShift, l = ref & (kBrickElements - 1);
    const int a = static_cast<int>((ref >> kLocalBits) & 3u);
    Brick& B = *bricks_[b];
    if (((B.mark[l] >> (2 * a)) & 3u) == kFinal) continue;  // queued, so the mark is of this step
    if (B.uniform >= 0) {
      switch (a) {
        case 0: settle<0, true>(h, B, b, l, r); break;
        case 1: settle<1, true>(h, B, b, l, r); break;
        default: settle<2, true>(h, B, b, l, r); break;
      }
    } else {
      switch (a) {
        case 0: settle<0, false>(h, B, b, l, r); break;
        case 1: settle<1, false>(h, B, b, l, r); break;
        default: settle<2, false>(h, B, b, l, r); break;
      }
    }
  }
  heap_head_ = head;
  r.processed += h.processed;
  r.moved += h.moved;
  r.conflicts += h.conflicts;
}

// Places a sponsor (all three coordinates, final), counts a conflict when a neighbour already
// final disagrees, and checks its other neighbours on every axis.
void ChainMail::place_sponsor(std::uint32_t b, std::uint32_t l, Vec3 u, ChainMailStepResult& r) {
  Brick& B = *bricks_[b];
  const std::uint64_t self = B.mark[l];
  const unsigned links = links_of(self);
  const std::size_t row = mat_of(self) * n_materials_;
  bool conflict = false;
  for (int d = 0; d < 6; ++d) {
    if (((links >> d) & 1u) == 0) continue;
    std::int32_t nb;
    std::uint32_t nl = 0;
    neighbour_of(B.nbr, b, l, d, nb, nl);
    if (nb < 0) continue;  // at rest, not final
    const Brick& N = *bricks_[static_cast<std::size_t>(nb)];
    const std::size_t box = (row + mat_of(N.mark[nl])) * 6 + static_cast<std::size_t>(d);
    for (int a = 0; a < 3; ++a) {  // N - u must lie in the box on every axis where N is final
      const auto ai = static_cast<std::size_t>(a);
      const double rel = N.u[ai][nl] - comp(u, a);
      const AxisBox& bx = axis_boxes_[ai][box];
      if (axis_state(N.mark[nl], step_, a) == kFinal && (rel < bx.lo - eps_ || rel > bx.hi + eps_)) conflict = true;
    }
  }
  if (conflict) ++r.conflicts;
  std::uint64_t mark = (step_ << kTagShift) | (self & kLatticeBits) | (kSponsorKey << kKeyAxisShift) | kFinal | kFinal << 2 | kFinal << 4;
  if (!(u == B.displacement(l))) {
    mark |= kMovedBit;
    ++r.moved;
    B.u[0][l] = u.x;
    B.u[1][l] = u.y;
    B.u[2][l] = u.z;
  }
  B.mark[l] = mark;
  ++r.processed;
  for (int d = 0; d < 6; ++d) {
    if (((links >> d) & 1u) == 0) continue;
    std::int32_t nb;
    std::uint32_t nl = 0;
    neighbour_of(B.nbr, b, l, d, nb, nl);
    Vec3 un{};
    std::size_t mn;
    if (nb >= 0) {
      un = bricks_[static_cast<std::size_t>(nb)]->displacement(nl);
      mn = mat_of(bricks_[static_cast<std::size_t>(nb)]->mark[nl]);
    } else {
      mn = neighbour_material(B, l, d);
    }
    const std::size_t box = (row + mn) * 6 + static_cast<std::size_t>(d);
    const AxisBox bx = axis_boxes_[0][box], by = axis_boxes_[1][box], bz = axis_boxes_[2][box];
    // check_neighbour may materialise nb's brick; re-resolve for each axis.
    check_neighbour<0>(nb, nl, static_cast<std::int32_t>(b), d, u.x + bx.lo, u.x + bx.hi, un.x, r);
    neighbour_of(B.nbr, b, l, d, nb, nl);
    check_neighbour<1>(nb, nl, static_cast<std::int32_t>(b), d, u.y + by.lo, u.y + by.hi, un.y, r);
    neighbour_of(B.nbr, b, l, d, nb, nl);
    check_neighbour<2>(nb, nl, static_cast<std::int32_t>(b), d, u.z + bz.lo, u.z + bz.hi, un.z, r);
  }
}

ChainMailStepResult ChainMail::move(const Index& e, Vec3 position) {
  const ChainMailSponsor s{e, position};
  return move(std::span<const ChainMailSponsor>(&s, 1));
}

ChainMailStepResult ChainMail::move(std::span<const ChainMailSponsor> sponsors) {
  // Check everything before touching any state.
  step_linear_.clear();
  for (std::size_t s = 0; s < sponsors.size(); ++s) {
    const auto what = [s] { return "ChainMail::move: sponsors[" + std::to_string(s) + "]"; };  // only on failure: no allocation
    if (!present(sponsors[s].element)) check_element(sponsors[s].element, what().c_str());
    if (!is_finite(sponsors[s].position))
      fail(what() + ".position = (" + num(sponsors[s].position.x) + ", " + num(sponsors[s].position.y) + ", " +
           num(sponsors[s].position.z) + ") m is not finite");
    const Index& e = sponsors[s].element;
    step_linear_.push_back(static_cast<std::uint64_t>(e[0]) |
                           (static_cast<std::uint64_t>(e[1]) << 24) | (static_cast<std::uint64_t>(e[2]) << 48));
  }
  std::sort(step_linear_.begin(), step_linear_.end());
  if (const auto dup = std::adjacent_find(step_linear_.begin(), step_linear_.end()); dup != step_linear_.end()) {
    const Index e{static_cast<int>(*dup & 0xFFFFFFu), static_cast<int>((*dup >> 24) & 0xFFFFFFu), static_cast<int>(*dup >> 48)};
    fail("ChainMail::move: sponsor element " + index_text(e) + " appears more than once");
  }

  ChainMailStepResult r;
  if (++step_ > kMaxStep) {  // once in 4e9 steps: every mark back to "an earlier step"
    for (auto& brick : bricks_)
      for (std::uint64_t& m : brick->mark) m &= kLatticeBits;
    step_ = 1;
  }
  for (auto& bucket : heap_) bucket.clear();  // empty unless an earlier step ended by an exception
  heap_nonempty_.fill(0);
  heap_last_ = 0;
  heap_head_ = 0;
  heap_ties_ = 0;

  // Sponsors: materialised and marked first, so that none is queued as a candidate.
  step_refs_.clear();
  const std::size_t bricks_before = bricks_.size();
  for (const ChainMailSponsor& s : sponsors) {
    const std::uint32_t ref = materialise_element(s.element);
    std::uint64_t& mark = bricks_[ref >> kRefBrickShift]->mark[ref & (kBrickElements - 1)];
    mark = (step_ << kTagShift) | (mark & kLatticeBits) | (kSponsorKey << kKeyAxisShift) | kQueued | kQueued << 2 | kQueued << 4;
    step_refs_.push_back(ref);
  }
  r.materialised += (bricks_.size() - bricks_before) * kBrickElements;
  for (std::size_t s = 0; s < sponsors.size(); ++s)
    place_sponsor(step_refs_[s] >> kRefBrickShift, step_refs_[s] & (kBrickElements - 1),
                  sponsors[s].position - rest_position(sponsors[s].element), r);

  drain(r);
  return r;
}

// ---------------------------------------------------------------------------------------------
// Links (the cut itself is chainmail_cut.cpp's)

void ChainMail::unlink(const Index& e, const Index& n, int axis) {
  const std::uint32_t re = materialise_element(e), rn = materialise_element(n);
  bricks_[re >> kRefBrickShift]->mark[re & (kBrickElements - 1)] &= ~(std::uint64_t{1} << (kLinksShift + 2 * axis));
  bricks_[rn >> kRefBrickShift]->mark[rn & (kBrickElements - 1)] &= ~(std::uint64_t{1} << (kLinksShift + 2 * axis + 1));
}

// ---------------------------------------------------------------------------------------------
// State

void ChainMail::reset() noexcept {
  for (auto& brick : bricks_) {
    Brick& B = *brick;
    for (auto& axis : B.u) axis.fill(0.0);
    B.uniform = fill_brick_links(
        B.mark, B.coord, lattice_.dims,
        [this](std::int64_t i, std::int64_t j, std::int64_t k) { return present_at(i, j, k); },
        [this](std::int64_t i, std::int64_t j, std::int64_t k) { return material_at(i, j, k); });
  }
}

void ChainMail::set_steps_made_for_testing(std::uint32_t steps) noexcept {
  assert(steps >= step_ && "ChainMail::set_steps_made_for_testing: the step counter only counts on");
  step_ = steps;
}

void ChainMail::for_each_materialised(const std::function<void(const Index&, const Vec3&)>& fn) const {
  for (const auto& brick : bricks_) {
    const Brick& B = *brick;
    for (std::uint32_t l = 0; l < kBrickElements; ++l) {
      const Index e{B.coord[0] * kBrickEdge + static_cast<int>(l & 7u), B.coord[1] * kBrickEdge + static_cast<int>((l >> 3) & 7u),
                    B.coord[2] * kBrickEdge + static_cast<int>(l >> 6)};
      if (present(e)) fn(e, B.displacement(l));
    }
  }
}

std::size_t ChainMail::heap_capacity_bytes() const noexcept {
  std::size_t n = 0;
  for (const auto& bucket : heap_) n += bucket.capacity() * sizeof(HeapEntry);
  return n;
}

std::uint64_t ChainMail::materialised_elements() const noexcept { return std::uint64_t{bricks_.size()} * kBrickElements; }

std::size_t ChainMail::bytes_used() const noexcept {
  return sizeof(*this) + materials_.capacity() * sizeof(ChainMailMaterial) + 3 * axis_boxes_[0].capacity() * sizeof(AxisBox) +
         bricks_.capacity() * sizeof(std::unique_ptr<Brick>) + bricks_.size() * sizeof(Brick) +
         hash_keys_.capacity() * sizeof(std::uint64_t) + hash_vals_.capacity() * sizeof(std::int32_t) +
         step_refs_.capacity() * sizeof(std::uint32_t) + step_linear_.capacity() * sizeof(std::uint64_t) +
         groove_sponsors_.capacity() * sizeof(ChainMailSponsor) + heap_capacity_bytes();
}

}  // namespace lancet::volume
