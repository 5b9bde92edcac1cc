#pragma once
// TissueScene: the tissue of one simulation, owning every model of it (ALGORITHMS.md §1, the
// hybrid model): the volume (CT in HU with material labels) placed in the world, the skin surface
// made from the volume's marching-cubes skin (the SurfaceModel that is dented, cut and opened),
// the ChainMail lattice around cuts (elements materialised lazily: the groove under an incision), the live
// bone isosurface and the drill.
//
// It applies lancet-rt's ToolSample stream in tick order, both hands' samples interleaved, each
// hand's state kept apart (TissueScene::apply_one says how two hands share the surface): the dent follows the proxy; a rupture
// starts a cut and each cut-progress event (0.5 mm of blade travel) extends it on the surface and,
// as a thin cut, into the ChainMail lattice down to the scenario's cut depth; a pull opens the
// incision to the hand's displacement and the groove with it (the same width at the top, closing
// as the tissue's shear allows below); a drill removal removes voxels from the volume (the ones
// lancet-rt already removed from its brick: the reconciliation) and re-extracts the bone surface
// there. It exports the TissuePatch around the tool with the voxel brick, and a mesh to draw: the
// surface with the groove's walls and floor beneath the opening (or, when the trainee works on
// exposed bone, the live bone surface with its drilled holes).
//
// World frame: m, z up, the skin's highest point at z = 0; the phantom lies along x. Not
// real-time: the viz thread only; allocates while the tissue changes. Configure-time errors come
// back as Result; nothing a peer sends can make it throw (samples are checked by wire::check
// before they get here, and drill radii are bounded there).

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "tissue/patch_export.hpp"
#include "tissue/volume_brick.hpp"
#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"
#include "surface/triangle_mesh.hpp"
#include "surface/surface_model.hpp"
#include "volume/live_isosurface.hpp"
#include "volume/phantom.hpp"

namespace lancet::volume {
class ChainMail;
struct ChainMailCut;
}  // namespace lancet::volume

namespace lancet::tissue {

enum class SceneSource : std::uint8_t {
  kBlock,    ///< the procedural skin block over layers parallel to it (no data needed)
  kPhantom,  ///< the built-in CT phantom limb
  kVolume,   ///< a CT given by the caller (SceneDescription::volume)
  kMesh,     ///< a surface mesh alone (SceneDescription::mesh): no volume, so no brick, groove or drill
};
enum class SceneSurface : std::uint8_t {
  kSkin,  ///< the trainee touches, cuts and opens the skin
  kBone,  ///< the bone is exposed: the trainee touches and drills the bone's surface
};

struct SceneDescription {
  SceneSource source = SceneSource::kPhantom;
  /// kVolume: the CT (HU). Its labels may be empty: they are then made from the isovalues (air
  /// below skin_iso, bone at or above bone_iso, muscle between).
  volume::LabelledVolume volume;
  surface::TriangleMesh mesh;  ///< kMesh: the surface (world frame, m)
  float skin_iso = -300;  ///< HU of the skin's isosurface
  float bone_iso = 300;   ///< HU of the bone's isosurface
  SceneSurface surface = SceneSurface::kSkin;
  /// kVolume (and kPhantom, where the default turns the limb along x): world axis a is the
  /// volume's axis `axis[a]` times `sign[a]`. The offset is chosen so that the volume's centre is
  /// at x = y = 0 and the skin's top at z = 0.
  std::array<int, 3> axis{0, 1, 2};
  std::array<int, 3> sign{1, 1, 1};
  double cut_depth = 0.006;  ///< m the scalpel's cut reaches below the skin
  surface::TissueBlockParams block{};
  surface::SurfaceParams surface_params{};
  PatchExportParams patch{};
};

/// The groove under one incision: the ChainMail cut along the cut's path and its opening.
struct GrooveFigures {
  std::size_t faces = 0;          ///< ChainMail face elements (both walls)
  double length = 0;              ///< m, the cut's polyline in x-y
  double width = 0;               ///< m, the opening it was last opened to (the incision's D)
  double top_gap = 0;             ///< m, the widest gap between the walls' top face elements, measured
  double depth = 0;               ///< m, deepest face element below the top of its column
  std::uint64_t conflicts = 0;    ///< ChainMail steps' conflicts (0: every link valid)
};

/// What lancet-rt's events said happened (and what the scene made of them).
struct SceneEvents {
  std::uint64_t samples = 0, contacts = 0, contact_ends = 0, ruptures = 0, cut_steps = 0, grabs = 0, releases = 0,
                pulls = 0, clamped_ticks = 0, faded_ticks = 0, fault_ticks = 0;
  std::uint64_t drill_removals = 0;  ///< kDrillRemove events carved into the volume
  std::uint64_t voxels_drilled = 0;  ///< voxels they removed
  std::uint64_t bone_updates = 0;    ///< local re-extractions of the bone surface
  std::string last;                  ///< the newest event worth a line on screen
  bool last_is_warning = false;
};

/// The cuts as measured on the mesh: the longest one's length along its chain of split vertices
/// (at rest) and the widest gap between the two lips of any cut (paired vertices, as they are now).
struct CutFigures {
  std::size_t cuts = 0;
  double longest = 0, opening = 0;  ///< m
  Vec3 from{}, to{};                ///< the longest cut's ends on the mesh (m)
};

class TissueScene {
 public:
  /// Builds the volume, places it, extracts the surface. Errors: an empty or non-finite volume,
  /// labels of the wrong size, an invalid axis permutation, no surface at the isovalue.
  [[nodiscard]] static Result<std::unique_ptr<TissueScene>> create(SceneDescription description);
  ~TissueScene();
  TissueScene(const TissueScene&) = delete;
  TissueScene& operator=(const TissueScene&) = delete;

  /// One frame's samples, in order (checked and in sequence; see VizSession). Returns true when
  /// what is drawn changed.
  bool apply(std::span<const ToolSample> samples);

  /// The TissuePatch around centre: the surface's triangles (haptic positions) and the brick.
  /// Leaves seq, t_ns and samples_applied to the caller.
  std::size_t export_patch(Vec3 centre, TissuePatch& out);
  /// The same with the caller's scratch: it only reads the scene, so patches for two hands can be
  /// made at once on two threads, a scratch each.
  std::size_t export_patch(Vec3 centre, PatchExportScratch& scratch, TissuePatch& out) const;

  /// The mesh to draw (world frame): the surface with the grooves' walls and floors (walls false:
  /// without them, when the volume is drawn beneath), or the live bone surface on exposed bone.
  void draw_mesh(surface::TriangleMesh& out, bool walls = true) const;
  /// Bumped whenever draw_mesh would give something else.
  [[nodiscard]] std::uint64_t revision() const noexcept;

  [[nodiscard]] const surface::SurfaceModel& surface() const noexcept { return *surface_; }
  [[nodiscard]] surface::SurfaceModel& surface() noexcept { return *surface_; }
  [[nodiscard]] const volume::Volume& volume() const noexcept { return tissue_.volume; }
  [[nodiscard]] std::span<const std::uint8_t> labels() const noexcept { return tissue_.material; }
  [[nodiscard]] const VolumePlacement& placement() const noexcept { return placement_; }
  [[nodiscard]] const SceneDescription& description() const noexcept { return desc_; }
  /// The live bone surface in the volume's frame (nullptr until the first drill removal, except
  /// on exposed bone where it exists from the start).
  [[nodiscard]] const volume::LiveIsosurface* bone() const noexcept { return bone_.get(); }
  [[nodiscard]] const SceneEvents& events() const noexcept { return events_; }
  [[nodiscard]] CutFigures cut_figures() const;
  /// One per surface cut that reached the volume (in order).
  [[nodiscard]] std::vector<GrooveFigures> grooves() const;
  /// The cuts' paths on the surface (m), for scoring.
  [[nodiscard]] std::vector<std::vector<Vec3>> cut_paths() const;
  /// The surface's topmost point straight below (x, y) (from 0.2 m above), or nullopt when none.
  [[nodiscard]] std::optional<Vec3> surface_below(double x, double y) const;
  /// A polyline laid on the surface: resampled every `step` m in x-y, each point at the surface.
  [[nodiscard]] std::vector<Vec3> drape(const std::vector<Vec3>& line, double step = 0.001) const;
  /// The volume as it is drawn: the tissue's volume with each open groove carved out (air where
  /// the incision gapes, a V down to the cut depth), so that a ray cast through the opening sees
  /// the layers beneath. Made at the first call; kept up to date from then on.
  [[nodiscard]] const volume::Volume& render_volume();
  /// The voxels the drill or an opening groove changed since the last call (one box around them; empty: none), for
  /// whoever keeps a copy of the volume (the GPU ray caster).
  [[nodiscard]] volume::VoxelBox take_volume_changes() noexcept;
  /// The placement as a column-major 4×4 matrix (volume frame → world).
  [[nodiscard]] std::array<float, 16> volume_to_world() const noexcept;
  /// Material label of the volume at a world point (kAir outside).
  [[nodiscard]] std::uint8_t label_at(Vec3 world) const noexcept;

 private:
  TissueScene();
  void apply_one(const ToolSample& t, double dt);
  void tally(const ToolSample& t);
  void drill(const ToolSample& t);
  void update_grooves();
  void ensure_lattice();
  void refresh_bone_surface();

  struct Groove;
  void carve(const Groove& g, double previous_width);
  SceneDescription desc_;
  volume::LabelledVolume tissue_;
  VolumePlacement placement_;
  std::unique_ptr<surface::SurfaceModel> surface_;
  PatchExportScratch scratch_;
  // The ChainMail lattice: the volume's grid turned into the world (z up), built at the first cut.
  std::unique_ptr<volume::ChainMail> chainmail_;
  std::vector<std::uint8_t> lattice_ids_;
  Vec3 lattice_origin_{};
  std::vector<Groove> grooves_;
  // The bone surface, re-extracted where the drill removed voxels.
  std::unique_ptr<volume::LiveIsosurface> bone_;
  volume::VoxelBox dirty_{};
  volume::VoxelBox changed_{};  ///< drilled or carved since take_volume_changes()
  volume::Volume render_;       ///< render_volume() (empty until asked for)
  bool bone_changed_ = false;
  std::int64_t last_removal_ns_ = 0;  ///< t_ns of the newest drill removal
  std::uint64_t own_revision_ = 0;
  SceneEvents events_;
  /// What a hand last gave the surface model.
  struct HandFeed {
    ToolSample last{};
    bool any = false;
  };
  static constexpr std::size_t kNoHand = kHandCount, kNoCut = static_cast<std::size_t>(-1);
  /// The cut with a path point nearest `at` in x-y (kNoCut: none; the newest when `at` is not finite).
  [[nodiscard]] std::size_t nearest_cut(Vec3 at) const;
  std::array<HandFeed, kHandCount> fed_{};
  std::size_t dent_hand_ = kNoHand;  ///< the hand whose press the dent shows
  std::size_t cut_hand_ = kNoHand;   ///< the hand making the active cut
  std::array<std::size_t, kHandCount> held_cut_{kNoCut, kNoCut};  ///< by hand: the cut its retractor holds
};

/// The skin's isosurface of volume v placed in the world as the scene places it: placement's
/// offset is set so that the volume's centre lies at x = y = 0 and the skin's top at z = 0, the
/// vertices are turned and moved there, the triangles flipped where the axes change handedness,
/// every face skin. The isosurface's arrays are taken, not copied; no normals (the surface model
/// makes its own from the faces). What TissueScene::create does between extraction and surface.
surface::TriangleMesh place_skin(volume::IsoSurface&& iso, const volume::Volume& v, VolumePlacement& placement);

/// Material labels from HU thresholds (air, muscle, cortical bone), for a CT without labels.
std::vector<std::uint8_t> labels_from_hu(const volume::Volume& v, float skin_iso, float bone_iso);

}  // namespace lancet::tissue
