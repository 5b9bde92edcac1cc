#include "hybrid/phantom_skin.hpp"

#include <algorithm>

#include "volume/marching_cubes.hpp"

namespace lancet::hybrid {

surface::TriangleMesh phantom_skin(const volume::Phantom& phantom, VolumePlacement& placement) {
  volume::IsoOptions o;
  o.iso = -300;
  o.pad_border = true;
  o.pad_value = -1000;
  auto s = volume::extract_isosurface(phantom.volume, o, phantom.material);
  surface::TriangleMesh m;
  if (!s.ok()) return m;
  const auto& iso = s.value();
  float top = -1e9f;
  for (const auto& p : iso.positions) top = std::max(top, p.y);
  placement.axis = {2, 0, 1};  // world (x, y, z) = volume (z, x, y): a rotation, then down
  placement.sign = {1, 1, 1};
  placement.offset = {0, 0, -static_cast<double>(top)};
  const VolumePlacement turn{placement.axis, placement.sign, {}};
  for (std::size_t i = 0; i < iso.positions.size(); ++i) {
    m.vertices.push_back(to_vec3f(placement.to_world(to_vec3(iso.positions[i]))));
    m.normals.push_back(to_vec3f(turn.to_world(to_vec3(iso.normals[i]))));
  }
  m.triangles = iso.triangles;
  for (const auto& t : iso.triangles) m.material.push_back(iso.material[t[0]]);
  return m;
}

}  // namespace lancet::hybrid
