#include "surface/surface_model.hpp"

#include "volume/halfedge_build.hpp"
#include "volume/in_two_halves.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <string>
#include <thread>

namespace lancet::surface {

namespace {

using P = OpenMesh::Vec3f;
using VH = SurfaceMesh::VertexHandle;
using FH = SurfaceMesh::FaceHandle;
using HH = SurfaceMesh::HalfedgeHandle;

Vec3 v3(const P& p) { return {p[0], p[1], p[2]}; }
P pf(Vec3 v) { return P(static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)); }
VH vh(std::uint32_t v) { return VH(static_cast<int>(v)); }
std::uint32_t idx(VH v) { return static_cast<std::uint32_t>(v.idx()); }

constexpr double kMinArea = 1e-14;  // m²: below this a face counts as degenerate
constexpr int kMaxWalkSteps = 4096;
constexpr double kCutReach = 0.02;  // m: a blade tip this close to the surface cuts the point over it

}  // namespace

Result<std::unique_ptr<SurfaceModel>> SurfaceModel::create(std::span<const Vec3f> positions,
                                                           std::span<const std::array<std::uint32_t, 3>> triangles,
                                                           std::span<const std::uint16_t> face_material, const SurfaceParams& params) {
  return make(positions, triangles, face_material, params, nullptr, nullptr);
}

Result<std::unique_ptr<SurfaceModel>> SurfaceModel::create(TriangleMesh&& mesh, const SurfaceParams& params) {
  return make(mesh.vertices, mesh.triangles, mesh.material, params, &mesh.triangles, &mesh.material);
}

Result<std::unique_ptr<SurfaceModel>> SurfaceModel::make(std::span<const Vec3f> positions, std::span<const std::array<std::uint32_t, 3>> triangles,
                                                         std::span<const std::uint16_t> face_material, const SurfaceParams& params,
                                                         std::vector<std::array<std::uint32_t, 3>>* own_triangles,
                                                         std::vector<std::uint16_t>* own_material) {
  if (!face_material.empty() && face_material.size() != triangles.size())
    return Error{ErrorCode::kInvalid, "surface: face_material has " + std::to_string(face_material.size()) + " entries, expected " +
                                          std::to_string(triangles.size()) + " (one per triangle)"};
  for (std::size_t i = 0; i < positions.size(); ++i)
    if (!is_finite(to_vec3(positions[i]))) return Error{ErrorCode::kInvalid, "surface: vertex " + std::to_string(i) + " is not finite"};
  if (!(params.deform_sigma > 0) || !(params.relax_tau > 0) || !(params.snap_limit > 0 && params.snap_limit <= 0.5) ||
      !(params.open_limit >= 0) || !(params.wrinkle_tau > 0) || !(params.wrinkle_decay > 0) || !(params.wrinkle_wavelength > 0))
    return Error{ErrorCode::kInvalid, "surface: parameters out of range (sigma, taus, decay, wavelength > 0; 0 < snap_limit <= 0.5; open_limit >= 0)"};
  for (std::size_t f = 0; f < triangles.size(); ++f)
    for (const std::uint32_t v : triangles[f])
      if (v >= positions.size())
        return Error{ErrorCode::kInvalid, "surface: triangle " + std::to_string(f) + " names a vertex past the " + std::to_string(positions.size()) +
                                              " given"};
  std::unique_ptr<SurfaceModel> m(new SurfaceModel());
  m->params_ = params;
  // The face arrays, the BVH, the per-vertex arrays and the rest face crosses need only the
  // positions and the triangles as given (the mesh's points are the same numbers), so they are
  // made on a thread of their own while this one builds the half-edge mesh; the jthread joins
  // once the mesh's connectivity is made, and before any return (so before m could be destroyed).
  // (Arrays handed over are moved: their elements stay where the spans see them.)
  std::jthread helper([&] {
    static_assert(sizeof(Vec3f) == 3 * sizeof(float));
    if (own_triangles != nullptr)
      m->faces_ = std::move(*own_triangles);
    else
      m->faces_.assign(triangles.begin(), triangles.end());
    if (own_material != nullptr && !face_material.empty()) {
      m->material_ = std::move(*own_material);
    } else {
      m->material_.assign(triangles.size(), 0);
      if (!face_material.empty()) m->material_.assign(face_material.begin(), face_material.end());
    }
    m->handle_.resize(triangles.size());
    m->bvh_.build(MeshView{positions.empty() ? nullptr : &positions.front().x, positions.size(), triangles});
    const std::size_t nv = positions.size();
    // Headroom for the copies cuts add, so a cut step never regrows a whole per-vertex array.
    for (auto* a : {&m->deform_, &m->open_, &m->wrinkle_}) a->reserve(nv * 5 / 4 + 64);
    m->haptic_.reserve(nv * 5 / 4 + 64);
    m->in_deformed_.reserve(nv * 5 / 4 + 64);
    m->deform_.resize(nv);  // zeros, not written (ZeroedVector)
    m->open_.resize(nv);
    m->wrinkle_.resize(nv);
    m->in_deformed_.resize(nv);
    for (std::size_t i = 0; i < nv; ++i) m->haptic_.emplace_back(positions[i].x, positions[i].y, positions[i].z);  // = rest
    m->mark_.resize(std::max(nv * 5 / 4 + 64, triangles.size()));
    // Each face's rest cross (b − a) × (c − a), as face_cross(f, true) forms it from the same
    // numbers (the rest positions are the given ones).
    m->rest_normal_.reserve(triangles.size());  // written once each (no zeros first)
    for (const auto& t : triangles) {
      const auto at = [&](std::uint32_t v) { return P(positions[v].x, positions[v].y, positions[v].z); };
      const P a = at(t[0]);
      m->rest_normal_.push_back(OpenMesh::cross(at(t[1]) - a, at(t[2]) - a));
    }
  });
  SurfaceMesh& mesh = m->mesh_;
  mesh.add_property(m->rest_);
  mesh.add_property(m->stable_);
  mesh.reserve(positions.size() * 5 / 4, triangles.size() * 2, triangles.size() * 5 / 4);
  // All vertices at once (one resize of every vertex property, where add_vertex grows each by one).
  mesh.resize(positions.size(), 0, 0);
  P lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());  // for the texture coordinates
  for (std::size_t i = 0; i < positions.size(); ++i) {
    const P p(positions[i].x, positions[i].y, positions[i].z);
    mesh.set_point(vh(static_cast<std::uint32_t>(i)), p);
    mesh.property(m->rest_, vh(static_cast<std::uint32_t>(i))) = p;
    lo.minimize(p);
    hi.maximize(p);
  }
  // The connectivity at once (volume/halfedge_build.hpp); what is not a manifold goes face by face
  // below, where add_face names the first triangle that does not fit.
  std::vector<VH> handles(positions.size());
  for (std::size_t i = 0; i < positions.size(); ++i) handles[i] = VH(static_cast<int>(i));
  volume::TriangleCorners corners;  // for the normals below
  const bool built = volume::build_triangle_mesh(mesh, std::span<const VH>(handles), triangles, &m->on_boundary_, &corners);
  helper.join();
  if (built)
    volume::in_two_halves(triangles.size(), volume::worth_two_threads(triangles.size()), [&](std::size_t begin, std::size_t end, int) {
      for (std::size_t f = begin; f < end; ++f) {
        const FH fh(static_cast<int>(f));
        mesh.property(m->stable_, fh) = static_cast<std::uint32_t>(f);
        m->handle_[f] = fh;
      }
    });
  for (std::size_t f = 0; !built && f < triangles.size(); ++f) {
    const auto& t = triangles[f];
    const FH fh = mesh.add_face(vh(t[0]), vh(t[1]), vh(t[2]));
    if (!fh.is_valid())
      return Error{ErrorCode::kInvalid, "surface: triangle " + std::to_string(f) + " (" + std::to_string(t[0]) + ", " + std::to_string(t[1]) + ", " +
                                            std::to_string(t[2]) + ") makes the mesh non-manifold (or repeats a vertex)"};
    mesh.property(m->stable_, fh) = static_cast<std::uint32_t>(f);
    m->handle_[f] = fh;
  }
  const std::size_t nv = mesh.n_vertices();
  if (!built) {  // face by face above: the flags from the mesh
    m->on_boundary_.resize(triangles.size());
    for (std::size_t f = 0; f < triangles.size(); ++f) m->on_boundary_[f] = m->boundary_of(m->handle_[f]) ? 1 : 0;
  }
  // Texture-atlas coordinates: the rest positions projected along the bounding box's thinnest
  // axis onto [0, 1]². (One chart; enough for a skin patch. Duplicated vertices keep theirs.)
  const P ext = hi - lo;
  int thin = 0;
  for (int a = 1; a < 3; ++a)
    if (ext[a] < ext[thin]) thin = a;
  const int ua = (thin + 1) % 3, va = (thin + 2) % 3;
  volume::in_two_halves(nv, volume::worth_two_threads(nv), [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t i = begin; i < end; ++i) {
      const P& p = mesh.point(vh(static_cast<std::uint32_t>(i)));
      mesh.set_texcoord2D(vh(static_cast<std::uint32_t>(i)),
                          OpenMesh::Vec2f(ext[ua] > 0 ? (p[ua] - lo[ua]) / ext[ua] : 0.f, ext[va] > 0 ? (p[va] - lo[va]) / ext[va] : 0.f));
    }
  });
  // Normals: the rest crosses from the other thread (with the BVH and the per-vertex arrays).
  // (Current and rest positions are equal here, so a vertex's normal sums the faces' rest crosses
  // around it, in its one-ring's order: vertex_cross_sum without computing each cross thrice.
  // Each vertex and face is written by one thread only.)
  volume::in_two_halves(nv, volume::worth_two_threads(nv), [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t i = begin; i < end; ++i) {
      P n(0, 0, 0);
      const auto add = [&](std::uint32_t f) { n += m->rest_normal_[f]; };
      if (built)  // the same walk as vf_range, on the build's compact corner arrays
        corners.for_each_triangle_around(static_cast<std::uint32_t>(i), add);
      else
        for (auto f : mesh.vf_range(vh(static_cast<std::uint32_t>(i)))) add(m->stable_of(f));
      const float len = n.norm();
      mesh.set_normal(vh(static_cast<std::uint32_t>(i)), len > 0 ? n / len : P(0, 0, 1));
    }
  });
  volume::in_two_halves(triangles.size(), volume::worth_two_threads(triangles.size()), [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t f = begin; f < end; ++f) {
      P& n = m->rest_normal_[f];
      const float len = n.norm();
      n = len > 0 ? n / len : P(0, 0, 0);
    }
  });
  return m;
}

// (b − a) × (c − a) of stable face f, at current or rest positions: twice its area along its normal.
OpenMesh::Vec3f SurfaceModel::face_cross(std::uint32_t f, bool rest) const {
  const auto& t = faces_[f];
  const auto at = [&](std::uint32_t v) { return rest ? mesh_.property(rest_, vh(v)) : mesh_.point(vh(v)); };
  const P a = at(t[0]);
  return OpenMesh::cross(at(t[1]) - a, at(t[2]) - a);
}

// Σ face_cross over the faces around v (current positions): the area-weighted normal direction.
OpenMesh::Vec3f SurfaceModel::vertex_cross_sum(std::uint32_t v) const {
  P n(0, 0, 0);
  for (auto f : mesh_.vf_range(vh(v))) n += face_cross(stable_of(f), false);
  return n;
}

Vec3 SurfaceModel::position(std::uint32_t v) const noexcept { return v3(mesh_.point(vh(v))); }
Vec3 SurfaceModel::rest_position(std::uint32_t v) const noexcept { return v3(mesh_.property(rest_, vh(v))); }

MeshView SurfaceModel::view() const noexcept {
  return MeshView{mesh_.n_vertices() > 0 ? mesh_.points()[0].data() : nullptr, mesh_.n_vertices(), faces_};
}

std::uint32_t SurfaceModel::stable_of(FH fh) const { return mesh_.property(stable_, fh); }

void SurfaceModel::set_current(std::uint32_t v) {
  const VH h = vh(v);
  mesh_.set_point(h, mesh_.property(rest_, h) + deform_[v] + open_[v] + wrinkle_[v]);
  set_haptic(v);
}

void SurfaceModel::set_haptic(std::uint32_t v) { haptic_[v] = mesh_.property(rest_, vh(v)) + open_[v] + wrinkle_[v]; }

bool SurfaceModel::boundary_of(FH fh) const {
  for (auto h : mesh_.fh_range(fh))
    if (mesh_.is_boundary(mesh_.opposite_halfedge_handle(h))) return true;
  return false;
}

// After faces around v were reconnected: an edge whose boundary status changed has v at one end,
// so every face that can have gained or lost a boundary edge is one of v's.
void SurfaceModel::update_boundary_flags(std::uint32_t v) {
  for (auto f : mesh_.vf_range(vh(v))) on_boundary_[stable_of(f)] = boundary_of(f) ? 1 : 0;
}

// After vertices moved or faces were reconnected: refit their faces in the BVH and renormalise
// the vertices of those faces.
void SurfaceModel::refresh(std::span<const std::uint32_t> vertices) {
  if (!vertices.empty()) ++revision_;
  scratch_faces_.clear();
  for (std::uint32_t v : vertices)
    for (auto f : mesh_.vf_range(vh(v))) {
      const std::uint32_t s = stable_of(f);
      if (mark_[s] == 0) {
        mark_[s] = 1;
        scratch_faces_.push_back(s);
      }
    }
  for (std::uint32_t s : scratch_faces_) mark_[s] = 0;
  if (scratch_faces_.empty()) return;
  bvh_.refit_faces(view(), scratch_faces_);
  scratch_vertices_.clear();
  for (std::uint32_t s : scratch_faces_)
    for (std::uint32_t v : faces_[s])
      if (mark_[v] == 0) {
        mark_[v] = 1;
        scratch_vertices_.push_back(v);
      }
  for (std::uint32_t v : scratch_vertices_) {
    mark_[v] = 0;
    const P n = vertex_cross_sum(v);
    const float len = n.norm();
    if (len > 0) mesh_.set_normal(vh(v), n / len);
  }
}

std::optional<std::uint32_t> SurfaceModel::locate(Vec3 p, double max_distance, Vec3* on_surface) const {
  const auto hit = bvh_.closest_point(view(), to_vec3f(p), static_cast<float>(max_distance));
  if (!hit) return std::nullopt;
  if (on_surface != nullptr) *on_surface = to_vec3(hit->point);
  return hit->face;
}

// ---- deformation --------------------------------------------------------------------------------

void SurfaceModel::update_contact(const std::optional<Contact>& contact, double dt) {
  const float keep = static_cast<float>(std::exp(-std::max(dt, 0.0) / params_.relax_tau));
  scratch_touched_.clear();
  if (contact && is_finite(contact->point) && is_finite(contact->direction) && contact->depth > 0) {
    const double sigma = params_.deform_sigma, reach = 3 * sigma;
    const double depth = std::min(contact->depth, params_.deform_max_depth);
    const Vec3 dir = normalized(contact->direction);
    std::vector<std::uint32_t>& near = scratch_faces_;
    bvh_.faces_within(view(), to_vec3f(contact->point), static_cast<float>(reach + depth), near);
    for (std::uint32_t f : near)
      for (std::uint32_t v : faces_[f]) {
        if (mark_[v] != 0) continue;
        mark_[v] = 1;
        scratch_touched_.push_back(v);
      }
    for (std::uint32_t v : scratch_touched_) {
      mark_[v] = 0;
      // Distance measured without this dent, so the dent does not feed on itself.
      const Vec3 base = v3(mesh_.property(rest_, vh(v)) + open_[v] + wrinkle_[v]);
      const double r2 = dot(base - contact->point, base - contact->point);
      // The Gaussian, shifted and rescaled to reach zero at 3σ, so the dent has no step at its rim.
      const double rim = std::exp(-4.5);
      const double g = r2 < reach * reach ? (std::exp(-r2 / (2 * sigma * sigma)) - rim) / (1 - rim) : 0.0;
      deform_[v] = pf(dir * (depth * g));
      if (in_deformed_[v] == 0) {
        in_deformed_[v] = 1;
        deformed_.push_back(v);
      }
      in_deformed_[v] = 2;  // held by the contact this step
    }
  }
  // Everything else relaxes towards rest; vertices back at rest leave the working set.
  std::size_t out = 0;
  for (std::uint32_t v : deformed_) {
    if (in_deformed_[v] == 2) {
      in_deformed_[v] = 1;
      deformed_[out++] = v;
      continue;
    }
    deform_[v] *= keep;
    if (deform_[v].sqrnorm() < 1e-14f) {
      deform_[v] = P(0, 0, 0);
      in_deformed_[v] = 0;
    } else {
      deformed_[out++] = v;
    }
    scratch_touched_.push_back(v);
  }
  deformed_.resize(out);
  for (std::uint32_t v : scratch_touched_) set_current(v);
  refresh(scratch_touched_);  // refresh uses the other scratch vectors
}

// ---- cutting ------------------------------------------------------------------------------------

bool SurfaceModel::snap(std::uint32_t v, Vec3 target, CutStepResult& r) {
  const VH h = vh(v);
  const P from = mesh_.point(h);
  const P to = pf(target);
  // The largest share of the move (1, ½, ¼, ⅛) that keeps every face around v from flipping or
  // collapsing; none at all if even ⅛ fails.
  for (float share = 1.0f; share >= 0.125f; share *= 0.5f) {
    const P p = from + (to - from) * share;
    bool ok = true;
    for (auto f : mesh_.vf_range(h)) {
      const auto& t = faces_[stable_of(f)];
      P c[3];
      for (int i = 0; i < 3; ++i) c[i] = t[static_cast<std::size_t>(i)] == v ? p : mesh_.point(vh(t[static_cast<std::size_t>(i)]));
      P o[3];
      for (int i = 0; i < 3; ++i) o[i] = mesh_.point(vh(t[static_cast<std::size_t>(i)]));
      const P n_new = OpenMesh::cross(c[1] - c[0], c[2] - c[0]);
      const P n_old = OpenMesh::cross(o[1] - o[0], o[2] - o[0]);
      if (0.5 * static_cast<double>(n_new.norm()) <= 1e-3 * 0.5 * static_cast<double>(n_old.norm()) || OpenMesh::dot(n_new, n_old) <= 0) {
        ok = false;
        break;
      }
    }
    if (!ok) continue;
    if (share < 1.0f) ++r.snaps_limited;
    const P delta = p - from;
    mesh_.property(rest_, h) += delta;
    set_current(v);
    const std::uint32_t one[1] = {v};
    refresh(one);
    for (auto f : mesh_.vf_range(h)) {
      const P n = face_cross(stable_of(f), true);
      const float len = n.norm();
      if (len > 0) rest_normal_[stable_of(f)] = n / len;
    }
    ++r.snapped;
    return true;
  }
  ++r.snaps_limited;
  return false;
}

bool SurfaceModel::duplicate(Cut& cut, std::size_t k, CutStepResult& r) {
  const std::uint32_t v = cut.chain[k], u = cut.chain[k - 1], w = cut.chain[k + 1];
  const VH hv = vh(v);
  const HH start = mesh_.find_halfedge(hv, vh(w));
  if (!start.is_valid()) return false;
  // Left of the path u → v → w: the faces swept counter-clockwise from v→w until v→u (or a
  // boundary). Everything else around v is on the right and moves to the copy.
  scratch_faces_.clear();
  HH cur = start;
  for (int guard = 0; guard < 256; ++guard) {
    const FH f = mesh_.face_handle(cur);
    if (!f.is_valid()) break;
    scratch_faces_.push_back(stable_of(f));
    cur = mesh_.ccw_rotated_halfedge_handle(cur);
    if (mesh_.to_vertex_handle(cur) == vh(u) || cur == start) break;
  }
  std::vector<std::uint32_t> right;
  for (auto f : mesh_.vf_range(hv)) {
    const std::uint32_t s = stable_of(f);
    if (std::find(scratch_faces_.begin(), scratch_faces_.end(), s) == scratch_faces_.end()) right.push_back(s);
  }
  if (right.empty() || scratch_faces_.empty()) return false;  // nothing to split here
  // The opening direction, from the path and the vertex normal.
  const Vec3 v_tool = normalized(position(w) - position(u));
  const Vec3 v_sn = v3(mesh_.normal(hv));
  const Vec3 v_co = normalized(cross(v_tool, v_sn));
  const std::uint32_t c = new_copy(v);
  if (!reattach(right, v, c)) {
    ++r.refused;
    mesh_.delete_vertex(vh(c), false);
    return false;
  }
  r.faces_reconnected += right.size();
  ++r.duplicated;
  cut.pairs.push_back(Cut::Pair{v, c, rest_position(v), rest_position(c), v_co});
  // The cut opens by its current width at once (±D/2 · V_co, no taper while it grows).
  const P off = pf(v_co * (cut.opening / 2));
  open_[v] = open_[v] - off;
  open_[c] = open_[c] + off;
  set_current(v);
  set_current(c);
  const std::uint32_t both[2] = {v, c};
  refresh(both);
  // Where the path meets an earlier cut or the border, a vertex can be left with two separate
  // fans (joined only at the vertex): each fan then gets its own vertex, so the mesh stays
  // manifold and the cuts join.
  for (std::uint32_t x : {u, v, c, w}) r.duplicated += split_fans(x);
  return true;
}

std::uint32_t SurfaceModel::new_copy(std::uint32_t v) {
  const VH hv = vh(v);
  const VH copy = mesh_.add_vertex(mesh_.point(hv));
  const std::uint32_t c = idx(copy);
  mesh_.property(rest_, copy) = mesh_.property(rest_, hv);
  mesh_.set_texcoord2D(copy, mesh_.texcoord2D(hv));
  mesh_.set_normal(copy, mesh_.normal(hv));
  deform_.push_back(deform_[v]);
  open_.push_back(open_[v]);
  wrinkle_.push_back(wrinkle_[v]);
  haptic_.push_back(OpenMesh::Vec3f(haptic_[v]));
  in_deformed_.push_back(0);
  if (mark_.size() < mesh_.n_vertices()) mark_.resize(mesh_.n_vertices() * 2, 0);
  if (in_deformed_[v] != 0) {
    in_deformed_[c] = 1;
    deformed_.push_back(c);
  }
  return c;
}

// Moves faces (stable ids) from vertex `from` to vertex `to`: delete them all, then add them back
// with `to`. On a refusal everything is put back and false returned.
bool SurfaceModel::reattach(const std::vector<std::uint32_t>& faces, std::uint32_t from, std::uint32_t to) {
  std::vector<std::array<std::uint32_t, 3>> old_tris;
  old_tris.reserve(faces.size());
  for (std::uint32_t s : faces) {
    old_tris.push_back(faces_[s]);
    mesh_.delete_face(handle_[s], false);
  }
  std::size_t added = 0;
  for (; added < faces.size(); ++added) {
    auto t = old_tris[added];
    for (auto& x : t)
      if (x == from) x = to;
    const FH fh = mesh_.add_face(vh(t[0]), vh(t[1]), vh(t[2]));
    if (!fh.is_valid()) break;
    mesh_.property(stable_, fh) = faces[added];
    handle_[faces[added]] = fh;
    faces_[faces[added]] = t;
  }
  if (added == faces.size()) {
    update_boundary_flags(from);
    update_boundary_flags(to);
    return true;
  }
  for (std::size_t i = 0; i < added; ++i) mesh_.delete_face(handle_[faces[i]], false);
  for (std::size_t i = 0; i < faces.size(); ++i) {
    const auto& t = old_tris[i];
    const FH fh = mesh_.add_face(vh(t[0]), vh(t[1]), vh(t[2]));
    mesh_.property(stable_, fh) = faces[i];
    handle_[faces[i]] = fh;
    faces_[faces[i]] = t;
  }
  update_boundary_flags(from);
  update_boundary_flags(to);
  return false;
}

std::size_t SurfaceModel::split_fans(std::uint32_t v) {
  std::size_t made = 0;
  for (int guard = 0; guard < 16; ++guard) {
    // Outgoing boundary halfedges of v: one per fan of a boundary vertex.
    HH first, second;
    for (auto h : mesh_.voh_range(vh(v)))
      if (mesh_.is_boundary(h)) {
        if (!first.is_valid()) first = h;
        else if (!second.is_valid()) second = h;
      }
    if (!second.is_valid()) return made;  // one fan (or none): manifold
    // The fan that begins at the second boundary halfedge moves to a new vertex.
    std::vector<std::uint32_t> fan;
    HH cur = second;
    for (int n = 0; n < 256; ++n) {
      const HH o = mesh_.opposite_halfedge_handle(cur);
      const FH f = mesh_.face_handle(o);
      if (!f.is_valid()) break;
      fan.push_back(stable_of(f));
      cur = mesh_.next_halfedge_handle(o);
      if (cur == second) break;
    }
    if (fan.empty()) return made;
    const std::uint32_t c = new_copy(v);
    if (!reattach(fan, v, c)) {
      mesh_.delete_vertex(vh(c), false);
      return made;
    }
    const std::uint32_t both[2] = {v, c};
    refresh(both);
    ++made;
  }
  return made;
}

bool SurfaceModel::begin_cut(Vec3 p, double max_distance) {
  if (cutting()) end_cut();
  Vec3 q;
  const auto f = locate(p, max_distance, &q);
  if (!f) return false;
  // The face's vertex nearest the entry point starts the chain, snapped onto it.
  std::uint32_t best = faces_[*f][0];
  for (std::uint32_t v : faces_[*f])
    if (norm(position(v) - q) < norm(position(best) - q)) best = v;
  CutStepResult r;
  snap(best, q, r);
  Cut cut;
  cut.chain.push_back(best);
  cut.path.push_back(q);
  cut.opening = params_.open_rest;
  cut.active = true;
  cuts_.push_back(std::move(cut));
  return true;
}

void SurfaceModel::end_cut() {
  if (!cutting()) return;
  cuts_.back().active = false;
  (void)split_fans(cuts_.back().chain.back());
}

CutStepResult SurfaceModel::cut_to(Vec3 target) {
  CutStepResult r;
  if (!cutting() || !is_finite(target)) return r;
  // The blade's tip is under the skin, often millimetres deep: cut towards the surface point over
  // it. (Walking towards the deep point itself, its depth projected onto a sloping face outweighs
  // a small step along the surface, and the cut runs downhill or stalls.)
  Vec3 on_surface;
  if (locate(target, kCutReach, &on_surface)) target = on_surface;
  Cut& cut = cuts_.back();
  cut.path.push_back(target);

  // A crossing of edge (a, b) at share s from a: the nearer endpoint (else the other) joins the
  // chain, snapped onto the crossing, if it is adjacent to the tip and not in the chain yet.
  const auto on_crossing = [&](std::uint32_t a, std::uint32_t b, double s, Vec3 x) -> bool {
    ++r.crossings;
    const std::uint32_t tip = cut.chain.back();
    const std::uint32_t order[2] = {s < 0.5 ? a : b, s < 0.5 ? b : a};
    for (std::uint32_t cand : order) {
      if (cand == tip) return false;
      if (std::find(cut.chain.begin(), cut.chain.end(), cand) != cut.chain.end()) continue;
      if (!mesh_.find_halfedge(vh(tip), vh(cand)).is_valid()) continue;
      snap(cand, x, r);
      cut.chain.push_back(cand);
      if (cut.chain.size() >= 3) duplicate(cut, cut.chain.size() - 2, r);
      return true;
    }
    return false;
  };

  // Walk the surface from the tip towards the target, face by face, in each face's plane.
  enum class At { kVertex, kFace };
  At at = At::kVertex;
  std::uint32_t at_vertex = cut.chain.back();
  FH face;
  std::uint32_t entry_a = 0, entry_b = 0;  // the edge the walk entered face through
  Vec3 x = position(at_vertex);
  for (int step = 0; step < kMaxWalkSteps; ++step) {
    if (at == At::kVertex) {
      x = position(at_vertex);
      // The face around the vertex whose wedge holds the direction to the target.
      FH best;
      double best_margin = -1;
      for (auto f : mesh_.vf_range(vh(at_vertex))) {
        const auto& t = faces_[stable_of(f)];
        int i = 0;
        while (t[static_cast<std::size_t>(i)] != at_vertex) ++i;
        const Vec3 a = position(t[static_cast<std::size_t>((i + 1) % 3)]) - x, b = position(t[static_cast<std::size_t>((i + 2) % 3)]) - x;
        const Vec3 n = normalized(cross(a, b));
        Vec3 d = target - x;
        d = d - n * dot(d, n);
        if (norm(d) < 1e-9) return r;  // at the target
        const double m1 = dot(cross(a, d), n) / (norm(a) * norm(d)), m2 = dot(cross(d, b), n) / (norm(b) * norm(d));
        const double margin = std::min(m1, m2);
        if (margin > best_margin) {
          best_margin = margin;
          best = f;
        }
      }
      if (!best.is_valid() || best_margin < -1e-6) {  // the direction leaves the mesh here
        r.hit_boundary = true;
        return r;
      }
      const auto& t = faces_[stable_of(best)];
      int i = 0;
      while (t[static_cast<std::size_t>(i)] != at_vertex) ++i;
      face = best;
      entry_a = t[static_cast<std::size_t>((i + 2) % 3)];  // "entered" through the two edges at the vertex:
      entry_b = at_vertex;                                 // exits are sought on the opposite edge only
    }
    // In face: exit through an edge other than the entry, unless the target comes first.
    const auto& t = faces_[stable_of(face)];
    const Vec3 c0 = position(t[0]), c1 = position(t[1]), c2 = position(t[2]);
    const Vec3 n = normalized(cross(c1 - c0, c2 - c0));
    Vec3 d = target - x;
    d = d - n * dot(d, n);
    if (norm(d) < 1e-9) return r;
    double best_s = std::numeric_limits<double>::infinity(), best_u = 0;
    std::uint32_t ea = 0, eb = 0;
    for (int e = 0; e < 3; ++e) {
      const std::uint32_t a = t[static_cast<std::size_t>(e)], b = t[static_cast<std::size_t>((e + 1) % 3)];
      if (at == At::kVertex ? (a == at_vertex || b == at_vertex) : ((a == entry_a && b == entry_b) || (a == entry_b && b == entry_a))) continue;
      const Vec3 pa = position(a), edge = position(b) - pa;
      const double den = dot(cross(d, edge), n);
      if (std::abs(den) < 1e-18) continue;
      const double s = dot(cross(pa - x, edge), n) / den;
      const double u = dot(cross(pa - x, d), n) / den;
      if (s > 1e-9 && u >= -1e-9 && u <= 1 + 1e-9 && s < best_s) {
        best_s = s;
        best_u = std::clamp(u, 0.0, 1.0);
        ea = a;
        eb = b;
      }
    }
    if (!std::isfinite(best_s) || best_s >= 1.0) return r;  // the target lies in this face
    const Vec3 cross_point = position(ea) + (position(eb) - position(ea)) * best_u;
    const HH across = mesh_.find_halfedge(vh(eb), vh(ea));  // the neighbour's halfedge of this edge
    if (on_crossing(ea, eb, best_u, cross_point)) {
      at = At::kVertex;
      at_vertex = cut.chain.back();
      continue;
    }
    if (!across.is_valid() || !mesh_.face_handle(across).is_valid()) {
      r.hit_boundary = true;
      return r;
    }
    at = At::kFace;
    face = mesh_.face_handle(across);
    entry_a = ea;
    entry_b = eb;
    x = cross_point;
  }
  return r;
}

// ---- opening and wrinkle ------------------------------------------------------------------------

void SurfaceModel::apply_opening(Cut& cut) {
  const std::size_t n = cut.pairs.size();
  scratch_touched_.clear();
  // The skin beside the cut follows its edge, less with distance (a quadratic falloff over
  // open_spread), so that opening wider than a triangle does not fold the triangles next to it.
  for (std::uint32_t v : cut.spread) {
    open_[v] = P(0, 0, 0);
    scratch_touched_.push_back(v);
  }
  cut.spread.clear();
  const double spread = params_.open_spread;
  if (cut.spread_map_pairs != n) build_spread_map(cut);
  const auto taper = [n](std::size_t i) {  // a lens: widest in the middle, closed at S and E
    return std::sin(std::numbers::pi * static_cast<double>(i + 1) / static_cast<double>(n + 1));
  };
  if (cut.opening > 0 && spread > 0)
    for (const auto& e : cut.spread_map) {
      const auto& pr = cut.pairs[e.pair];
      open_[e.vertex] = pf(pr.v_co * (e.side_fall * cut.opening / 2 * taper(e.pair)));
      cut.spread.push_back(e.vertex);
      scratch_touched_.push_back(e.vertex);
    }
  for (std::size_t i = 0; i < n; ++i) {
    const auto& pr = cut.pairs[i];
    const P off = pf(pr.v_co * (cut.opening / 2 * taper(i)));
    open_[pr.left] = -off;
    open_[pr.right] = off;
    scratch_touched_.push_back(pr.left);
    scratch_touched_.push_back(pr.right);
  }
  for (std::uint32_t v : scratch_touched_) set_current(v);
  refresh(scratch_touched_);
}

// The vertices of every face within r (now) of one of the cut's pairs' left vertices, unmarked
// ones only, each marked 1 and appended to `out` (cleared first) in face order: one walk of the
// tree for all pairs (their spheres overlap almost entirely) rather than one a pair.
void SurfaceModel::gather_around_pairs(const Cut& cut, float r, std::vector<std::uint32_t>& out) {
  out.clear();
  scratch_points_.clear();
  for (const auto& pr : cut.pairs) scratch_points_.push_back(to_vec3f(position(pr.left)));
  bvh_.faces_within_any(view(), scratch_points_, r, scratch_faces_, scratch_indices_);
  for (std::uint32_t f : scratch_faces_)
    for (std::uint32_t v : faces_[f])
      if (mark_[v] == 0) {
        mark_[v] = 1;
        out.push_back(v);
      }
}

// Every vertex within open_spread (at rest) of the cut's pairs, with its nearest pair and signed
// falloff. Gathered through the BVH around the pairs' current positions with room for the widest
// opening, so it does not depend on how open the cut is now.
void SurfaceModel::build_spread_map(Cut& cut) {
  const std::size_t n = cut.pairs.size();
  cut.spread_map.clear();
  cut.spread_map_pairs = n;
  const double spread = params_.open_spread;
  if (n == 0 || !(spread > 0)) return;
  for (const auto& pr : cut.pairs) mark_[pr.left] = mark_[pr.right] = 2;  // the pairs themselves move in full
  gather_around_pairs(cut, static_cast<float>(spread + params_.open_limit), scratch_vertices_);
  for (std::uint32_t v : scratch_vertices_) {
    mark_[v] = 0;
    const Vec3 p = rest_position(v);
    std::size_t best = 0;
    double d2 = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < n; ++i) {
      const double e = dot(p - cut.pairs[i].rest_left, p - cut.pairs[i].rest_left);
      if (e < d2) {
        d2 = e;
        best = i;
      }
    }
    const double d = std::sqrt(d2);
    if (!(d < spread)) continue;
    const auto& pr = cut.pairs[best];
    const double side = dot(p - pr.rest_left, pr.v_co) >= 0 ? 1.0 : -1.0;
    cut.spread_map.push_back({v, static_cast<std::uint32_t>(best), static_cast<float>(side * (1 - d / spread) * (1 - d / spread))});
  }
  for (const auto& pr : cut.pairs) mark_[pr.left] = mark_[pr.right] = 0;
}

double SurfaceModel::set_opening(std::size_t c, double width) {
  if (c >= cuts_.size() || !std::isfinite(width)) return 0;
  cuts_[c].opening = std::clamp(width, 0.0, params_.open_limit);
  apply_opening(cuts_[c]);
  return cuts_[c].opening;
}

double SurfaceModel::pull(std::size_t c, double displacement) {
  if (c >= cuts_.size() || !std::isfinite(displacement)) return 0;
  const double width = set_opening(c, displacement);
  // The wrinkle: skin beside the cut buckles along its normal. Where, and its profile, follow
  // from the cut's rest geometry alone: built once per cut, pair count and vertex count (kept
  // while the wrinkle dies away between pulls), then each pull only rescales it.
  if (wrinkle_cut_ != c || wrinkle_pairs_ != cuts_[c].pairs.size() || wrinkle_vertices_ != mesh_.n_vertices())
    build_wrinkle_map(c);
  wrinkle_level_ = 0.25 * width;
  wrinkle_live_ = true;
  relax(0);
  return width;
}

// The skin beside cut c that buckles when it is pulled, and each vertex's profile: oscillating
// with the distance from the cut and decaying away from it.
void SurfaceModel::build_wrinkle_map(std::size_t c) {
  const Cut& cut = cuts_[c];
  wrinkle_cut_ = c;
  wrinkle_pairs_ = cut.pairs.size();
  wrinkle_vertices_ = mesh_.n_vertices();
  for (std::uint32_t v : wrinkled_) wrinkle_[v] = P(0, 0, 0), set_haptic(v);
  wrinkled_.clear();
  wrinkle_amp_.clear();
  gather_around_pairs(cut, static_cast<float>(params_.wrinkle_reach), scratch_touched_);
  for (std::uint32_t v : scratch_touched_) {
    mark_[v] = 0;
    double dmin = std::numeric_limits<double>::infinity();
    for (std::uint32_t cv : cut.chain) dmin = std::min(dmin, norm(rest_position(v) - rest_position(cv)));
    for (const auto& pr : cut.pairs) dmin = std::min(dmin, norm(rest_position(v) - pr.rest_right));
    if (dmin > params_.wrinkle_reach) continue;
    const double profile = std::exp(-dmin / params_.wrinkle_decay) * std::sin(2 * std::numbers::pi * dmin / params_.wrinkle_wavelength);
    wrinkled_.push_back(v);
    wrinkle_amp_.push_back(static_cast<float>(profile));
  }
}

void SurfaceModel::relax(double dt) {
  if (!wrinkle_live_ || wrinkled_.empty()) return;
  wrinkle_level_ *= std::exp(-std::max(dt, 0.0) / params_.wrinkle_tau);
  const bool gone = wrinkle_level_ < 1e-7;
  if (gone) wrinkle_level_ = 0;
  for (std::size_t i = 0; i < wrinkled_.size(); ++i) {
    const std::uint32_t v = wrinkled_[i];
    wrinkle_[v] = mesh_.normal(vh(v)) * static_cast<float>(wrinkle_level_ * wrinkle_amp_[i]);
    set_current(v);
  }
  refresh(wrinkled_);
  if (gone) wrinkle_live_ = false;  // flat again; the map stays for the next pull
}

void SurfaceModel::to_triangle_mesh(TriangleMesh& out) const {
  const std::size_t nv = mesh_.n_vertices();
  out.vertices.resize(nv);
  out.normals.resize(nv);
  for (std::size_t v = 0; v < nv; ++v) {
    const P& p = mesh_.point(vh(static_cast<std::uint32_t>(v)));
    const P& n = mesh_.normal(vh(static_cast<std::uint32_t>(v)));
    out.vertices[v] = Vec3f{p[0], p[1], p[2]};
    out.normals[v] = Vec3f{n[0], n[1], n[2]};
  }
  out.triangles.assign(faces_.begin(), faces_.end());
  out.material.assign(material_.begin(), material_.end());
}

// ---- checks -------------------------------------------------------------------------------------

SurfaceStats SurfaceModel::stats() const {
  SurfaceStats s;
  s.faces = faces_.size();
  for (auto v : mesh_.vertices()) {
    if (mesh_.is_isolated(v)) continue;
    ++s.vertices;
    if (!mesh_.is_manifold(v)) ++s.non_manifold_vertices;
  }
  for (auto e : mesh_.edges())
    if (mesh_.is_boundary(e)) ++s.boundary_edges;
  for (std::size_t f = 0; f < faces_.size(); ++f) {
    const auto& t = faces_[f];
    const P n = face_cross(static_cast<std::uint32_t>(f), false);
    const double area = 0.5 * static_cast<double>(n.norm());
    s.area += area;
    s.rest_area += 0.5 * static_cast<double>(face_cross(static_cast<std::uint32_t>(f), true).norm());
    if (!(area > kMinArea) || t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) ++s.degenerate_faces;
    if (OpenMesh::dot(n, rest_normal_[f]) <= 0) ++s.flipped_faces;
  }
  for (std::uint32_t v = 0; v < mesh_.n_vertices(); ++v) {
    const P h = mesh_.property(rest_, vh(v)) + open_[v] + wrinkle_[v];
    if (std::memcmp(&h, &haptic_[v], sizeof h) != 0) ++s.stale_haptic;
  }
  for (std::size_t f = 0; f < faces_.size(); ++f)
    if ((on_boundary_[f] != 0) != boundary_of(handle_[f])) ++s.stale_boundary_flags;
  // Boundary loops: follow next_halfedge from each unvisited boundary halfedge.
  std::vector<std::uint8_t> seen(mesh_.n_halfedges(), 0);
  for (auto h : mesh_.halfedges()) {
    if (!mesh_.is_boundary(h) || seen[static_cast<std::size_t>(h.idx())] != 0) continue;
    ++s.boundary_loops;
    HH cur = h;
    std::size_t guard = 0;
    do {
      seen[static_cast<std::size_t>(cur.idx())] = 1;
      cur = mesh_.next_halfedge_handle(cur);
      if (++guard > mesh_.n_halfedges() || !mesh_.is_boundary(cur)) {
        s.boundary_loops_closed = false;
        break;
      }
    } while (cur != h);
  }
  return s;
}

}  // namespace lancet::surface
