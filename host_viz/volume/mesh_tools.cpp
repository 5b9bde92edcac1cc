#include "volume/mesh_tools.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <numeric>
#include <vector>

namespace lancet::volume {

namespace {

using P = OpenMesh::Vec3d;

P to_d(const IsoMesh::Point& p) { return P(p[0], p[1], p[2]); }

struct FileCloser {
  void operator()(std::FILE* f) const noexcept { std::fclose(f); }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

Error io_error(const std::string& path, const char* what) {
  return Error{ErrorCode::kSystem, path + ": " + what + ": " + std::strerror(errno)};
}

// File units per metre.
double metres_to(LengthUnit unit) { return unit == LengthUnit::kMetre ? 1.0 : 1000.0; }

// Output numbering of the live (not deleted) vertices; -1 for deleted ones.
std::vector<std::int64_t> live_vertex_numbers(const IsoMesh& mesh, std::size_t& count) {
  std::vector<std::int64_t> number(mesh.n_vertices(), -1);
  count = 0;
  for (auto v : mesh.vertices()) number[static_cast<std::size_t>(v.idx())] = static_cast<std::int64_t>(count++);
  return number;
}

}  // namespace

MeshStats mesh_stats(const IsoMesh& mesh) {
  MeshStats s;
  for (auto v : mesh.vertices()) {
    ++s.vertices;
    if (mesh.is_isolated(v)) ++s.isolated_vertices;
    else if (!mesh.is_manifold(v)) ++s.non_manifold_vertices;
  }
  for (auto e : mesh.edges()) {
    ++s.edges;
    if (mesh.is_boundary(e)) ++s.boundary_edges;
  }
  // Faces: area, signed volume (divergence theorem), degeneracy; components by union-find.
  std::vector<int> parent(mesh.n_faces());
  std::iota(parent.begin(), parent.end(), 0);
  const auto find = [&](int x) {
    while (parent[static_cast<std::size_t>(x)] != x) x = parent[static_cast<std::size_t>(x)] = parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(x)])];
    return x;
  };
  s.min_face_area = std::numeric_limits<double>::infinity();
  for (auto f : mesh.faces()) {
    ++s.faces;
    std::array<IsoMesh::VertexHandle, 3> vh;
    int n = 0;
    for (auto v : mesh.fv_range(f)) vh[static_cast<std::size_t>(n++)] = v;
    const P a = to_d(mesh.point(vh[0])), b = to_d(mesh.point(vh[1])), c = to_d(mesh.point(vh[2]));
    const P cr = OpenMesh::cross(b - a, c - a);
    const double area = 0.5 * cr.norm();
    s.area += area;
    s.volume += OpenMesh::dot(a, OpenMesh::cross(b, c)) / 6.0;
    s.min_face_area = std::min(s.min_face_area, area);
    if (!(area > 0) || vh[0] == vh[1] || vh[1] == vh[2] || vh[0] == vh[2]) ++s.degenerate_faces;
    for (auto g : mesh.ff_range(f)) {
      const int ra = find(f.idx()), rb = find(g.idx());
      if (ra != rb) parent[static_cast<std::size_t>(std::max(ra, rb))] = std::min(ra, rb);
    }
  }
  for (auto f : mesh.faces())
    if (find(f.idx()) == f.idx()) ++s.components;
  if (s.faces == 0) s.min_face_area = 0;
  s.euler = static_cast<long long>(s.vertices) - static_cast<long long>(s.edges) + static_cast<long long>(s.faces);
  return s;
}

const char* unit_name(LengthUnit unit) noexcept { return unit == LengthUnit::kMetre ? "m" : "mm"; }

Result<std::size_t> write_ply(const IsoMesh& mesh, const std::string& path, LengthUnit unit) {
  File f(std::fopen(path.c_str(), "wb"));
  if (!f) return io_error(path, "cannot open for writing");
  std::size_t nv = 0;
  const auto number = live_vertex_numbers(mesh, nv);
  std::size_t nf = 0;
  for ([[maybe_unused]] auto face : mesh.faces()) ++nf;
  const double scale = metres_to(unit);
  std::fprintf(f.get(),
               "ply\nformat binary_little_endian 1.0\ncomment Lancet isosurface\ncomment units %s\n"
               "element vertex %zu\nproperty float x\nproperty float y\nproperty float z\n"
               "property float nx\nproperty float ny\nproperty float nz\nproperty uchar material\n"
               "element face %zu\nproperty list uchar int vertex_indices\nend_header\n",
               unit_name(unit), nv, nf);
  std::vector<unsigned char> buf;
  buf.reserve(nv * 25 + nf * 13);
  const auto put = [&](const void* p, std::size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    buf.insert(buf.end(), b, b + n);
  };
  for (auto v : mesh.vertices()) {
    const auto& p = mesh.point(v);
    const auto& n = mesh.normal(v);
    const float xyz[6] = {static_cast<float>(p[0] * scale), static_cast<float>(p[1] * scale), static_cast<float>(p[2] * scale),
                          n[0], n[1], n[2]};
    put(xyz, sizeof xyz);
    const std::uint8_t m = mesh.material(v);
    put(&m, 1);
  }
  for (auto face : mesh.faces()) {
    const std::uint8_t three = 3;
    put(&three, 1);
    for (auto v : mesh.fv_range(face)) {
      const auto i = static_cast<std::int32_t>(number[static_cast<std::size_t>(v.idx())]);
      put(&i, sizeof i);
    }
  }
  if (std::fwrite(buf.data(), 1, buf.size(), f.get()) != buf.size()) return io_error(path, "write failed");
  if (std::fclose(f.release()) != 0) return io_error(path, "close failed");
  return nf;
}

Result<std::size_t> write_obj(const IsoMesh& mesh, const std::string& path, LengthUnit unit) {
  File f(std::fopen(path.c_str(), "w"));
  if (!f) return io_error(path, "cannot open for writing");
  std::size_t nv = 0;
  const auto number = live_vertex_numbers(mesh, nv);
  const double scale = metres_to(unit);
  std::fprintf(f.get(), "# Lancet isosurface; %zu vertices\n# units: %s\n", nv, unit_name(unit));
  for (auto v : mesh.vertices()) {
    const auto& p = mesh.point(v);
    // The float positions scaled in double, printed with a float's precision.
    std::fprintf(f.get(), "v %.9g %.9g %.9g\n", double(static_cast<float>(p[0] * scale)), double(static_cast<float>(p[1] * scale)),
                 double(static_cast<float>(p[2] * scale)));
  }
  for (auto v : mesh.vertices()) {
    const auto& n = mesh.normal(v);
    std::fprintf(f.get(), "vn %.6g %.6g %.6g\n", double(n[0]), double(n[1]), double(n[2]));
  }
  std::size_t nf = 0;
  for (auto face : mesh.faces()) {
    std::fputc('f', f.get());
    for (auto v : mesh.fv_range(face)) {
      const auto i = number[static_cast<std::size_t>(v.idx())] + 1;
      std::fprintf(f.get(), " %lld//%lld", static_cast<long long>(i), static_cast<long long>(i));
    }
    std::fputc('\n', f.get());
    ++nf;
  }
  if (std::ferror(f.get()) != 0) return io_error(path, "write failed");
  if (std::fclose(f.release()) != 0) return io_error(path, "close failed");
  return nf;
}

}  // namespace lancet::volume
