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
constexpr std::uint32_t kRefBrickShift = 9;         // ref = brick << 9 | local
constexpr std::uint32_t kMaxBricks = 1u << (32 - kRefBrickShift);
// Mark, one 64-bit word per element: everything a step reads about an element but its
// displacement. step << 32 | material << 24 | links << 16 | queued << 8 | sponsor << 7 | moved << 6
// | lowered on z, y, x << 3 | raised on z, y, x. Step and the low bits belong to the step in the
// high bits (a mark from an earlier step reads as untouched); links (bit d: the link in direction d
// is live) and material belong to the lattice.
constexpr int kTagShift = 32;
constexpr int kLinksShift = 16, kMatShift = 24;
constexpr std::uint64_t kRaised = 1, kLowered = 1u << 3;  // shifted by the axis
constexpr std::uint64_t kMovedBit = 1u << 6, kSponsorBit = 1u << 7, kQueuedBit = 1u << 8;
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

// A brick's elements as arrays (structure of arrays): a pass over one axis reads only that axis's
// displacements and the marks, 16 of the 40 bytes per element (and writes `pre` where it raises),
// so the cache holds more than twice the region it would with whole elements; an x-row of 8
// elements shares a cache line.
struct alignas(64) ChainMail::Brick {
  std::array<std::array<double, kBrickElements>, 3> u;  // m, displacement from rest per axis
  std::array<std::uint64_t, kBrickElements> mark;        // see kTagShift
  std::array<double, kBrickElements> pre;                // m, a coordinate's value before the step, once raised in it
  std::array<std::int32_t, 6> nbr;    // brick index in direction d, -1 none yet
  std::array<Brick*, 6> nbrp;         // the same bricks (stable: each brick is its own allocation)
  std::array<std::int32_t, 3> coord;  // brick coordinates
  std::int32_t uniform;               // the material of every element it links and of its neighbours, -1 when mixed

  [[nodiscard]] Vec3 displacement(std::uint32_t l) const noexcept { return {u[0][l], u[1][l], u[2][l]}; }
};

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
  double widest = 0;  // m, the largest change along a link: compression, stretch or shear
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
        widest = std::max({widest, -dlo, dhi, shear});
        const std::size_t box = (m1 * n_materials_ + m2) * 6 + static_cast<std::size_t>(d);
        for (int b = 0; b < 3; ++b) axis_boxes_[static_cast<std::size_t>(b)][box] = {-shear, shear};
        axis_boxes_[static_cast<std::size_t>(a)][box] = {kStep[d] > 0 ? dlo : -dhi, kStep[d] > 0 ? dhi : -dlo};
      }
    }
  const double smin = std::min({lattice_.spacing.x, lattice_.spacing.y, lattice_.spacing.z});
  eps_ = 1e-9 * smin;
  // A link changes a value by at most `widest`: the ring's buckets span a little more.
  inv_delta_ = widest > 0 ? static_cast<double>(kRing - 4) / (2 * widest) : 0.0;
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

}  // namespace

std::uint8_t ChainMail::neighbour_material(const Brick& B, std::uint32_t l, int d) const noexcept {
  std::int64_t c[3] = {std::int64_t{B.coord[0]} * kBrickEdge + (l & 7u), std::int64_t{B.coord[1]} * kBrickEdge + ((l >> 3) & 7u),
                       std::int64_t{B.coord[2]} * kBrickEdge + (l >> 6)};
  c[kAxisOf[d]] += kStep[d];
  return material_at(c[0], c[1], c[2]);
}

// What a pass keeps in registers. As members they would be reloaded after every store to a mark
// (std::uint64_t) or a displacement (double), which may alias them.
struct ChainMail::Pass {
  std::uint64_t tag;       // step_ << kTagShift
  double eps;              // m, eps_
  double origin;           // m, the value of bucket 0: the first seed's
  double inv_delta;        // buckets per m (inv_delta_)
  std::int64_t cur;        // the bucket being taken
  std::uint64_t nonempty;  // bit i: ring_[i] holds entries
  std::uint64_t processed = 0, moved = 0, conflicts = 0;
};

namespace {
constexpr std::size_t kPrefetch = 8;  // queue entries ahead whose element a pass prefetches

// Bucket of a value in a raising (Up) or lowering pass: counted from the first seed's value, in
// steps of 1/inv_delta, away from it (larger values first when raising).
template <bool Up>
[[gnu::always_inline]] inline std::int64_t bucket_of(double origin, double inv_delta, double value) noexcept {
  const double x = (Up ? origin - value : value - origin) * inv_delta;
  return x < 0x1p62 ? static_cast<std::int64_t>(x) : std::int64_t{1} << 62;
}
}  // namespace

// Moves coordinate A of local element nl of brick N (index nb) from `before` to v, which its
// neighbour requires, and queues it (unless queued in the same bucket already). A sponsor does not
// move (a conflict), nor does an element raised on A in this step get lowered without counting
// one: it is lowered only when that moves it further from where it was before the step than the
// raising did.
template <int A, bool Up>
[[gnu::always_inline]] inline void ChainMail::move_to(Pass& p, Brick& N, std::uint32_t nb, std::uint32_t nl, double v, double before) {
  std::uint64_t m = N.mark[nl];
  if ((m & kStepBits) != p.tag) m = p.tag | (m & kLatticeBits);
  if ((m & kSponsorBit) != 0) [[unlikely]] {
    ++p.conflicts;
    return;
  }
  constexpr std::uint64_t mine = (Up ? kRaised : kLowered) << A, other = (Up ? kLowered : kRaised) << A;
  if constexpr (Up) {
    if ((m & mine) == 0) N.pre[nl] = before;
  } else if ((m & (mine | other)) == other) [[unlikely]] {
    // Raised in this step, and now required lower than before it: its bounds disagree (a
    // conflict). The larger of the two moves prevails, as largest violation first would have it.
    ++p.conflicts;
    const double rest = N.pre[nl];
    if (!(v < rest - p.eps) || before - rest >= rest - v) return;
  }
  p.processed += (m & (mine | other)) == 0 ? 1u : 0u;
  p.moved += (m & kMovedBit) == 0 ? 1u : 0u;
  N.u[A][nl] = v;
  const bool queued = (m & kQueuedBit) != 0;
  N.mark[nl] = m | mine | kMovedBit | kQueuedBit;
  const std::int64_t k = std::clamp(bucket_of<Up>(p.origin, p.inv_delta, v), p.cur, p.cur + std::int64_t{kRing} - 1);
  if (queued && k == std::clamp(bucket_of<Up>(p.origin, p.inv_delta, before), p.cur, p.cur + std::int64_t{kRing} - 1)) return;
  const auto slot = static_cast<std::size_t>(k) & (kRing - 1);
  ring_[slot].push_back((nb << kRefBrickShift) | nl);
  p.nonempty |= std::uint64_t{1} << slot;
}

// The neighbour of local element l of brick b in direction d has no brick yet (it is at rest):
// whether coordinate A of l, at ue, requires it to move, and where to (v). Out of line, and without
// the pass (whose address would then escape and its fields be reloaded after every store).
template <int A, bool Up>
[[gnu::noinline]] bool ChainMail::unmaterialised_moves(std::uint32_t b, std::uint32_t l, int d, double ue, double& v) const {
  const Brick& B = *bricks_[b];
  const std::size_t box = (mat_of(B.mark[l]) * n_materials_ + neighbour_material(B, l, d)) * 6 + static_cast<std::size_t>(d);
  v = ue + (Up ? axis_boxes_[A][box].lo : axis_boxes_[A][box].hi);
  return Up ? v > eps_ : v < -eps_;
}

// Relaxes the links of local element l of brick b on axis A: every linked neighbour that lies
// below the interval l's coordinate now allows it (raising) or above it (lowering) moves to its
// edge. The hot loop of a step. Uniform: the brick and its halo have one material.
template <int A, bool Up, bool Uniform>
[[gnu::always_inline]] inline void ChainMail::relax(Pass& p, Brick& B, std::uint32_t b, std::uint32_t l, ChainMailStepResult& r) {
  const std::uint64_t self = B.mark[l];
  const unsigned links = links_of(self);
  const std::size_t mat = mat_of(self);
  const AxisBox* row = axis_boxes_[A].data() + mat * n_materials_ * 6;
  const unsigned cross = kNeighbours.cross[l];
  const std::array<std::uint16_t, 6>& nls = kNeighbours.local[l];
  const double ue = B.u[A][l];
#pragma GCC unroll 6
  for (int d = 0; d < 6; ++d) {
    if (((links >> d) & 1u) == 0) continue;
    const auto di = static_cast<std::size_t>(d);
    const bool across = ((cross >> d) & 1u) != 0;
    Brick* NB = across ? B.nbrp[di] : &B;
    const std::uint32_t nl = nls[di];
    if (NB == nullptr) [[unlikely]] {
      double v = 0;
      if (!unmaterialised_moves<A, Up>(b, l, d, ue, v)) continue;
      std::int64_t c[3] = {B.coord[0], B.coord[1], B.coord[2]};
      c[kAxisOf[d]] += kStep[d];
      const auto nb = static_cast<std::uint32_t>(materialise_brick(c[0], c[1], c[2]));
      r.materialised += kBrickElements;
      move_to<A, Up>(p, *bricks_[nb], nb, nl, v, 0.0);
      continue;
    }
    const AxisBox& bx = row[(Uniform ? mat : mat_of(NB->mark[nl])) * 6 + di];
    const double v = ue + (Up ? bx.lo : bx.hi), un = NB->u[A][nl];
    if (Up ? !(v > un + p.eps) : !(v < un - p.eps)) continue;
    move_to<A, Up>(p, *NB, across ? static_cast<std::uint32_t>(B.nbr[di]) : b, nl, v, un);
  }
}

template <int A, bool Up>
[[gnu::always_inline]] inline void ChainMail::relax_ref(Pass& p, std::uint32_t ref, ChainMailStepResult& r) {
  const std::uint32_t b = ref >> kRefBrickShift, l = ref & (kBrickElements - 1);
  Brick& B = *bricks_[b];
  if (B.uniform >= 0) {
    relax<A, Up, true>(p, B, b, l, r);
  } else {
    relax<A, Up, false>(p, B, b, l, r);
  }
}

// One pass over axis A: raising (Up) or lowering every coordinate a link requires, from the
// sponsors out. A bucketed label-correcting propagation: buckets of 1/inv_delta_ of the value
// (kRing of them in a ring, more than the largest change of a link), taken largest value first
// when raising, each first in, first out; an element raised again after it was taken (by one of
// its bucket) is queued again. The sponsors enter when their bucket comes up.
template <int A, bool Up>
void ChainMail::pass(ChainMailStepResult& r) {
  seeds_.clear();
  for (const std::uint32_t ref : step_refs_) seeds_.push_back({bricks_[ref >> kRefBrickShift]->u[A][ref & (kBrickElements - 1)], ref});
  std::sort(seeds_.begin(), seeds_.end(), [](const Seed& x, const Seed& y) {
    return x.value != y.value ? (Up ? x.value > y.value : x.value < y.value) : x.ref < y.ref;
  });
  Pass p{step_ << kTagShift, eps_, seeds_.front().value, inv_delta_, 0, 0};
  constexpr std::int64_t kNone = std::numeric_limits<std::int64_t>::max();
  std::size_t next = 0;  // the next seed
  const auto next_seed_bucket = [&] { return next < seeds_.size() ? bucket_of<Up>(p.origin, p.inv_delta, seeds_[next].value) : kNone; };
  for (;;) {
    for (; next_seed_bucket() <= p.cur; ++next) relax_ref<A, Up>(p, seeds_[next].ref, r);
    const std::size_t slot = static_cast<std::size_t>(p.cur) & (kRing - 1);
    std::vector<std::uint32_t>& bucket = ring_[slot];
    for (std::size_t i = 0; i < bucket.size(); ++i) {  // grows while it is taken
      if (i + kPrefetch < bucket.size()) {  // the entry taken kPrefetch later: its mark and coordinate, and
        // those of its neighbours in z within its brick (512 B away: the lines a wave reaches cold)
        const std::uint32_t ahead = bucket[i + kPrefetch];
        const Brick& F = *bricks_[ahead >> kRefBrickShift];
        const std::uint32_t la = ahead & (kBrickElements - 1);
        const std::uint32_t below = la >= 64u ? la - 64u : la, above = la < kBrickElements - 64u ? la + 64u : la;
        __builtin_prefetch(&F.mark[la]);
        __builtin_prefetch(&F.u[A][la]);
        __builtin_prefetch(&F.u[A][below]);
        __builtin_prefetch(&F.mark[below]);
        __builtin_prefetch(&F.u[A][above]);
        __builtin_prefetch(&F.mark[above]);
      }
      const std::uint32_t ref = bucket[i];
      std::uint64_t& mark = bricks_[ref >> kRefBrickShift]->mark[ref & (kBrickElements - 1)];
      if ((mark & kQueuedBit) == 0) continue;  // taken already, from a bucket it was queued to later
      mark &= ~kQueuedBit;
      relax_ref<A, Up>(p, ref, r);
    }
    bucket.clear();
    p.nonempty &= ~(std::uint64_t{1} << slot);
    if (p.nonempty == 0 && next == seeds_.size()) break;
    const std::int64_t queued = p.nonempty == 0 ? kNone : p.cur + std::countr_zero(std::rotr(p.nonempty, static_cast<int>(slot)));
    p.cur = std::min(queued, next_seed_bucket());
  }
  r.processed += p.processed;
  r.moved += p.moved;
  r.conflicts += p.conflicts;
}

// Places a sponsor: all three coordinates, as given.
void ChainMail::place_sponsor(std::uint32_t b, std::uint32_t l, Vec3 u, ChainMailStepResult& r) {
  Brick& B = *bricks_[b];
  std::uint64_t mark = (step_ << kTagShift) | (B.mark[l] & kLatticeBits) | kSponsorBit;
  if (!(u == B.displacement(l))) {
    mark |= kMovedBit;
    ++r.moved;
    B.u[0][l] = u.x;
    B.u[1][l] = u.y;
    B.u[2][l] = u.z;
  }
  B.mark[l] = mark;
  ++r.processed;
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
  for (auto& bucket : ring_) bucket.clear();  // empty unless an earlier step ended by an exception

  step_refs_.clear();
  const std::size_t bricks_before = bricks_.size();
  for (const ChainMailSponsor& s : sponsors) step_refs_.push_back(materialise_element(s.element));
  r.materialised += (bricks_.size() - bricks_before) * kBrickElements;
  for (std::size_t s = 0; s < sponsors.size(); ++s)
    place_sponsor(step_refs_[s] >> kRefBrickShift, step_refs_[s] & (kBrickElements - 1),
                  sponsors[s].position - rest_position(sponsors[s].element), r);
  if (sponsors.empty()) return r;
  pass<0, true>(r);
  pass<0, false>(r);
  pass<1, true>(r);
  pass<1, false>(r);
  pass<2, true>(r);
  pass<2, false>(r);
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

std::size_t ChainMail::ring_capacity_bytes() const noexcept {
  std::size_t n = seeds_.capacity() * sizeof(Seed);
  for (const auto& bucket : ring_) n += bucket.capacity() * sizeof(std::uint32_t);
  return n;
}

std::uint64_t ChainMail::materialised_elements() const noexcept { return std::uint64_t{bricks_.size()} * kBrickElements; }

std::size_t ChainMail::bytes_used() const noexcept {
  return sizeof(*this) + materials_.capacity() * sizeof(ChainMailMaterial) + 3 * axis_boxes_[0].capacity() * sizeof(AxisBox) +
         bricks_.capacity() * sizeof(std::unique_ptr<Brick>) + bricks_.size() * sizeof(Brick) +
         hash_keys_.capacity() * sizeof(std::uint64_t) + hash_vals_.capacity() * sizeof(std::int32_t) +
         step_refs_.capacity() * sizeof(std::uint32_t) + step_linear_.capacity() * sizeof(std::uint64_t) +
         groove_sponsors_.capacity() * sizeof(ChainMailSponsor) + ring_capacity_bytes();
}

}  // namespace lancet::volume
