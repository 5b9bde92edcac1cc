#include "surface/triangle_mesh.hpp"

#include <cmath>

namespace lancet::surface {

double tissue_block_height(const TissueBlockParams& p, double x, double y) {
  return p.wave_amplitude * std::sin(x / p.wave_length) * std::cos(y / p.wave_length);
}

TriangleMesh make_tissue_block(const TissueBlockParams& p) {
  TriangleMesh m;
  const int n = p.cells;
  const double step = 2.0 * p.half_extent / n;
  m.vertices.reserve(static_cast<std::size_t>((n + 1) * (n + 1)));
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const double x = -p.half_extent + i * step, y = -p.half_extent + j * step;
      m.vertices.push_back(to_vec3f({x, y, tissue_block_height(p, x, y)}));
    }
  }
  const auto idx = [n](int i, int j) { return static_cast<std::uint32_t>(j * (n + 1) + i); };
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      // Counter-clockwise seen from +z.
      m.triangles.push_back({idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)});
      m.triangles.push_back({idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)});
      const double yc = -p.half_extent + (j + 0.5) * step;
      const std::uint16_t mat = std::abs(yc - 0.04) < 0.005 ? 2 : 1;
      m.material.push_back(mat);
      m.material.push_back(mat);
    }
  }
  compute_vertex_normals(m);
  return m;
}

void compute_vertex_normals(TriangleMesh& mesh) {
  std::vector<Vec3> acc(mesh.vertices.size());
  for (const auto& t : mesh.triangles) {
    const Vec3 a = to_vec3(mesh.vertices[t[0]]), b = to_vec3(mesh.vertices[t[1]]), c = to_vec3(mesh.vertices[t[2]]);
    const Vec3 n = cross(b - a, c - a);  // length = 2·area: area weighting
    for (auto v : t) acc[v] += n;
  }
  mesh.normals.resize(mesh.vertices.size());
  for (std::size_t i = 0; i < acc.size(); ++i) mesh.normals[i] = to_vec3f(normalized(acc[i]));
}

}  // namespace lancet::surface
