#pragma once
// The indexed triangle mesh every surface of the visualizer is handed around as (isosurfaces, the
// skin, the bone, what the renderer draws), and the procedural tissue block: a regular
// triangulated height field over a square with outward (+z-ish) normals, the scene without a CT.
// Allocating; not for the RT path.

#include <array>
#include <cstdint>
#include <vector>

#include "lancet/shared_model/geometry.hpp"

namespace lancet::surface {

/// Indexed triangle mesh. Shapes: vertices #V, normals #V, triangles #F (counter-clockwise seen
/// from outside), material #F.
struct TriangleMesh {
  std::vector<Vec3f> vertices;                     ///< m
  std::vector<Vec3f> normals;                      ///< unit, per vertex
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::uint16_t> material;             ///< material id per triangle
};

struct TissueBlockParams {
  double half_extent = 0.08;   ///< m, the square spans [-h, h]²
  int cells = 80;              ///< grid cells per side (2 triangles each)
  double wave_amplitude = 0.003;  ///< m, height of the gentle undulation
  double wave_length = 0.03;      ///< m (the height is a·sin(x/L)·cos(y/L))
};

/// Height of the block's surface at (x, y), in m.
double tissue_block_height(const TissueBlockParams& p, double x, double y);

/// Builds the height-field surface. Material 1 (skin) everywhere except a band |y - 0.04| < 5 mm
/// of material 2 (a superficial vessel), so material ids are exercised end to end.
TriangleMesh make_tissue_block(const TissueBlockParams& p);

/// Recomputes area-weighted vertex normals.
void compute_vertex_normals(TriangleMesh& mesh);

}  // namespace lancet::surface
