#pragma once
// A sheet of tissue for tests and benchmarks: nx × ny rectangular cells appended to a TissuePatch,
// two triangles a cell, counter-clockwise seen from +z (outward up), ids the triangle's index plus
// id_base. The corner of grid point (x, y) is corner(x, y) (a height, a shift), so a flat plane,
// a wavy sheet and a moved copy of either come from one loop. No gtest: benchmarks use it too.

#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "lancet/shared_model/messages.hpp"

namespace lancet::test {

/// Appends the sheet of cells [x_min + cell_x·i, + cell_x] × [y_min + cell_y·j, + cell_y]. Aborts
/// when it does not fit (a test's own mistake).
template <class Corner>
void add_sheet(TissuePatch& p, int nx, int ny, float x_min, float y_min, float cell_x, float cell_y, Corner&& corner,
               std::uint16_t material = 1, std::uint32_t id_base = 0) {
  if (nx < 0 || ny < 0 || p.n_triangles + 2ull * static_cast<unsigned>(nx) * static_cast<unsigned>(ny) > kPatchCapacity) {
    std::fprintf(stderr, "add_sheet: %d x %d cells do not fit the patch\n", nx, ny);
    std::abort();
  }
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const float x0 = x_min + cell_x * static_cast<float>(i), y0 = y_min + cell_y * static_cast<float>(j);
      const float x1 = x0 + cell_x, y1 = y0 + cell_y;
      const Vec3f a = corner(x0, y0), b = corner(x1, y0), c = corner(x1, y1), d = corner(x0, y1);
      const std::uint32_t k = p.n_triangles;
      p.triangles[k] = {{a, b, c}, material, 0, k + id_base};
      p.triangles[k + 1] = {{a, c, d}, material, 0, k + 1 + id_base};
      p.n_triangles += 2;
    }
}

}  // namespace lancet::test
