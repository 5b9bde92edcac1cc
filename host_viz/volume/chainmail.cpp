#include "volume/chainmail.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <utility>

namespace lancet::volume {
namespace {

constexpr int kBrickShift = 3;                       // bricks of 8 × 8 × 8 elements
constexpr int kBrickEdge = 1 << kBrickShift;
constexpr std::uint32_t kBrickElements = 512;
constexpr std::uint32_t kLocalBits = 9;              // ref = brick << 9 | local
constexpr std::uint32_t kMaxBricks = 1u << (32 - kLocalBits);
constexpr std::uint32_t kNone = 0xFFFFFFFFu;
constexpr std::uint32_t kBuckets = 4096;
constexpr double kBucketsPerSpacing = 32;
constexpr std::uint16_t kSponsorBucket = 0xFFFF;     // above every real bucket: never re-queued
constexpr std::uint64_t kEmptyKey = ~std::uint64_t{0};
constexpr int kMaxDim = 1 << 24;
constexpr double kInf = std::numeric_limits<double>::infinity();

// Directions d = 2·axis + (1 for the negative side); the opposite of d is d ^ 1.
constexpr int kAxisOf[6] = {0, 0, 1, 1, 2, 2};
constexpr int kStep[6] = {1, -1, 1, -1, 1, -1};

double& comp(Vec3& v, int a) noexcept { return a == 0 ? v.x : (a == 1 ? v.y : v.z); }

const char* axis_name(int a) noexcept { return a == 0 ? "x" : (a == 1 ? "y" : "z"); }

std::string num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

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

}  // namespace

struct ChainMail::Brick {
  std::array<Vec3, kBrickElements> u;                // m, displacement from rest
  std::array<std::uint64_t, kBrickElements> mark;    // 2g queued in step g, 2g+1 final in step g
  std::array<std::uint16_t, kBrickElements> bucket;  // bucket it is queued in (valid while queued)
  std::array<std::uint8_t, kBrickElements> links;    // bit d: link in direction d is live
  std::array<std::uint8_t, kBrickElements> mat;      // material index (0 outside the lattice)
  std::array<std::int32_t, 6> nbr;                   // brick index in direction d, -1 none yet
  std::array<std::int32_t, 3> coord;                 // brick coordinates
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
  const std::size_t voxels = static_cast<std::size_t>(lattice_.dims[0]) * static_cast<std::size_t>(lattice_.dims[1]) *
                             static_cast<std::size_t>(lattice_.dims[2]);
  if (!ids_.empty()) {
    if (ids_.size() != voxels)
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
  boxes_.assign(n_materials_ * n_materials_ * 6, Box{});
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
        Box& bx = boxes_[(m1 * n_materials_ + m2) * 6 + static_cast<std::size_t>(d)];
        bx.lo = {-shear, -shear, -shear};
        bx.hi = {shear, shear, shear};
        comp(bx.lo, a) = kStep[d] > 0 ? dlo : -dhi;
        comp(bx.hi, a) = kStep[d] > 0 ? dhi : -dlo;
      }
    }
  const double smin = std::min({lattice_.spacing.x, lattice_.spacing.y, lattice_.spacing.z});
  eps_ = 1e-9 * smin;
  inv_bucket_ = kBucketsPerSpacing / smin;
  head_.assign(kBuckets, kNone);
  tail_.assign(kBuckets, kNone);
  top_ = 0;
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
// Fills links and materials of a brick from the lattice: bit d set when the element and its
// neighbour in direction d are both present (presence read once into a 10³ halo).
template <class PresentAt, class MaterialAt>
void fill_brick_links(std::array<std::uint8_t, kBrickElements>& links, std::array<std::uint8_t, kBrickElements>& mat,
                      const std::array<std::int32_t, 3>& coord, const std::array<int, 3>& dims, PresentAt present_at,
                      MaterialAt material_at) {
  std::array<bool, 1000> pres{};
  const std::int64_t i0 = std::int64_t{coord[0]} * kBrickEdge, j0 = std::int64_t{coord[1]} * kBrickEdge,
                     k0 = std::int64_t{coord[2]} * kBrickEdge;
  for (int hz = 0; hz < 10; ++hz)
    for (int hy = 0; hy < 10; ++hy)
      for (int hx = 0; hx < 10; ++hx)
        pres[static_cast<std::size_t>(hx + 10 * (hy + 10 * hz))] = present_at(i0 + hx - 1, j0 + hy - 1, k0 + hz - 1);
  constexpr int kHaloStep[6] = {1, -1, 10, -10, 100, -100};
  for (std::uint32_t l = 0; l < kBrickElements; ++l) {
    const int lx = static_cast<int>(l & 7u), ly = static_cast<int>((l >> 3) & 7u), lz = static_cast<int>(l >> 6);
    const std::int64_t i = i0 + lx, j = j0 + ly, k = k0 + lz;
    const bool inside = i < dims[0] && j < dims[1] && k < dims[2];
    mat[l] = inside ? material_at(i, j, k) : std::uint8_t{0};
    const int h = (lx + 1) + 10 * ((ly + 1) + 10 * (lz + 1));
    unsigned bits = 0;
    if (pres[static_cast<std::size_t>(h)])
      for (int d = 0; d < 6; ++d)
        if (pres[static_cast<std::size_t>(h + kHaloStep[d])]) bits |= 1u << d;
    links[l] = static_cast<std::uint8_t>(bits);
  }
}
}  // namespace

std::int32_t ChainMail::materialise_brick(std::int64_t bx, std::int64_t by, std::int64_t bz) {
  if (const std::int32_t found = find_brick(bx, by, bz); found >= 0) return found;
  if (bricks_.size() >= kMaxBricks) throw std::length_error("ChainMail: more than 2^23 bricks materialised");
  auto brick = std::make_unique<Brick>();
  Brick& B = *brick;
  B.coord = {static_cast<std::int32_t>(bx), static_cast<std::int32_t>(by), static_cast<std::int32_t>(bz)};
  B.nbr.fill(-1);
  B.mark.fill(0);
  B.bucket.fill(0);
  for (Vec3& u : B.u) u = {};
  fill_brick_links(
      B.links, B.mat, B.coord, lattice_.dims,
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
    B.nbr[static_cast<std::size_t>(d)] = other;
    bricks_[static_cast<std::size_t>(other)]->nbr[static_cast<std::size_t>(d ^ 1)] = index;
  }
  return index;
}

std::uint32_t ChainMail::materialise_element(const Index& e) {
  const std::int32_t b = materialise_brick(e[0] >> kBrickShift, e[1] >> kBrickShift, e[2] >> kBrickShift);
  const auto local = static_cast<std::uint32_t>((e[0] & 7) | ((e[1] & 7) << 3) | ((e[2] & 7) << 6));
  return (static_cast<std::uint32_t>(b) << kLocalBits) | local;
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
  return (bricks_[static_cast<std::size_t>(b)]->links[local] >> (2 * axis)) & 1u;
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
  return bricks_[static_cast<std::size_t>(b)]->u[local];
}

void ChainMail::check_element(const Index& e, const char* what) const {
  for (std::size_t a = 0; a < 3; ++a)
    if (e[a] < 0 || e[a] >= lattice_.dims[a])
      fail(std::string(what) + " element " + index_text(e) + " is outside the lattice (dims " +
           index_text(lattice_.dims) + ")");
  if (!present(e)) fail(std::string(what) + " element " + index_text(e) + " is not present (its material is air)");
}

// ---------------------------------------------------------------------------------------------
// Queue: buckets of violation, largest first, FIFO within a bucket.

void ChainMail::push(std::uint32_t ref, double violation) {
  const double scaled = violation * inv_bucket_;
  const std::uint32_t b = scaled >= static_cast<double>(kBuckets - 1) ? kBuckets - 1 : static_cast<std::uint32_t>(scaled);
  const auto idx = static_cast<std::uint32_t>(pool_.size());
  pool_.push_back({ref, kNone});
  if (tail_[b] == kNone)
    head_[b] = idx;
  else
    pool_[tail_[b]].next = idx;
  tail_[b] = idx;
  if (static_cast<std::int64_t>(b) > top_) top_ = b;
  ++queued_;
}

bool ChainMail::pop(std::uint32_t& ref) noexcept {
  if (queued_ == 0) return false;
  while (head_[static_cast<std::size_t>(top_)] == kNone) --top_;
  const auto t = static_cast<std::size_t>(top_);
  const std::uint32_t idx = head_[t];
  ref = pool_[idx].ref;
  head_[t] = pool_[idx].next;
  if (head_[t] == kNone) tail_[t] = kNone;
  --queued_;
  return true;
}

// ---------------------------------------------------------------------------------------------
// The step

template <bool kSponsor>
void ChainMail::process(std::uint32_t ref, Vec3 sponsor_u, ChainMailStepResult& r) {
  const std::uint32_t b = ref >> kLocalBits, l = ref & (kBrickElements - 1);
  Brick& B = *bricks_[b];
  const std::uint64_t final_mark = gen_ + 1, queued_mark = gen_;
  const unsigned links = B.links[l];
  const std::size_t row = static_cast<std::size_t>(B.mat[l]) * n_materials_;

  struct Pending {
    std::int32_t brick;   // -1: its brick is not materialised (it is at rest)
    std::uint32_t local;
    int d;
    const Box* box;
    Vec3 u;
  };
  std::array<Pending, 6> pending;
  int n_pending = 0;
  double lo[3] = {-kInf, -kInf, -kInf}, hi[3] = {kInf, kInf, kInf};

  const std::uint32_t lx = l & 7u, ly = (l >> 3) & 7u, lz = l >> 6;
  for (int d = 0; d < 6; ++d) {
    if (((links >> d) & 1u) == 0) continue;
    // The neighbour: in this brick, or in the neighbour brick across the face.
    std::int32_t nb = static_cast<std::int32_t>(b);
    std::uint32_t nl = 0;
    switch (d) {
      case 0: if (lx != 7) nl = l + 1; else { nb = B.nbr[0]; nl = l - 7; } break;
      case 1: if (lx != 0) nl = l - 1; else { nb = B.nbr[1]; nl = l + 7; } break;
      case 2: if (ly != 7) nl = l + 8; else { nb = B.nbr[2]; nl = l - 56; } break;
      case 3: if (ly != 0) nl = l - 8; else { nb = B.nbr[3]; nl = l + 56; } break;
      case 4: if (lz != 7) nl = l + 64; else { nb = B.nbr[4]; nl = l - 448; } break;
      default: if (lz != 0) nl = l - 64; else { nb = B.nbr[5]; nl = l + 448; } break;
    }
    Brick* N = nb >= 0 ? bricks_[static_cast<std::size_t>(nb)].get() : nullptr;
    std::uint8_t mn;
    Vec3 un{};
    std::uint64_t mk = 0;
    if (N != nullptr) {
      mn = N->mat[nl];
      un = N->u[nl];
      mk = N->mark[nl];
    } else {
      std::int64_t c[3] = {std::int64_t{B.coord[0]} * kBrickEdge + lx, std::int64_t{B.coord[1]} * kBrickEdge + ly,
                           std::int64_t{B.coord[2]} * kBrickEdge + lz};
      c[kAxisOf[d]] += kStep[d];
      mn = material_at(c[0], c[1], c[2]);
    }
    const Box& bx = boxes_[(row + mn) * 6 + static_cast<std::size_t>(d)];
    if (mk == final_mark) {
      // A final neighbour: this element must lie in the box it defines (u_n − hi, u_n − lo).
      lo[0] = std::max(lo[0], un.x - bx.hi.x);
      hi[0] = std::min(hi[0], un.x - bx.lo.x);
      lo[1] = std::max(lo[1], un.y - bx.hi.y);
      hi[1] = std::min(hi[1], un.y - bx.lo.y);
      lo[2] = std::max(lo[2], un.z - bx.hi.z);
      hi[2] = std::min(hi[2], un.z - bx.lo.z);
    } else {
      pending[static_cast<std::size_t>(n_pending++)] = {nb, nl, d, &bx, un};
    }
  }

  // Place the element: a sponsor where asked; a candidate at the nearest point of the
  // intersection of its final neighbours' boxes (the middle of the bounds on an axis where they
  // do not intersect: a conflict).
  Vec3 u;
  bool conflict = false;
  if constexpr (kSponsor) {
    u = sponsor_u;
    for (int a = 0; a < 3; ++a) {
      const double v = comp(u, a);
      if (v < lo[a] - eps_ || v > hi[a] + eps_) conflict = true;
    }
  } else {
    u = B.u[l];
    for (int a = 0; a < 3; ++a) {
      double& v = comp(u, a);
      if (lo[a] > hi[a]) {
        if (lo[a] - hi[a] > eps_) conflict = true;
        v = 0.5 * (lo[a] + hi[a]);
      } else if (v < lo[a]) {
        v = lo[a];
      } else if (v > hi[a]) {
        v = hi[a];
      }
    }
  }
  if (conflict) ++r.conflicts;
  if (!(u == B.u[l])) {
    ++r.moved;
    B.u[l] = u;
  }
  B.mark[l] = final_mark;
  ++r.processed;

  // Check the neighbours that are not final against the box this element defines for them.
  for (int p = 0; p < n_pending; ++p) {
    Pending& q = pending[static_cast<std::size_t>(p)];
    const Box& bx = *q.box;
    const double violation = std::max({u.x + bx.lo.x - q.u.x, q.u.x - (u.x + bx.hi.x), u.y + bx.lo.y - q.u.y,
                                       q.u.y - (u.y + bx.hi.y), u.z + bx.lo.z - q.u.z, q.u.z - (u.z + bx.hi.z)});
    if (!(violation > eps_)) continue;
    if (q.brick < 0) {
      std::int64_t c[3] = {B.coord[0], B.coord[1], B.coord[2]};
      c[kAxisOf[q.d]] += kStep[q.d];
      q.brick = materialise_brick(c[0], c[1], c[2]);
      r.materialised += kBrickElements;
    }
    Brick& N = *bricks_[static_cast<std::size_t>(q.brick)];
    const double scaled = violation * inv_bucket_;
    const auto bucket = static_cast<std::uint16_t>(scaled >= static_cast<double>(kBuckets - 1) ? kBuckets - 1 : static_cast<std::uint32_t>(scaled));
    if (N.mark[q.local] == queued_mark && N.bucket[q.local] >= bucket) continue;  // already queued at least this high
    N.mark[q.local] = queued_mark;
    N.bucket[q.local] = bucket;
    push((static_cast<std::uint32_t>(q.brick) << kLocalBits) | q.local, violation);
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
    const std::string what = "ChainMail::move: sponsors[" + std::to_string(s) + "]";
    check_element(sponsors[s].element, what.c_str());
    if (!is_finite(sponsors[s].position))
      fail(what + ".position = (" + num(sponsors[s].position.x) + ", " + num(sponsors[s].position.y) + ", " +
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
  gen_ += 2;
  if (queued_ != 0) {  // a previous step ended by an exception (allocation failure)
    std::fill(head_.begin(), head_.end(), kNone);
    std::fill(tail_.begin(), tail_.end(), kNone);
    queued_ = 0;
  }
  pool_.clear();
  top_ = 0;

  // Sponsors: materialised and marked queued first, so that none is taken as a candidate.
  step_refs_.clear();
  const std::size_t bricks_before = bricks_.size();
  for (const ChainMailSponsor& s : sponsors) {
    const std::uint32_t ref = materialise_element(s.element);
    Brick& B = *bricks_[ref >> kLocalBits];
    B.mark[ref & (kBrickElements - 1)] = gen_;
    B.bucket[ref & (kBrickElements - 1)] = kSponsorBucket;
    step_refs_.push_back(ref);
  }
  r.materialised += (bricks_.size() - bricks_before) * kBrickElements;
  for (std::size_t s = 0; s < sponsors.size(); ++s)
    process<true>(step_refs_[s], sponsors[s].position - rest_position(sponsors[s].element), r);

  // Candidates, largest violation first; stale entries (re-queued higher, already final) skipped.
  std::uint32_t ref = 0;
  while (pop(ref)) {
    if (bricks_[ref >> kLocalBits]->mark[ref & (kBrickElements - 1)] == gen_ + 1) continue;
    process<false>(ref, Vec3{}, r);
  }
  return r;
}

// ---------------------------------------------------------------------------------------------
// Cut and groove

ChainMailCut ChainMail::cut(std::span<const Vec3> polyline, double depth) {
  if (polyline.size() < 2)
    fail("ChainMail::cut: polyline has " + std::to_string(polyline.size()) + " point(s), at least 2 are needed");
  for (std::size_t p = 0; p < polyline.size(); ++p)
    if (!std::isfinite(polyline[p].x) || !std::isfinite(polyline[p].y))
      fail("ChainMail::cut: polyline[" + std::to_string(p) + "] = (" + num(polyline[p].x) + ", " + num(polyline[p].y) +
           ") m is not finite");
  if (!(std::isfinite(depth) && depth > 0)) fail("ChainMail::cut: depth = " + num(depth) + " m, must be finite and > 0");

  struct Segment {
    double x0, y0, tx, ty, len, arc0;
  };
  std::vector<Segment> segments;
  double length = 0;
  for (std::size_t p = 0; p + 1 < polyline.size(); ++p) {
    const double tx = polyline[p + 1].x - polyline[p].x, ty = polyline[p + 1].y - polyline[p].y;
    const double len = std::hypot(tx, ty);
    if (len <= 0) continue;
    segments.push_back({polyline[p].x, polyline[p].y, tx, ty, len, length});
    length += len;
  }
  if (segments.empty()) fail("ChainMail::cut: polyline has zero length (all " + std::to_string(polyline.size()) + " points coincide)");

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
    const Segment& g = segments[si];
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
            const std::uint32_t re = materialise_element(e), rn = materialise_element(n);
            bricks_[re >> kLocalBits]->links[re & (kBrickElements - 1)] &= static_cast<std::uint8_t>(~(1u << (2 * axis)));
            bricks_[rn >> kLocalBits]->links[rn & (kBrickElements - 1)] &= static_cast<std::uint8_t>(~(1u << (2 * axis + 1)));
            ++out.links_removed;
            const double arc = g.arc0 + u * g.len;
            hits.push_back({linear_of(i, j, k), static_cast<std::uint32_t>(si), ca >= 0 ? 1 : -1, arc});
            hits.push_back({linear_of(in, jn, k), static_cast<std::uint32_t>(si), cb >= 0 ? 1 : -1, arc});
          }
  }

  // One face per element: the miter of the (distinct) segments it faces, so that its displacement
  // along each of their away normals is exactly one (|away| <= 2 at sharp corners).
  std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) {
    return a.linear != b.linear ? a.linear < b.linear : (a.segment != b.segment ? a.segment < b.segment : a.arc < b.arc);
  });
  const auto nx = static_cast<std::uint64_t>(dims[0]), ny = static_cast<std::uint64_t>(dims[1]);
  std::vector<std::pair<double, double>> normals;  // away normals of one element's segments
  for (std::size_t h = 0; h < hits.size();) {
    std::size_t end = h;
    while (end < hits.size() && hits[end].linear == hits[h].linear) ++end;
    ChainMailCutFace f;
    const std::uint64_t lin = hits[h].linear;
    f.element = {static_cast<int>(lin % nx), static_cast<int>((lin / nx) % ny), static_cast<int>(lin / (nx * ny))};
    f.side = hits[h].side;
    double sx = 0, sy = 0, arc = 0;
    normals.clear();
    for (std::size_t q = h; q < end; ++q) {
      arc += hits[q].arc;
      if (q > h && hits[q].segment == hits[q - 1].segment) continue;
      const Segment& g = segments[hits[q].segment];
      const double ax = hits[q].side * -g.ty / g.len, ay = hits[q].side * g.tx / g.len;  // away from the cut
      normals.emplace_back(ax, ay);
      sx += ax;
      sy += ay;
    }
    f.arc = arc / static_cast<double>(end - h);
    const double s = std::hypot(sx, sy);
    if (s > 1e-9) {
      double c = 1;
      for (const auto& [ax, ay] : normals) c = std::min(c, (sx * ax + sy * ay) / s);
      c = std::max(c, 0.5);
      f.away = {sx / (s * c), sy / (s * c), 0};
    }
    out.faces.push_back(f);
    h = end;
  }

  // Depth of each face below the top face of its column (same i, j).
  std::vector<std::pair<std::uint64_t, int>> columns;  // (j · nx + i, top k)
  columns.reserve(out.faces.size());
  for (const ChainMailCutFace& f : out.faces)
    columns.emplace_back(static_cast<std::uint64_t>(f.element[1]) * nx + static_cast<std::uint64_t>(f.element[0]), f.element[2]);
  std::sort(columns.begin(), columns.end(), [](const auto& a, const auto& b) { return a.first != b.first ? a.first < b.first : a.second > b.second; });
  for (ChainMailCutFace& f : out.faces) {
    const std::uint64_t col = static_cast<std::uint64_t>(f.element[1]) * nx + static_cast<std::uint64_t>(f.element[0]);
    const auto it = std::lower_bound(columns.begin(), columns.end(), col, [](const auto& a, std::uint64_t c) { return a.first < c; });
    f.depth = (it->second - f.element[2]) * sp.z;
  }
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

// ---------------------------------------------------------------------------------------------
// State

void ChainMail::reset() noexcept {
  for (auto& brick : bricks_) {
    Brick& B = *brick;
    for (Vec3& u : B.u) u = {};
    fill_brick_links(
        B.links, B.mat, B.coord, lattice_.dims,
        [this](std::int64_t i, std::int64_t j, std::int64_t k) { return present_at(i, j, k); },
        [this](std::int64_t i, std::int64_t j, std::int64_t k) { return material_at(i, j, k); });
  }
}

void ChainMail::for_each_materialised(const std::function<void(const Index&, const Vec3&)>& fn) const {
  for (const auto& brick : bricks_) {
    const Brick& B = *brick;
    for (std::uint32_t l = 0; l < kBrickElements; ++l) {
      const Index e{B.coord[0] * kBrickEdge + static_cast<int>(l & 7u), B.coord[1] * kBrickEdge + static_cast<int>((l >> 3) & 7u),
                    B.coord[2] * kBrickEdge + static_cast<int>(l >> 6)};
      if (present(e)) fn(e, B.u[l]);
    }
  }
}

std::uint64_t ChainMail::materialised_elements() const noexcept { return std::uint64_t{bricks_.size()} * kBrickElements; }

std::size_t ChainMail::bytes_used() const noexcept {
  return sizeof(*this) + materials_.capacity() * sizeof(ChainMailMaterial) + boxes_.capacity() * sizeof(Box) +
         bricks_.capacity() * sizeof(std::unique_ptr<Brick>) + bricks_.size() * sizeof(Brick) +
         hash_keys_.capacity() * sizeof(std::uint64_t) + hash_vals_.capacity() * sizeof(std::int32_t) +
         step_refs_.capacity() * sizeof(std::uint32_t) + step_linear_.capacity() * sizeof(std::uint64_t) +
         groove_sponsors_.capacity() * sizeof(ChainMailSponsor) + pool_.capacity() * sizeof(QueueEntry) +
         (head_.capacity() + tail_.capacity()) * sizeof(std::uint32_t);
}

}  // namespace lancet::volume
