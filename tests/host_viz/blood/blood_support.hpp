#pragma once
// Meshes for the blood tests: a grid of nx × ny vertices, h apart, as triangles; its height a
// function of (x, y).

#include <cstdint>
#include <functional>
#include <vector>

namespace lancet::blood::test {

struct Grid {
  std::vector<float> xyz;
  std::vector<std::uint32_t> tri;
  int nx = 0, ny = 0;
  [[nodiscard]] std::uint32_t at(int i, int j) const { return static_cast<std::uint32_t>(j * nx + i); }
};

inline Grid grid(int nx, int ny, float h, const std::function<float(float, float)>& z) {
  Grid g;
  g.nx = nx, g.ny = ny;
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) {
      const float x = static_cast<float>(i) * h, y = static_cast<float>(j) * h;
      g.xyz.insert(g.xyz.end(), {x, y, z(x, y)});
    }
  for (int j = 0; j + 1 < ny; ++j)
    for (int i = 0; i + 1 < nx; ++i) {
      // Diagonals alternate (a criss-cross pattern): no preferred sideways direction for the flow.
      const std::uint32_t a = g.at(i, j), b = g.at(i + 1, j), c = g.at(i + 1, j + 1), d = g.at(i, j + 1);
      if ((i + j) % 2 == 0) {
        g.tri.insert(g.tri.end(), {a, b, c, a, c, d});
      } else {
        g.tri.insert(g.tri.end(), {a, b, d, b, c, d});
      }
    }
  return g;
}

inline constexpr float kDown[3] = {0, 0, -1};

}  // namespace lancet::blood::test
