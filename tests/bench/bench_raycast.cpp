// lancet-bench-raycast: the GPU ray caster (render::VolumeRaycaster, a GL compute shader, headless
// through EGL) on the built-in phantom, a CT with air around the body: ms per frame with and
// without empty-space skipping, for CT-Skin, CT-Bone and MIP; and the CPU reference on the same
// frame for scale. Prints one JSON object.
//   lancet-bench-raycast [--size N] [--frames F]

#include <epoxy/gl.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>

#include "render/volume_raycaster.hpp"
#include "render/window.hpp"
#include "volume/phantom.hpp"

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

volume::RayCamera camera(const volume::Volume& v, int size) {
  const glm::vec3 c(static_cast<float>(v.origin.x) + 0.5f * (v.dims[0] - 1) * static_cast<float>(v.spacing.x),
                    static_cast<float>(v.origin.y) + 0.5f * (v.dims[1] - 1) * static_cast<float>(v.spacing.y),
                    static_cast<float>(v.origin.z) + 0.5f * (v.dims[2] - 1) * static_cast<float>(v.spacing.z));
  const glm::vec3 eye = c + 0.35f * glm::normalize(glm::vec3(0.6f, -0.7f, 0.4f));
  const glm::mat4 vp = glm::perspective(glm::radians(35.0f), 1.0f, 0.01f, 2.0f) * glm::lookAt(eye, c, glm::vec3(0, 0, 1));
  volume::RayCamera cam;
  const glm::mat4 inv = glm::inverse(vp);
  std::memcpy(cam.inv_view_proj.data(), glm::value_ptr(inv), sizeof(float) * 16);
  cam.width = cam.height = size;
  return cam;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  int size = 512, frames = 5;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (std::strcmp(argv[i], "--size") == 0) size = std::max(16, std::atoi(argv[i + 1]));
    if (std::strcmp(argv[i], "--frames") == 0) frames = std::max(1, std::atoi(argv[i + 1]));
  }
  auto window = render::Window::create({size, size, false, "bench"});
  if (!window) {
    std::fprintf(stderr, "lancet-bench-raycast: %s\n", window.error().message.c_str());
    return 1;
  }
  const volume::Phantom ph = volume::make_phantom({});
  const volume::Volume& v = ph.volume;
  render::VolumeRaycaster gpu;
  gpu.set_volume(v);
  const volume::BrickGrid grid(v);
  const volume::RayCamera cam = camera(v, size);
  std::printf("{\n  \"gl\": \"%s\",\n  \"volume\": \"phantom %dx%dx%d\",\n  \"image\": %d,\n  \"step\": 0.5,\n  \"presets\": [\n",
              window.value()->gl_description().c_str(), v.dims[0], v.dims[1], v.dims[2], size);
  const volume::TfPreset presets[] = {volume::TfPreset::kCtSkin, volume::TfPreset::kCtBone, volume::TfPreset::kMip};
  for (std::size_t n = 0; n < 3; ++n) {
    const volume::TransferFunction tf = volume::tf_preset(presets[n]);
    gpu.set_transfer_function(tf);
    double ms[2] = {0, 0};
    for (int skip = 1; skip >= 0; --skip) {
      volume::RaycastParams p;
      p.skip_empty = skip == 1;
      std::vector<double> t;
      for (int f = 0; f <= frames; ++f) {
        const auto t0 = Clock::now();
        gpu.render(cam, p);
        glFinish();
        if (f > 0) t.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());  // the first warms up
      }
      ms[skip] = median(t);
    }
    // The CPU reference on the same frame, with skipping, for scale.
    volume::RgbaImage img;
    volume::RaycastStats st;
    const auto t0 = Clock::now();
    volume::raycast_cpu(v, grid, tf, cam, volume::RaycastParams{}, {}, img, &st);
    const double cpu_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    std::printf("    {\"preset\": \"%s\", \"gpu_ms\": %.1f, \"gpu_ms_no_skipping\": %.1f, \"skipping_speedup\": %.2f, "
                "\"cpu_reference_ms\": %.0f, \"cpu_samples\": %llu, \"cpu_skipped_bricks\": %llu}%s\n",
                std::string(volume::tf_preset_name(presets[n])).c_str(), ms[1], ms[0], ms[1] > 0 ? ms[0] / ms[1] : 0.0, cpu_ms,
                static_cast<unsigned long long>(st.samples), static_cast<unsigned long long>(st.skipped_bricks), n + 1 < 3 ? "," : "");
  }
  std::printf("  ]\n}\n");
  return 0;
}
