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
// A step (move). Sponsors are placed exactly where the caller says; every other element moves as
// little as its links require. The box constraints are separable: a link's limits on axis a involve
// only the a coordinates of its ends, so each axis is solved on its own. On one axis, a chain of
// links from a sponsor bounds an element's coordinate from below by the sponsor's value less the
// links' allowances along the chain (its lower bound L, over all chains the tightest) and from above
// likewise (H); the coordinate moves to the nearest point of [L, H]. That is what Enhanced ChainMail
// (largest violation first, eq. 3.9) computes when it settles each (element, axis) pair once, in
// that order, against its neighbours already final. The thesis moves the whole element into its
// sponsor's box only, in one order for all three coordinates; but the three coordinates need three
// different orders (e.g. a diagonal push: x spreads by compression along x and by shear along y),
// so the thesis's version leaves links invalid (its fig. 3.21) and this one does not.
//
// How: per axis, a raising pass and then a lowering pass, each from the sponsors out. A raising
// pass takes a moved coordinate and raises every linked neighbour that lies below the interval it
// now allows that neighbour to that interval's edge, and queues it; the lowering pass is its
// mirror. The queue is a ring of 64 buckets of value (Dial's buckets, as in delta-stepping), taken
// largest value first when raising, each bucket first in, first out: a bucket spans 1/30 of the
// largest change one link allows (compression, stretch or shear over all pairs of materials), so
// one move reaches at most 31 buckets ahead. A coordinate raised again after it was taken (by a
// larger value of its own bucket) is queued and taken again. So the result does not depend on the
// order in which the queue takes its entries, but for rounding: this is a label-correcting
// propagation (a coordinate moves only by more than 1e-9 of the spacing, so each link is met to that
// tolerance). The tests compare it with a plain largest-violation-first ChainMail (1e-6 of the
// spacing) and a recorded groove. Where the bounds disagree (L > H: a coordinate raised that a
// neighbour then requires lower, or a link that would have to move a sponsor: sponsors that
// contradict each other, a groove wider than its cut or its floor can open without tearing) the
// step counts a conflict each time it finds one, and the larger of the two moves from where the
// coordinate was before the step prevails (the lowering, and its propagation, only when it is the
// larger: as largest violation first would take it, and alike for mirror-image sides, a raise
// winning a tie); the links between the two remain invalid. conflicts == 0 means every link is
// valid (to 1e-9 of the spacing) after a step from a valid state. A step from the invalid state a
// conflict leaves repairs only the links its moves reach.
//
// Once per step. Each coordinate of each element is counted once per step (`processed`): an
// element pushed along one axis (a groove, a push) once, one moved diagonally at most three times.
// Instead of Dräger's ignore-direction flags (thesis fig. 3.22), each element carries a 64-bit
// mark: the step counter (32 bits; after 4e9 steps every mark's counter is cleared once and
// counting starts again) above its material, its 6 link bits, and the bits of the step (raised and
// lowered per axis, moved, sponsor, queued), so that moving a neighbour reads one word besides its
// coordinate. The thesis also restricts the left side of a cut to propagate only left/down and the
// right side only right/down. Here the removed links already keep each side's propagation on its
// own side; the only places where the sides still meet are the intact tissue past the cut's ends
// and under its floor, where the direction rule would leave the links between the two sides
// unchecked (invalid). So it is not used: both sides' drags meet there, and an impossible opening
// is reported as conflicts.
//
// Cut and groove. cut() removes every x and y link that crosses the cut surface: the polyline (x,
// y; z ignored) swept from the lattice's top layer (largest z) down by `depth`. The elements at
// the ends of removed links are the cut's faces, each on the left or right of the polyline (left of
// its direction of travel). open_groove() displaces the faces held by the retractor (an arc-length
// range of the polyline and a depth below each face column's top element) by width/2 away from the
// cut, perpendicular to the segment they face (near a polyline corner blended toward the miter of
// both normals, which keeps the opening across each segment exactly the width while the direction
// turns smoothly), all as sponsors of one step; everything
// else follows by ChainMail. The opening between the held faces is exactly `width`; below and past
// the held faces the groove closes as fast as the material's shear allows (by 2·max_shear of the z
// links per layer, of the links along the cut per element), so the material decides the groove's
// V shape. A groove too wide for its cut (still open where the cut ends or at its floor) cannot be
// valid and is reported as conflicts.
//
// Memory. Elements live in 8×8×8 bricks created on demand (an open-addressing hash from brick
// coordinates; each brick keeps its 6 neighbour bricks, so a step never hashes). Only bricks that
// hold a moved, queued or cut element exist; memory follows the deformed region, never the volume:
// the same cut in a 64³ and a 4096³ lattice uses the same bytes. A brick stores its elements as
// arrays (displacement per axis, mark, and a raised coordinate's value before the step: 40 B per
// element, 20.5 kB per brick), so a pass over one axis touches 16 B per element (24 B where it
// raises) and an x-row of 8 shares a cache line. A brick whose elements and
// halo all have one material is flagged, and its passes skip the per-neighbour material lookup.
// Plus the queue (4 B per entry, the capacity of the largest pass so far) and the hash.
//
// Speed: the figures, against a bare flood fill in the same run, are in docs/PERFORMANCE.md
// (lancet-bench-chainmail).
//
// Threads and allocation: one thread (the viz thread); not real-time safe. A step allocates when
// the deformed region grows (new bricks) or its queue outgrows the buckets of earlier steps;
// the same step repeated after reset() allocates nothing. cut() allocates its result. Invalid
// arguments throw std::invalid_argument naming the field and value, before any state changes;
// numerical trouble in a step is counted (conflicts), never thrown. Deterministic: one thread, one
// order, so the same steps on the same lattice give the same displacements bit for bit (replays
// rely on it).

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
  std::uint64_t processed = 0;     ///< coordinates the step moved (each once, however often the queue took it), plus 1 per sponsor (= elements when they move along one axis)
  std::uint64_t moved = 0;         ///< elements whose position changed
  std::uint64_t conflicts = 0;     ///< times a link could not be made valid: a coordinate raised, then lowered, or a link that would move a sponsor (0: every link valid, after a step from a valid state)
  std::uint64_t materialised = 0;  ///< elements newly materialised (whole bricks, 512 each)
};

/// One face element of a cut: an element whose link across the cut surface was removed.
struct ChainMailCutFace {
  std::array<int, 3> element{};  ///< (i, j, k)
  int side = 0;                  ///< +1 left of the polyline's direction of travel, −1 right
  Vec3 away;                     ///< z = 0; displacement per metre of half-width that opens the groove (unit on a straight stretch, longer near corners)
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

  /// Every element back at rest and every link restored (cuts made before are undone: cut again);
  /// keeps the materialised bricks and queue capacity, so repeating the same steps does not
  /// allocate.
  void reset() noexcept;

  /// For tests only (product code never calls it): count on from `steps` steps made, as if the
  /// steps in between had touched nothing, so that a test reaches the step counter's wrap (see
  /// "Once per step" above: after 2^32 − 1 steps every mark's step is cleared) without making 4e9
  /// steps. `steps` >= the steps made so far since the last wrap (counting back would let marks
  /// of earlier steps read as those of the current one).
  void set_steps_made_for_testing(std::uint32_t steps) noexcept;

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
  struct AxisBox {
    double lo, hi;  // m, neighbour's displacement minus the element's, on one axis
  };
  struct Seed {
    double value;       // m, a sponsor's displacement on the pass's axis
    std::uint32_t ref;  // brick << 9 | local
  };
  static constexpr std::size_t kRing = 64;  // buckets of a pass's queue
  struct Pass;                               // what a pass keeps in registers (chainmail.cpp)

  [[nodiscard]] std::uint8_t material_at(std::int64_t i, std::int64_t j, std::int64_t k) const noexcept;
  [[nodiscard]] bool present_at(std::int64_t i, std::int64_t j, std::int64_t k) const noexcept;
  [[nodiscard]] std::uint8_t neighbour_material(const Brick& b, std::uint32_t local, int direction) const noexcept;
  [[nodiscard]] std::int32_t find_brick(std::int64_t bx, std::int64_t by, std::int64_t bz) const noexcept;
  std::int32_t materialise_brick(std::int64_t bx, std::int64_t by, std::int64_t bz);
  std::uint32_t materialise_element(const Index& e);
  /// Removes the link between e and its neighbour n = e + 1 along axis (both sides of it).
  void unlink(const Index& e, const Index& n, int axis);
  void check_element(const Index& e, const char* what) const;
  [[nodiscard]] std::size_t ring_capacity_bytes() const noexcept;
  void place_sponsor(std::uint32_t brick, std::uint32_t local, Vec3 u, ChainMailStepResult& r);
  template <int A, bool Up>
  void pass(ChainMailStepResult& r);
  template <int A, bool Up>
  void relax_ref(Pass& p, std::uint32_t ref, ChainMailStepResult& r);
  template <int A, bool Up, bool Uniform>
  void relax(Pass& p, Brick& brick, std::uint32_t b, std::uint32_t local, ChainMailStepResult& r);
  template <int A, bool Up>
  void move_to(Pass& p, Brick& n, std::uint32_t nb, std::uint32_t nl, double v, double before);
  template <int A, bool Up>
  bool unmaterialised_moves(std::uint32_t b, std::uint32_t l, int d, double ue, double& v) const;

  ChainMailLattice lattice_;
  std::vector<ChainMailMaterial> materials_;
  std::span<const std::uint8_t> ids_;
  std::size_t n_materials_ = 0;
  std::array<std::vector<AxisBox>, 3> axis_boxes_;  // per axis: (m1 · n + m2) · 6 + direction
  double eps_ = 0;        // m, tolerance for violations and conflicts
  double inv_delta_ = 0;  // 1/m, buckets of a pass per m of displacement

  std::vector<std::unique_ptr<Brick>> bricks_;
  std::vector<std::uint64_t> hash_keys_;  // open addressing, all ones = empty
  std::vector<std::int32_t> hash_vals_;
  std::size_t hash_count_ = 0;

  std::uint64_t step_ = 0;                         // steps so far (the high bits of every mark)
  std::vector<std::uint32_t> step_refs_;           // scratch: the sponsors' elements
  std::vector<std::uint64_t> step_linear_;         // scratch: duplicate check
  std::vector<ChainMailSponsor> groove_sponsors_;  // scratch of open_groove()
  std::vector<Seed> seeds_;                        // scratch of a pass: the sponsors in the order their values come up
  std::array<std::vector<std::uint32_t>, kRing> ring_;  // a pass's queue: buckets of refs (brick << 9 | local)
};

}  // namespace lancet::volume
