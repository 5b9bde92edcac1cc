#pragma once
// Enhanced ChainMail groove deformation (thesis 3.3.2, eq. 3.9; ALGORITHMS.md section 4).
//
// Elements and links. One element per voxel of a lattice (dims nx, ny, nz; spacing s_x, s_y, s_z
// in m; rest position of element (i, j, k) = origin + (i s_x, j s_y, k s_z): the lattice frame, no
// direction matrix). A voxel whose material is not `present` (air) has no element. Each element is
// linked to its 6 axis neighbours. A link along axis a is valid when, with d = position(+a end) −
// position(−a end): min_length_a <= d_a <= max_length_a and |d_b| <= max_shear_a for both other
// axes b. Every element thus defines a box (the thesis's "valid area") for each neighbour; limits
// are per axis, so materials can be anisotropic. A link between two materials uses the mean of
// their limits, so whether a link is valid never depends on which end moved. Internally everything
// is kept as displacement from rest, and an untouched element is implicitly at rest.
//
// A step (move). Sponsors are placed exactly where the caller says. Then Enhanced ChainMail: every
// neighbour of a moved element is checked against the box the moved element defines for it; one
// that lies outside is a candidate with priority = its violation (the largest per-axis distance to
// the box, the 3-D form of eq. 3.9), and candidates are taken largest first. A candidate taken from
// the queue is moved to the point nearest its current position inside the intersection of the
// boxes of ALL its neighbours already final in this step (boxes are axis aligned, so this is a clamp
// per axis). The thesis clamps to the sponsor's box only; intersecting them is what makes every
// link valid after every step, not just most. When the intersection is empty (the final neighbours
// disagree, e.g. a groove wider than its cut's floor can open without tearing) the element goes to
// the middle of the conflicting bounds and the step counts a conflict: conflicts == 0 means every
// link is valid.
//
// Once per step. Each element is processed at most once per step. Instead of Dräger's
// ignore-direction flags (thesis fig. 3.22) or a wrapping timestamp, each element carries a 64-bit
// mark: the step counter g advances by 2 per step, mark 2g = queued in step g, 2g+1 = final in step
// g; it cannot overflow in practice (2^63 steps). A queued candidate whose violation grows (a second
// moved neighbour pushes it harder) is re-queued at the higher priority and the stale entry is
// skipped, as in Dijkstra's algorithm; it is still processed once. The thesis also restricts the
// left side of a cut to propagate only left/down and the right side only right/down. Here the
// unlinked cut already keeps each side's propagation on its own side, and the only places where
// the sides still meet are the intact tissue past the cut's ends and under its floor: there the
// direction rule would leave the links between the two sides unchecked (invalid), so it is not
// used; both sides' drags meet there and any impossibility is reported as a conflict.
//
// Priority queue. Buckets of violation, width w = (smallest spacing) / 32, 4096 of them (128
// spacings; larger violations share the top bucket); the highest non-empty bucket is emptied
// first, FIFO within a bucket. "Largest first" is exact to within w: two candidates whose
// violations differ by less than w are taken in the order they were queued. Push and pop are O(1).
//
// Cut and groove. cut() removes every x and y link that crosses the cut surface: the polyline (x,
// y; z ignored) swept from the lattice's top layer (largest z) down by `depth`. The elements at
// the ends of removed links are the cut's faces, each on the left or right of the polyline (left of
// its direction of travel). open_groove() displaces the faces held by the retractor (an arc-length
// range of the polyline and a depth below each face column's top element) by width/2 away from the
// cut, perpendicular to the segment they face (at a polyline corner: the miter of both normals, so
// the opening across each segment is exactly the width), all as sponsors of one step; everything
// else follows by ChainMail. The opening between the held faces is exactly `width`; below and past
// the held faces the groove closes as fast as the material's shear allows (by 2·max_shear of the z
// links per layer, of the links along the cut per element), so the material decides the groove's
// V shape. A groove too wide for its cut (still open where the cut ends or at its floor) cannot be
// valid and is reported as conflicts.
//
// Memory. Elements live in 8×8×8 bricks created on demand (an open-addressing hash from brick
// coordinates; each brick keeps the indices of its 6 neighbour bricks, so the hot loop never
// hashes). Only bricks that hold a moved, queued or cut element exist; memory follows the deformed
// region, never the volume: the same cut in a 64³ and a 4096³ lattice uses the same bytes.
// Per brick: 512 × (24 B displacement + 8 B mark + 2 B bucket + 2 B links/material) + 36 B.
//
// Threads and allocation: one thread (the viz thread); not real-time safe: a step allocates when
// the deformed region grows (new bricks, a larger queue); a step inside already materialised bricks
// whose queue fits the capacity of earlier steps does not allocate (reset() keeps both). Invalid
// arguments throw std::invalid_argument naming the field and value, before any state changes;
// numerical trouble in a step is counted (conflicts), never thrown. Deterministic.

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <vector>

#include "lancet/shared_model/geometry.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// Limits of the links along one lattice axis a (all m).
struct ChainMailAxisLimits {
  double min_length = 0;  ///< shortest extent along a between two elements linked along a (compression limit), >= 0
  double max_length = 0;  ///< longest extent along a (stretch limit); min_length <= spacing_a <= max_length
  double max_shear = 0;   ///< largest offset along either other axis between two elements linked along a, >= 0
};

/// One material's ChainMail behaviour.
struct ChainMailMaterial {
  bool present = true;                           ///< false: air, no element and no links
  std::array<ChainMailAxisLimits, 3> axis{};     ///< limits of the links along x, y, z

  /// Limits as fractions of the lattice spacing, the same on every axis: min = (1 − compression)·s_a,
  /// max = (1 + stretch)·s_a, shear = shear·s_a.
  static ChainMailMaterial relative(Vec3 spacing, double compression, double stretch, double shear);
  /// No element (present = false).
  static ChainMailMaterial air();
};

/// The element lattice (the voxel grid of a Volume without its direction matrix).
struct ChainMailLattice {
  std::array<int, 3> dims{};  ///< nx, ny, nz elements; each 1 .. 2^24
  Vec3 spacing{};             ///< m between rest positions along x, y, z; each > 0
  Vec3 origin{};              ///< m, rest position of element (0, 0, 0)

  /// dims, spacing and origin of v (the lattice frame is v's index frame scaled; v.direction is not used).
  static ChainMailLattice of(const Volume& v);
};

/// An initially moved element of a step.
struct ChainMailSponsor {
  std::array<int, 3> element{};  ///< (i, j, k)
  Vec3 position;                 ///< m, where it goes (lattice frame)
};

/// What one step did.
struct ChainMailStepResult {
  std::uint64_t processed = 0;     ///< elements taken (sponsors included) and whose 6 neighbours were checked
  std::uint64_t moved = 0;         ///< elements whose position changed
  std::uint64_t conflicts = 0;     ///< elements whose final neighbours' boxes did not intersect (0: every link valid)
  std::uint64_t materialised = 0;  ///< elements newly materialised (whole bricks, 512 each)
};

/// One face element of a cut: an element whose link across the cut surface was removed.
struct ChainMailCutFace {
  std::array<int, 3> element{};  ///< (i, j, k)
  int side = 0;                  ///< +1 left of the polyline's direction of travel, −1 right
  Vec3 away;                     ///< z = 0; displacement per metre of half-width that opens the groove (unit at a straight segment)
  double arc = 0;                ///< m along the polyline to where the element's removed links cross it (mean)
  double depth = 0;              ///< m below the top face element of its column (same i, j)
};

/// A cut made by ChainMail::cut(): its faces and size.
struct ChainMailCut {
  std::vector<ChainMailCutFace> faces;  ///< sorted by element (k, j, i)
  std::uint64_t links_removed = 0;      ///< links unlinked by this cut (already cut ones not counted)
  double length = 0;                    ///< m, polyline length in x-y
};

/// Which faces open_groove() holds: arc in [from, to] and depth <= depth. Default: the whole cut's
/// top layer.
struct ChainMailRetractor {
  double from = 0;                                     ///< m of arc length
  double to = std::numeric_limits<double>::infinity();  ///< m of arc length, >= from
  double depth = 0;                                    ///< m below each face column's top element, >= 0
};

/// Enhanced ChainMail on a sparse lattice. Not copyable (owns bricks); movable.
class ChainMail {
 public:
  using Index = std::array<int, 3>;

  /// material_ids: nx·ny·nz material indices (x fastest, as Volume::data), each < materials.size();
  /// empty = every element is materials[0]. Not copied: it must outlive this object. materials:
  /// 1..256 entries. Throws std::invalid_argument naming the field and value on bad dims, spacing,
  /// origin, limits (negative, min > max, rest spacing outside [min, max]) or ids. O(n voxels) to
  /// check the ids; nothing else is proportional to the volume.
  ChainMail(const ChainMailLattice& lattice, std::vector<ChainMailMaterial> materials,
            std::span<const std::uint8_t> material_ids = {});
  ~ChainMail();
  ChainMail(ChainMail&&) noexcept;
  ChainMail& operator=(ChainMail&&) noexcept;
  ChainMail(const ChainMail&) = delete;
  ChainMail& operator=(const ChainMail&) = delete;

  [[nodiscard]] const ChainMailLattice& lattice() const noexcept { return lattice_; }
  /// True when (i, j, k) is inside the lattice and its material is present.
  [[nodiscard]] bool present(const Index& e) const noexcept;
  /// True when the link from e to e + unit(axis) exists: both present and not cut. axis 0..2.
  [[nodiscard]] bool linked(const Index& e, int axis) const noexcept;
  /// m, rest position of e (any index, in the lattice or not).
  [[nodiscard]] Vec3 rest_position(const Index& e) const noexcept;
  /// m, displacement of e from rest (zero when untouched or outside the lattice).
  [[nodiscard]] Vec3 displacement(const Index& e) const noexcept;
  /// m, rest_position(e) + displacement(e).
  [[nodiscard]] Vec3 position(const Index& e) const noexcept { return rest_position(e) + displacement(e); }

  /// One step with one sponsor: e goes to `position` (m), the rest follows. Throws
  /// std::invalid_argument when e is outside the lattice or not present, or position is not finite.
  ChainMailStepResult move(const Index& e, Vec3 position);
  /// One step with several sponsors (placed in the given order, all before any other element).
  /// Throws std::invalid_argument as move(), and for a duplicate sponsor.
  ChainMailStepResult move(std::span<const ChainMailSponsor> sponsors);

  /// Unlinks every x and y link crossing the surface swept by `polyline` (m, x-y in the lattice
  /// frame, z ignored; >= 2 points, nonzero length) from the top layer down by `depth` (m, > 0).
  /// Moves nothing. Throws std::invalid_argument on a bad polyline or depth.
  ChainMailCut cut(std::span<const Vec3> polyline, double depth);
  /// One step opening `cut` into a groove `width` wide (m, > 0) where the retractor holds it (see
  /// the file comment). Calling it again with another width re-places the held faces. Throws
  /// std::invalid_argument on a bad width or retractor, or a face outside the lattice.
  ChainMailStepResult open_groove(const ChainMailCut& cut, double width, const ChainMailRetractor& retractor = {});

  /// Every element back at rest and every link restored; keeps the materialised bricks and queue
  /// capacity, so repeating the same steps does not allocate.
  void reset() noexcept;

  /// Calls fn(element, displacement) for every present element of every materialised brick, in
  /// brick creation order.
  void for_each_materialised(const std::function<void(const Index&, const Vec3&)>& fn) const;
  /// Elements in materialised bricks (512 per brick, present or not).
  [[nodiscard]] std::uint64_t materialised_elements() const noexcept;
  /// Bytes this object owns: bricks, hash, queue, pair table (capacities, not sizes); not the
  /// caller's material_ids.
  [[nodiscard]] std::size_t bytes_used() const noexcept;

 private:
  struct Brick;
  struct Box {
    Vec3 lo, hi;  // neighbour's displacement minus the element's, per axis
  };
  struct HeapEntry {
    std::uint64_t key;  // ~bits(violation)
    std::uint32_t ref;  // brick << 11 | axis << 9 | local
  };

  [[nodiscard]] std::uint8_t material_at(std::int64_t i, std::int64_t j, std::int64_t k) const noexcept;
  [[nodiscard]] bool present_at(std::int64_t i, std::int64_t j, std::int64_t k) const noexcept;
  [[nodiscard]] std::uint8_t neighbour_material(const Brick& b, std::uint32_t local, int direction) const noexcept;
  [[nodiscard]] std::int32_t find_brick(std::int64_t bx, std::int64_t by, std::int64_t bz) const noexcept;
  std::int32_t materialise_brick(std::int64_t bx, std::int64_t by, std::int64_t bz);
  std::uint32_t materialise_element(const Index& e);
  void check_element(const Index& e, const char* what) const;
  void push(std::uint64_t key, std::uint32_t ref);
  bool pop(std::uint32_t& ref);
  [[nodiscard]] std::size_t heap_capacity_bytes() const noexcept;
  template <int A>
  void check_neighbour(std::int32_t nb, std::uint32_t nl, std::int32_t from_brick, int d, double lo, double hi, double un,
                       ChainMailStepResult& r);
  template <int A>
  void settle(std::uint32_t brick, std::uint32_t local, ChainMailStepResult& r);
  void place_sponsor(std::uint32_t brick, std::uint32_t local, Vec3 u, ChainMailStepResult& r);

  ChainMailLattice lattice_;
  std::vector<ChainMailMaterial> materials_;
  std::span<const std::uint8_t> ids_;
  std::size_t n_materials_ = 0;
  std::vector<Box> boxes_;  // (m1 · n + m2) · 6 + direction
  double eps_ = 0;          // m, tolerance for violations and conflicts

  std::vector<std::unique_ptr<Brick>> bricks_;
  std::vector<std::uint64_t> hash_keys_;  // open addressing, all ones = empty
  std::vector<std::int32_t> hash_vals_;
  std::size_t hash_count_ = 0;

  std::uint64_t step_ = 0;                         // steps so far (the high bits of every mark)
  std::vector<std::uint32_t> step_refs_;           // scratch: the sponsors' elements
  std::vector<std::uint64_t> step_linear_;         // scratch: duplicate check
  std::vector<ChainMailSponsor> groove_sponsors_;  // scratch of open_groove()
  std::array<std::vector<HeapEntry>, 65> heap_;    // radix heap buckets
  std::uint64_t heap_last_ = 0;
  std::size_t heap_size_ = 0;
};

}  // namespace lancet::volume
