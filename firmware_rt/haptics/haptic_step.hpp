#pragma once
// The haptic step of one servo tick, in the model/data manner (STYLE.md): an immutable
// HapticModel, a preallocated HapticData, and haptic_step(), which never allocates.
//
// Stages (ALGORITHMS.md §1–2): free → deform (proxy on the surface, Hooke force
// f = −k (x_device − x_proxy) − D (v_device − v_proxy)) → rupture, once, when a scalpel's force
// exceeds the material's yield force → cutting with directional friction → exit when the device
// leaves the tissue. Cutting, per tick: (1) the cutting direction is the blade direction projected
// onto the surface; (2) the proxy follows the device through viscous drag; (3) motion along the
// cutting direction is followed with the low drag cut_drag_along and backward motion not at all;
// (4) the sideways rest slips with the high drag cut_drag_across. So cutting along the blade is
// easy, sideways hard, backward blocked, and the felt force depends on the blade angle.
// Retractor (ALGORITHMS.md §2, thesis 4.2.4): within snap_distance of the surface the tool snaps
// to the closest point (magnetic effect: the hand is pulled onto it) and grabs it; that point is
// the control point of the opening. Pulling stretches the tissue up to elastic_limit (events
// report the displacement, clamped there) with a spring pulling back; pulled much further, the
// grip slips and the tissue is released.
// Drill: volume haptics on the patch's voxel brick (volume_haptics.hpp); pressing harder than
// drill_min_force removes burr spheres at drill_rate·(|f| − min)·(2000 / ρ) per second, where
// ρ = HU + 1000 (about kg/m³, at least 100) is the density in front of the burr: drill_rate itself
// at 1000 HU (cortical bone), twice as fast through water.

#include <array>
#include <cstdint>

#include "haptics/force_safety.hpp"
#include "haptics/proxy.hpp"
#include "haptics/volume_haptics.hpp"
#include "lancet/shared_model/messages.hpp"

namespace lancet::haptics {

inline constexpr std::size_t kMaxMaterials = 16;

struct HapticModel {
  double proxy_radius = 0.001;             ///< m
  double dt = 0.001;                       ///< s, the servo period
  std::array<MaterialParams, kMaxMaterials> materials{};  ///< by material id (ids beyond: the last)
  SafetyParams safety{};
  Vec3 blade_axis{1, 0, 0};                ///< blade edge direction in the tool frame
  /// m: a free stylus found at most this far behind the surface is brought to its front (pushed
  /// out); deeper, it is left free (a jump to the surface from further would be a shove)
  double capture_depth = 0.01;
  double snap_distance = 0.003;            ///< m: a retractor this close to the surface grabs it
  double elastic_limit = 0.015;            ///< m: how far the grabbed tissue stretches
  double release_factor = 1.5;             ///< pulled beyond elastic_limit × this, the grip slips
  double drill_iso_hu = 300;               ///< HU at and above which the drill meets hard tissue
  double drill_stiffness = 800;            ///< N/m, the felt stiffness of the volume surface
  double drill_burr_radius = 0.0015;       ///< m
  double drill_min_force = 1.0;            ///< N: pressing harder than this removes material
  double drill_rate = 2.0;                 ///< removals per second per newton above the minimum, at 1000 HU
  /// m: a newer patch that moves the triangle under the proxy carries the proxy with it up to
  /// this far; further, the face id is taken to name another piece of surface and the proxy stays
  double ride_max_move = 0.005;
  /// Default materials: id 0 and 1 skin-like, 2 vessel (softer, weaker).
  static HapticModel defaults();
};

/// The probe's (and the swab's, and the scalpel's before it ruptures) contact with the surface.
struct ProbeData {
  bool sliding = false;        ///< dynamic friction last tick
  ProxyScratch scratch{};
  ProxyAnchor anchor{};        ///< where the proxy rested last tick, on which triangle
  std::uint64_t carried = 0;   ///< patch updates that carried the proxy with its triangle
  std::uint64_t carry_lost = 0;///< ... that could not (the triangle gone, or moved too far)
};

/// The scalpel's cut, from the rupture on.
struct ScalpelData {
  Vec3 normal{};               ///< surface normal where the cut entered
  Vec3 entry{};                ///< where it entered (m)
  std::uint32_t material = 1;
  Vec3 last_event{};           ///< where the last kCutProgress was sent
  std::uint64_t ruptures = 0;

  void hash(WordHasher& w) const noexcept { w.v(normal), w.v(entry), w.word(material), w.v(last_event), w.word(ruptures); }
};

/// The retractor's grip.
struct RetractorData {
  bool grabbed = false;        ///< holding the tissue
  Vec3 control{};              ///< where it grabbed (m)
  std::uint32_t material = 1;
  Vec3 last_pull_event{};

  void hash(WordHasher& w) const noexcept { w.b(grabbed), w.v(control), w.word(material), w.v(last_pull_event); }
};

/// The drill's own copy of the bone and what it has removed.
struct DrillData {
  VoxelBrick brick{};          ///< the patch's brick, carved as it drills
  std::uint64_t brick_seq = 0; ///< patch seq the copy came from
  /// The drill's recent removals (a ring): a newer brick from the viz may not reflect them yet
  /// (it was built before the viz saw their events), so they are carved into it again.
  struct Carve {
    Vec3 centre;
    double radius;
    std::uint64_t tick;
  };
  static constexpr std::size_t kCarveMemory = 128;
  std::array<Carve, kCarveMemory> carves{};
  std::size_t n_carves = 0, carve_head = 0;    ///< valid entries; where the next one goes
  std::uint64_t reapplied = 0;                 ///< removals carved again into a newer brick
  double progress = 0;         ///< accumulated removal (1 = remove one burr sphere)
  std::uint64_t removals = 0;

  /// Its state without the brick (the patch's, hashed where it comes from): the counters and the
  /// removals it remembers, oldest first.
  void hash(WordHasher& w) const noexcept {
    w.word(brick_seq), w.f(progress), w.word(removals), w.word(reapplied), w.word(n_carves), w.word(carve_head);
    for (std::size_t i = 0; i < n_carves; ++i) {
      const Carve& c = carves[(carve_head + kCarveMemory - n_carves + i) % kCarveMemory];
      w.v(c.centre), w.f(c.radius), w.word(c.tick);
    }
  }
};

struct HapticData {
  /// The version of the patch in use (0: none or unversioned): a new one is one of another version.
  std::uint64_t patch_version = 0;
  /// Search tree of the patch in use, when the input brings none (built when its version changes).
  PatchBvh bvh{};
  Stage stage = Stage::kFree;
  Vec3 proxy{};
  bool initialised = false;
  bool contact = false;
  ProbeData probe{};
  ScalpelData scalpel{};
  RetractorData retractor{};
  DrillData drill{};
  SafetyData safety{};

  /// Its state without the search tree (built from the patch) or the scratch. The probe's fields
  /// stand around patch_version: the order recordings were hashed in, kept so they still replay.
  void hash(WordHasher& w) const noexcept {
    w.word(static_cast<std::uint64_t>(stage)), w.v(proxy), w.b(initialised), w.b(contact);
    w.b(probe.sliding), w.word(patch_version);
    probe.anchor.hash(w);
    w.word(probe.carried), w.word(probe.carry_lost);
    scalpel.hash(w);
    retractor.hash(w);
    drill.hash(w);
    safety.hash(w);
  }
};

struct HapticInput {
  Vec3 device;                 ///< device (haptic interface point) position (m)
  Vec3 velocity;               ///< its velocity (m/s)
  Quat orientation;            ///< tool orientation (the blade is orientation · blade_axis)
  ToolMode mode = ToolMode::kProbe;
  const TissuePatch* patch = nullptr;  ///< null: no tissue known
  /// Its version (the seqlock's; each new one is a new patch): with one, the step searches the
  /// patch through HapticData::bvh and carries the proxy across patch updates; 0 (unit tests):
  /// it scans the whole patch and does not carry
  std::uint64_t patch_version = 0;
  /// The patch's search tree, built for patch_version by whoever brings the patch (lancet-rt's
  /// patch intake, off the tick); null or built for another version: the step builds it into
  /// HapticData::bvh on the tick the version changes. Either way the same tree (it is a function
  /// of the patch), so a replay that brings none steps exactly as the live servo did.
  const PatchBvh* tree = nullptr;
  std::uint64_t tick = 0;              ///< seq of the ToolSample this tick pushes
};

struct HapticOutput {
  Vec3 force;                  ///< on the hand, after safety (N)
  Vec3 proxy;
  Stage stage = Stage::kFree;
  bool contact = false;
  std::uint32_t events = 0;
  EventPayload payload{};
};

/// One tick: the tool's own step (haptics/probe.cpp, scalpel.cpp, retractor.cpp, drill.cpp), then
/// the contact events and the safety layer. Real-time safe: no allocation, no exceptions; with a
/// patch version, O(triangles near the tool), but on the tick a new patch arrives without its tree
/// (the tree's build, O(patch triangles)); without a version, O(patch triangles).
void haptic_step(const HapticModel& m, HapticData& d, const HapticInput& in, HapticOutput& out) noexcept;

}  // namespace lancet::haptics
