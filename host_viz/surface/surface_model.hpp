#pragma once
// SurfaceModel: the outer skin the trainee cuts (thesis 3.2; ALGORITHMS.md §3). An OpenMesh
// triangle mesh with rest and current positions, normals, a material per face and texture-atlas
// coordinates per vertex, kept in a BVH, with the operations of the surface stage:
//   - pre-rupture deformation: a Gaussian-falloff displacement around the contact, returning
//     elastically when released;
//   - the progressive node-snapping cut: as the tool's path crosses mesh edges, the vertex nearest
//     each crossing snaps onto the path; every snapped vertex but the cut's start and end is
//     duplicated, and the faces on the right of the path are reconnected to the copy. No face is
//     created or removed: the face count stays the same and area is conserved until the cut
//     opens; only vertices are added;
//   - opening (copies moved apart by ±D/2 · V_co, V_co = normalize(V_tool × V_sn), tapered to the
//     cut's ends; D set by pulling, bounded by an elastic limit) and a damped, decaying wrinkle
//     near the cut.
// Every operation touches only the faces near the tool: the cost does not grow with the mesh.
//
// Faces have stable indices 0..n_faces()-1 for the life of the model (the BVH, patch export and
// the blood atlas use them); reconnecting a face to a copy re-adds it in OpenMesh under a new
// handle, so OpenMesh face handles are not stable (use face_handle()). Vertices are only added.
// Allocating; viz frame time, never the real-time path.

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/result.hpp"
#include "surface/bvh.hpp"
#include "surface/triangle_mesh.hpp"
#include "volume/build_arrays.hpp"

namespace lancet::surface {

struct SurfaceTraits : public OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3f;
  using Normal = OpenMesh::Vec3f;
  using TexCoord2D = OpenMesh::Vec2f;
  VertexAttributes(OpenMesh::Attributes::Normal | OpenMesh::Attributes::Status | OpenMesh::Attributes::TexCoord2D);
  HalfedgeAttributes(OpenMesh::Attributes::PrevHalfedge | OpenMesh::Attributes::Status);
  EdgeAttributes(OpenMesh::Attributes::Status);
  FaceAttributes(OpenMesh::Attributes::Status);
};
using SurfaceMesh = OpenMesh::TriMesh_ArrayKernelT<SurfaceTraits>;

struct SurfaceParams {
  // Pre-rupture deformation.
  double deform_sigma = 0.006;     ///< m, Gaussian width of the dent around the contact
  double deform_max_depth = 0.015; ///< m, deepest dent rendered
  double relax_tau = 0.15;         ///< s, time constant of the elastic return
  // Cut.
  double snap_limit = 0.5;         ///< the largest share of an edge a vertex may travel when snapping
  double open_limit = 0.012;       ///< m, elastic limit of the opening width D
  double open_rest = 0.0;          ///< m, opening a released cut returns to
  double open_spread = 0.008;      ///< m, how far beside the cut the skin follows the opening
  // Wrinkle near the cut on pulling.
  double wrinkle_reach = 0.012;    ///< m, how far from the cut it extends
  double wrinkle_wavelength = 0.004;  ///< m
  double wrinkle_decay = 0.004;    ///< m, amplitude falls as exp(−d / decay) away from the cut
  double wrinkle_tau = 0.4;        ///< s, time constant of its damping
};

/// A contact pressing the surface (pre-rupture): the proxy on the surface and the tool below it.
struct Contact {
  Vec3 point;       ///< m, where the tool touches (the proxy)
  Vec3 direction;   ///< unit, into the tissue (proxy → tool)
  double depth;     ///< m, how far the tool is past the surface
};

/// What one progressive cut step did.
struct CutStepResult {
  std::size_t crossings = 0;       ///< mesh edges the path crossed
  std::size_t snapped = 0;         ///< vertices snapped onto the path
  std::size_t duplicated = 0;      ///< vertices split into two
  std::size_t faces_reconnected = 0;
  std::size_t snaps_limited = 0;   ///< snaps shortened so that no triangle flips or collapses
  std::size_t refused = 0;         ///< reconnections OpenMesh refused (0 expected; rolled back)
  bool hit_boundary = false;       ///< the path ran into the mesh's boundary or an open cut
};

/// One cut: its chain of snapped vertices and the pairs it split.
struct Cut {
  std::vector<std::uint32_t> chain;          ///< snapped vertices in path order (start … tip)
  struct Pair {
    std::uint32_t left, right;               ///< the original (left of the path) and its copy
    Vec3 rest_left, rest_right;              ///< m, rest positions when split (before opening)
    Vec3 v_co;                               ///< unit opening direction (towards the right)
  };
  std::vector<Pair> pairs;
  std::vector<Vec3> path;                    ///< m, the tool path points fed to the cut
  double opening = 0;                        ///< m, current opening width D
  std::vector<std::uint32_t> spread;         ///< vertices beside the cut moved by the opening
  /// Per vertex within open_spread of the cut (at rest): its nearest pair and its signed falloff.
  /// It depends on the rest geometry only, so it is rebuilt when pairs are added, not per opening.
  struct SpreadEntry {
    std::uint32_t vertex, pair;
    float side_fall;                         ///< ±(1 − d / open_spread)², the side of the cut times the falloff
  };
  std::vector<SpreadEntry> spread_map;
  std::size_t spread_map_pairs = 0;          ///< pairs.size() when spread_map was built (0: not built)
  bool active = false;
};

struct SurfaceStats {
  std::size_t faces = 0, vertices = 0;
  std::size_t boundary_edges = 0;
  std::size_t non_manifold_vertices = 0;
  std::size_t degenerate_faces = 0;      ///< area ≤ 1e-14 m² or repeated vertex
  std::size_t flipped_faces = 0;         ///< current normal against the face's rest normal
  std::size_t boundary_loops = 0;
  bool boundary_loops_closed = true;     ///< every boundary halfedge chain returns to its start
  std::size_t stale_haptic = 0;          ///< vertices whose kept haptic position is not rest + opening + wrinkle (0 expected)
  std::size_t stale_boundary_flags = 0;  ///< faces whose kept face_on_boundary() is not the mesh's (0 expected)
  double area = 0;                       ///< m², current positions
  double rest_area = 0;                  ///< m², rest positions
};

class SurfaceModel {
 public:
  /// positions: m; triangles: counter-clockwise from outside; face_material: one per triangle
  /// (or empty: all 0). Errors: indices out of range, a non-manifold input (a face OpenMesh
  /// refuses), non-finite positions.
  [[nodiscard]] static Result<std::unique_ptr<SurfaceModel>> create(std::span<const Vec3f> positions,
                                                                    std::span<const std::array<std::uint32_t, 3>> triangles,
                                                                    std::span<const std::uint16_t> face_material = {},
                                                                    const SurfaceParams& params = {});
  /// The same from a mesh handed over: its triangles and materials become the model's own arrays,
  /// not copied (its normals are not used: the model makes its own from the faces).
  [[nodiscard]] static Result<std::unique_ptr<SurfaceModel>> create(TriangleMesh&& mesh, const SurfaceParams& params = {});

  [[nodiscard]] const SurfaceMesh& mesh() const noexcept { return mesh_; }
  [[nodiscard]] std::size_t n_faces() const noexcept { return faces_.size(); }
  [[nodiscard]] std::span<const std::array<std::uint32_t, 3>> faces() const noexcept { return faces_; }
  [[nodiscard]] std::uint16_t face_material(std::uint32_t f) const noexcept { return material_[f]; }
  [[nodiscard]] SurfaceMesh::FaceHandle face_handle(std::uint32_t f) const noexcept { return handle_[f]; }
  [[nodiscard]] Vec3 position(std::uint32_t v) const noexcept;
  [[nodiscard]] Vec3 rest_position(std::uint32_t v) const noexcept;
  /// The surface the stylus is felt against: the current position without the dent the tool
  /// itself presses (rest + opening + wrinkle). The dent is what the trainee sees of the contact;
  /// exporting it to the haptics would let the surface, and the proxy on it, follow the tool down.
  [[nodiscard]] Vec3 haptic_position(std::uint32_t v) const noexcept { return to_vec3(haptic_position_f(v)); }
  /// The same in the mesh's floats, kept per vertex as rest, opening and wrinkle change (one load
  /// where the patch export would gather three arrays).
  [[nodiscard]] Vec3f haptic_position_f(std::uint32_t v) const noexcept {
    const OpenMesh::Vec3f& p = haptic_[v];
    return {p[0], p[1], p[2]};
  }
  /// Whether stable face f has an edge on the mesh's boundary (a cut's lip or the border): kept per
  /// face as faces are reconnected.
  [[nodiscard]] bool face_on_boundary(std::uint32_t f) const noexcept { return on_boundary_[f] != 0; }
  [[nodiscard]] MeshView view() const noexcept;
  [[nodiscard]] const TriangleBvh& bvh() const noexcept { return bvh_; }
  [[nodiscard]] const SurfaceParams& params() const noexcept { return params_; }
  /// Bumped whenever positions or connectivity change (to redraw only when needed).
  [[nodiscard]] std::uint64_t revision() const noexcept { return revision_; }

  // ---- pre-rupture deformation ----
  /// Advances the deformation by dt: with a contact, vertices near it take the Gaussian dent;
  /// all others displaced earlier return towards rest with time constant relax_tau.
  void update_contact(const std::optional<Contact>& contact, double dt);
  /// Vertices currently displaced by deformation (the working set; 0 at rest).
  [[nodiscard]] std::size_t deformed_vertices() const noexcept { return deformed_.size(); }

  // ---- cutting ----
  /// Starts a cut where the tool meets the surface (the nearest vertex of the face under p snaps
  /// to p). False when p is farther than max_distance from the surface.
  bool begin_cut(Vec3 p, double max_distance = 0.005);
  /// Extends the active cut along the surface to (the surface point nearest) p.
  CutStepResult cut_to(Vec3 p);
  /// Ends the active cut; its last vertex stays joined (the end E).
  void end_cut();
  [[nodiscard]] const std::vector<Cut>& cuts() const noexcept { return cuts_; }
  [[nodiscard]] bool cutting() const noexcept { return !cuts_.empty() && cuts_.back().active; }

  // ---- opening and wrinkle ----
  /// Sets cut c's opening width D (clamped to [0, open_limit]); returns the width applied.
  double set_opening(std::size_t cut, double width);
  /// A pull of displacement (m) on cut c: opening D = displacement, within the elastic limit, and
  /// a wrinkle of the skin beside the cut of amplitude proportional to the pull.
  double pull(std::size_t cut, double displacement);
  /// Advances the wrinkle's damping by dt (and the deformation's return: see update_contact).
  void relax(double dt);

  [[nodiscard]] SurfaceStats stats() const;

  /// The current surface as plain arrays for drawing: every vertex (copies included, deleted
  /// ones as unused entries), current positions and normals, the stable faces and materials.
  void to_triangle_mesh(TriangleMesh& out) const;

 private:
  // create(), taking the triangles' and materials' arrays where the caller hands them over
  // (own_*: the vectors the spans view, moved from; null: copied).
  static Result<std::unique_ptr<SurfaceModel>> make(std::span<const Vec3f> positions, std::span<const std::array<std::uint32_t, 3>> triangles,
                                                    std::span<const std::uint16_t> face_material, const SurfaceParams& params,
                                                    std::vector<std::array<std::uint32_t, 3>>* own_triangles,
                                                    std::vector<std::uint16_t>* own_material);
  SurfaceModel() = default;
  void set_current(std::uint32_t v);  // current = rest + deformation + opening + wrinkle
  void set_haptic(std::uint32_t v);   // haptic = rest + opening + wrinkle
  bool boundary_of(SurfaceMesh::FaceHandle fh) const;
  void update_boundary_flags(std::uint32_t v);  // the faces around v
  void refresh(std::span<const std::uint32_t> vertices);  // positions → normals, BVH
  std::uint32_t stable_of(SurfaceMesh::FaceHandle fh) const;
  OpenMesh::Vec3f face_cross(std::uint32_t f, bool rest) const;
  OpenMesh::Vec3f vertex_cross_sum(std::uint32_t v) const;
  std::optional<std::uint32_t> locate(Vec3 p, double max_distance, Vec3* on_surface) const;
  bool snap(std::uint32_t v, Vec3 target, CutStepResult& r);
  bool duplicate(Cut& cut, std::size_t k, CutStepResult& r);
  std::uint32_t new_copy(std::uint32_t v);
  bool reattach(const std::vector<std::uint32_t>& faces, std::uint32_t from, std::uint32_t to);
  std::size_t split_fans(std::uint32_t v);
  void apply_opening(Cut& cut);
  void build_spread_map(Cut& cut);
  void build_wrinkle_map(std::size_t cut);
  void gather_around_pairs(const Cut& cut, float r, std::vector<std::uint32_t>& out);

  SurfaceParams params_;
  SurfaceMesh mesh_;
  OpenMesh::VPropHandleT<OpenMesh::Vec3f> rest_;
  OpenMesh::FPropHandleT<std::uint32_t> stable_;
  std::vector<std::array<std::uint32_t, 3>> faces_;
  std::vector<std::uint16_t> material_;
  std::vector<SurfaceMesh::FaceHandle> handle_;
  std::vector<OpenMesh::Vec3f> rest_normal_;       ///< per stable face, for the flip check
  // Displacements on top of rest, per vertex (dense; vertices are few next to faces' data). Zero
  // until a contact, a cut or a pull moves a vertex: ZeroedVector, so the pages of those far from
  // the tool are never touched (they only grow, as vertices are only added).
  volume::ZeroedVector<OpenMesh::Vec3f> deform_, open_, wrinkle_;
  std::vector<OpenMesh::Vec3f> haptic_;            ///< rest + open_ + wrinkle_ (haptic_position)
  std::vector<std::uint8_t> on_boundary_;          ///< per stable face (face_on_boundary)
  std::vector<std::uint32_t> deformed_;            ///< vertices with a deformation displacement
  volume::ZeroedVector<std::uint8_t> in_deformed_;
  std::vector<std::uint32_t> wrinkled_;
  std::vector<float> wrinkle_amp_;                 ///< per vertex in wrinkled_: its profile
  double wrinkle_level_ = 0;                       ///< current wrinkle amplitude (m)
  /// The cut, its pair count and the mesh's vertex count wrinkled_ was made for (none yet).
  std::size_t wrinkle_cut_ = std::numeric_limits<std::size_t>::max(), wrinkle_pairs_ = 0, wrinkle_vertices_ = 0;
  bool wrinkle_live_ = false;  ///< a pull's wrinkle still dying away (relax has work to do)
  TriangleBvh bvh_;
  std::uint64_t revision_ = 0;
  std::vector<Cut> cuts_;
  std::uint32_t walk_face_ = 0;                    ///< stable face under the cut's tip
  Vec3 walk_point_{};
  // Scratch (reused, so steady-state steps do not allocate).
  std::vector<std::uint32_t> scratch_faces_, scratch_vertices_, scratch_touched_;
  std::vector<std::uint32_t> scratch_indices_;  ///< faces_within_any's points on the way down
  std::vector<Vec3f> scratch_points_;
  volume::ZeroedVector<std::uint8_t> mark_;  ///< per vertex or face, 0 but within one call
};

}  // namespace lancet::surface
