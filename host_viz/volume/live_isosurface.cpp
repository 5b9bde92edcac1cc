#include "volume/live_isosurface.hpp"

#include <algorithm>
#include <string>

#include "volume/detail/mc_core.hpp"

namespace lancet::volume {

namespace {

std::string dims_text(const std::array<int, 3>& d) {
  return std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x" + std::to_string(d[2]);
}

}  // namespace

Result<std::unique_ptr<LiveIsosurface>> LiveIsosurface::create(const Volume& volume, const IsoOptions& options,
                                                               std::span<const std::uint8_t> labels) {
  auto st = detail::prepare_field(volume, options, labels, true);
  if (!st.ok()) return st.error();
  std::unique_ptr<LiveIsosurface> live(new LiveIsosurface());
  live->options_ = options;
  live->geometry_.dims = volume.dims;
  live->geometry_.spacing = volume.spacing;
  live->geometry_.origin = volume.origin;
  live->geometry_.direction = volume.direction;
  live->storage_grid_ = st.value().grid;
  live->values_ = std::move(st.value().values);
  live->labels_ = std::move(st.value().labels);
  live->has_labels_ = !labels.empty();
  IsoSurface s;
  s.grid = live->storage_grid_;
  detail::FieldStorage view{live->storage_grid_, {}, {}};
  detail::McField f = detail::field_view(view, live->geometry_, live->options_, {});
  f.v = live->values_.data();
  f.labels = live->has_labels_ ? live->labels_.data() : nullptr;
  try {
    detail::extract_field(f, s, options.threads);
  } catch (const std::length_error& e) {
    return Error{ErrorCode::kInvalid, e.what()};
  }
  if (auto finite = detail::check_finite_vertices(s); !finite) return finite.error();
  live->refused_ = fill_openmesh(s, live->mesh_);
  // Headroom, so that drilling does not regrow OpenMesh's arrays (a copy of the whole mesh) or
  // rehash the edge map in the middle of an interaction.
  const auto& m = live->mesh_;
  live->mesh_.reserve(m.n_vertices() * 3 / 2 + 1024, m.n_edges() * 3 / 2 + 1024, m.n_faces() * 3 / 2 + 1024);
  live->vertex_of_edge_.reserve(s.positions.size() * 3 / 2 + 1024);
  for (auto v : live->mesh_.vertices()) live->vertex_of_edge_.emplace(live->mesh_.edge_key(v), v);
  return live;
}

Result<RegionUpdate> LiveIsosurface::update(const Volume& volume, VoxelBox dirty, std::span<const std::uint8_t> labels) {
  if (volume.dims != geometry_.dims || volume.data.size() != volume.voxel_count())
    return Error{ErrorCode::kMismatch, "live isosurface: volume is " + dims_text(volume.dims) + ", the surface was made from " + dims_text(geometry_.dims)};
  if (has_labels_ != !labels.empty() || (!labels.empty() && labels.size() != volume.voxel_count()))
    return Error{ErrorCode::kMismatch, "live isosurface: labels must be given exactly when they were at creation, one per voxel (" +
                                           std::to_string(volume.voxel_count()) + "), found " + std::to_string(labels.size())};
  for (int a = 0; a < 3; ++a) {
    dirty.lo[static_cast<std::size_t>(a)] = std::max(dirty.lo[static_cast<std::size_t>(a)], 0);
    dirty.hi[static_cast<std::size_t>(a)] = std::min(dirty.hi[static_cast<std::size_t>(a)], volume.dims[static_cast<std::size_t>(a)]);
  }
  RegionUpdate u;
  if (dirty.empty()) return u;

  const IsoGrid& g = storage_grid_;
  const int pad = g.pad;
  // Copy the changed voxels into the grid.
  for (int k = dirty.lo[2]; k < dirty.hi[2]; ++k)
    for (int j = dirty.lo[1]; j < dirty.hi[1]; ++j) {
      const std::size_t src = volume.index(dirty.lo[0], j, k), dst = g.node(dirty.lo[0] + pad, j + pad, k + pad);
      const auto n = static_cast<std::ptrdiff_t>(dirty.hi[0] - dirty.lo[0]);
      std::copy_n(volume.data.begin() + static_cast<std::ptrdiff_t>(src), n, values_.begin() + static_cast<std::ptrdiff_t>(dst));
      if (has_labels_) std::copy_n(labels.begin() + static_cast<std::ptrdiff_t>(src), n, labels_.begin() + static_cast<std::ptrdiff_t>(dst));
    }

  detail::FieldStorage view{g, {}, {}};
  detail::McField f = detail::field_view(view, geometry_, options_, {});
  f.v = values_.data();
  f.labels = has_labels_ ? labels_.data() : nullptr;

  // Changed nodes [nlo, nhi) in grid indices; the cubes touching them [clo, chi).
  std::array<int, 3> nlo{}, nhi{}, clo{}, chi{};
  for (std::size_t a = 0; a < 3; ++a) {
    nlo[a] = dirty.lo[a] + pad;
    nhi[a] = dirty.hi[a] + pad;
    clo[a] = std::max(nlo[a] - 1, 0);
    chi[a] = std::min(nhi[a], g.dims[a] - 1);
  }
  const auto in_cubes = [&](std::uint32_t cube) {
    const auto c = static_cast<std::uint64_t>(cube);
    const auto nx = static_cast<std::uint64_t>(g.dims[0]), ny = static_cast<std::uint64_t>(g.dims[1]);
    const auto i = static_cast<int>(c % nx), j = static_cast<int>((c / nx) % ny), k = static_cast<int>(c / (nx * ny));
    return i >= clo[0] && i < chi[0] && j >= clo[1] && j < chi[1] && k >= clo[2] && k < chi[2];
  };

  // 1. Delete the faces of those cubes, and the vertices they leave alone. Every edge of a cube in
  //    the range has its lower node in [clo, chi] (inclusive) and stays below chi along its axis.
  std::vector<IsoMesh::FaceHandle> doomed;
  for (int k = clo[2]; k <= chi[2]; ++k)
    for (int j = clo[1]; j <= chi[1]; ++j)
      for (int i = clo[0]; i <= chi[0]; ++i)
        for (int axis = 0; axis < 3; ++axis) {
          const int c[3] = {i, j, k};
          if (c[axis] >= chi[static_cast<std::size_t>(axis)]) continue;
          const auto it = vertex_of_edge_.find(g.edge_key(i, j, k, axis));
          if (it == vertex_of_edge_.end()) continue;
          const auto v = it->second;
          doomed.clear();
          for (auto fh : mesh_.vf_range(v))
            if (in_cubes(mesh_.cube(fh))) doomed.push_back(fh);
          for (auto fh : doomed) mesh_.delete_face(fh, false);
          u.faces_removed += doomed.size();
          if (mesh_.is_isolated(v)) {
            mesh_.delete_vertex(v, false);
            vertex_of_edge_.erase(it);
            ++u.vertices_removed;
          }
        }

  // 2. Triangulate the cubes anew, reusing the vertices on their boundary.
  const auto& table = mc_case_table();
  for (int k = clo[2]; k < chi[2]; ++k)
    for (int j = clo[1]; j < chi[1]; ++j)
      for (int i = clo[0]; i < chi[0]; ++i) {
        ++u.cubes;
        const McCase& cs = table[detail::cube_case(f, i, j, k)];
        if (cs.n_triangles == 0) continue;
        IsoMesh::VertexHandle ev[12];
        std::uint16_t have = 0;
        const auto vertex_for = [&](int e) {
          if ((have >> e & 1) != 0) return ev[e];
          const auto ce = detail::cube_edge(e);
          const int vi = i + ce.di, vj = j + ce.dj, vk = k + ce.dk;
          const std::uint64_t key = g.edge_key(vi, vj, vk, ce.axis);
          auto [it, fresh] = vertex_of_edge_.try_emplace(key);
          if (fresh) {
            const auto vx = detail::edge_vertex(f, vi, vj, vk, ce.axis);
            it->second = mesh_.add_vertex(IsoMesh::Point(vx.position.x, vx.position.y, vx.position.z));
            mesh_.set_normal(it->second, IsoMesh::Normal(vx.normal.x, vx.normal.y, vx.normal.z));
            mesh_.set_material(it->second, vx.material);
            mesh_.set_edge_key(it->second, key);
            ++u.vertices_added;
          } else {
            ++u.vertices_reused;
          }
          have = static_cast<std::uint16_t>(have | 1u << e);
          return ev[e] = it->second;
        };
        const std::uint32_t cube = g.cube(i, j, k);
        for (int t = 0; t < cs.n_triangles; ++t) {
          const auto a = vertex_for(cs.edges[static_cast<std::size_t>(3 * t)]);
          const auto b = vertex_for(cs.edges[static_cast<std::size_t>(3 * t + 1)]);
          const auto c = vertex_for(cs.edges[static_cast<std::size_t>(3 * t + 2)]);
          const auto fh = f.flip ? mesh_.add_face(a, c, b) : mesh_.add_face(a, b, c);
          if (!fh.is_valid()) {
            ++u.refused;
            continue;
          }
          mesh_.set_cube(fh, cube);
          ++u.faces_added;
        }
      }

  // 3. Normals read the gradient at both nodes of their edge, which reads one node further: every
  //    vertex on an edge with a node within one of a changed node.
  if (options_.normals)
    for (int k = std::max(nlo[2] - 2, 0); k <= std::min(nhi[2] + 1, g.dims[2] - 1); ++k)
      for (int j = std::max(nlo[1] - 2, 0); j <= std::min(nhi[1] + 1, g.dims[1] - 1); ++j)
        for (int i = std::max(nlo[0] - 2, 0); i <= std::min(nhi[0] + 1, g.dims[0] - 1); ++i)
          for (int axis = 0; axis < 3; ++axis) {
            const auto it = vertex_of_edge_.find(g.edge_key(i, j, k, axis));
            if (it == vertex_of_edge_.end()) continue;
            const auto vx = detail::edge_vertex(f, i, j, k, axis);
            mesh_.set_normal(it->second, IsoMesh::Normal(vx.normal.x, vx.normal.y, vx.normal.z));
          }
  deleted_faces_ += u.faces_removed;
  return u;
}

void LiveIsosurface::compact() {
  mesh_.garbage_collection();
  vertex_of_edge_.clear();
  for (auto v : mesh_.vertices()) vertex_of_edge_.emplace(mesh_.edge_key(v), v);
  deleted_faces_ = 0;
}

}  // namespace lancet::volume
