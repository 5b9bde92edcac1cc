#pragma once
// A 64³ test volume for the ray casters (anisotropic voxels, air around a soft-tissue ball with a
// bone core, partial-volume boundaries) and a camera looking at it.

#include <glm/glm.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "volume/raycast.hpp"

namespace lancet::test {

inline volume::Volume ball_volume(int n = 64) {
  volume::Volume v;
  v.dims = {n, n, n};
  v.spacing = {0.001, 0.001, 0.0015};
  v.origin = {0, 0, 0};
  v.value_unit = "HU";
  v.data.resize(v.voxel_count());
  const double cx = 0.5 * (n - 1) * 0.001, cz = 0.5 * (n - 1) * 0.0015;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const double r = std::sqrt(std::pow(i * 0.001 - cx, 2) + std::pow(j * 0.001 - cx, 2) + std::pow(k * 0.0015 - cz, 2));
        const double soft = std::clamp((0.022 - r) / 0.002 + 0.5, 0.0, 1.0);  // a 2 mm ramp
        const double bone = std::clamp((0.010 - r) / 0.002 + 0.5, 0.0, 1.0);
        v.data[v.index(i, j, k)] = static_cast<float>(-1000 + soft * 1040 + bone * 1160);
      }
  return v;
}

/// Looks at the volume's centre from `distance` m away (yaw, pitch in rad), w×h pixels.
inline volume::RayCamera camera_on(const volume::Volume& v, int w, int h, float yaw = 0.5f, float pitch = 0.4f, float distance = 0.2f) {
  const glm::vec3 c(0.5f * (v.dims[0] - 1) * static_cast<float>(v.spacing.x), 0.5f * (v.dims[1] - 1) * static_cast<float>(v.spacing.y),
                    0.5f * (v.dims[2] - 1) * static_cast<float>(v.spacing.z));
  const glm::vec3 eye = c + distance * glm::vec3(std::cos(pitch) * std::sin(yaw), -std::cos(pitch) * std::cos(yaw), std::sin(pitch));
  const glm::mat4 view = glm::lookAt(eye, c, glm::vec3(0, 0, 1));
  const glm::mat4 proj = glm::perspective(glm::radians(30.0f), static_cast<float>(w) / static_cast<float>(h), 0.01f, 1.0f);
  const glm::mat4 inv = glm::inverse(proj * view);
  volume::RayCamera cam;
  std::memcpy(cam.inv_view_proj.data(), glm::value_ptr(inv), sizeof(float) * 16);
  cam.width = w;
  cam.height = h;
  return cam;
}

inline double mean_alpha(const volume::RgbaImage& img) {
  double s = 0;
  for (std::size_t i = 3; i < img.rgba.size(); i += 4) s += img.rgba[i];
  return s / static_cast<double>(img.rgba.size() / 4);
}

}  // namespace lancet::test
