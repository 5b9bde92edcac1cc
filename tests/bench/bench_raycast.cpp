// lancet-bench-raycast: the GPU ray caster (render::VolumeRaycaster, a GL compute shader, headless
// through EGL) on the built-in phantom, a CT with air around the body: ms per frame with and
// without empty-space skipping, for CT-Skin, CT-Bone and MIP, with the largest difference between
// the two images (skipping must leave it as it is); and the CPU reference on the same frame for
// scale. Prints one JSON object.
//   lancet-bench-raycast [--size N] [--frames F] [--volume PATH] [--vtk-export DIR] [--screenshot PREFIX]
// --volume: a CT (DICOM directory, MetaImage, NRRD) instead of the phantom. --vtk-export: writes
// what scripts/bench_raycast_vtk.py needs to render the same frames with VTK's
// vtkGPUVolumeRayCastMapper (volume.mhd/.raw as float32, and setup.json: camera, image size,
// sample distance, reference step, each preset's table); scripts/bench-raycast-vs-vtk runs both.
// --screenshot: each preset's image with skipping, as PREFIX-<preset>.png.

#include <epoxy/gl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <glm/glm.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>

#include "render/image.hpp"
#include "render/volume_raycaster.hpp"
#include "render/window.hpp"
#include "tissue/scenario_scene.hpp"
#include "volume/phantom.hpp"

namespace {

using namespace lancet;
using Clock = std::chrono::steady_clock;

struct View {
  glm::vec3 eye, centre, up{0, 0, 1};
  float fov_deg = 35, near = 0.01f, far = 2.0f;
};

View view_of(const volume::Volume& v) {
  View w;
  w.centre = glm::vec3(static_cast<float>(v.origin.x) + 0.5f * (v.dims[0] - 1) * static_cast<float>(v.spacing.x),
                    static_cast<float>(v.origin.y) + 0.5f * (v.dims[1] - 1) * static_cast<float>(v.spacing.y),
                    static_cast<float>(v.origin.z) + 0.5f * (v.dims[2] - 1) * static_cast<float>(v.spacing.z));
  // Close enough that the volume fills the frame (its corners may leave it).
  const glm::vec3 half(0.5f * (v.dims[0] - 1) * static_cast<float>(v.spacing.x), 0.5f * (v.dims[1] - 1) * static_cast<float>(v.spacing.y),
                       0.5f * (v.dims[2] - 1) * static_cast<float>(v.spacing.z));
  const float distance = std::max(0.35f, 0.8f * glm::length(half) / std::sin(glm::radians(0.5f * w.fov_deg)));
  w.eye = w.centre + distance * glm::normalize(glm::vec3(0.6f, -0.7f, 0.4f));
  w.far = 2.0f * distance + 1.0f;
  return w;
}

volume::RayCamera camera(const View& w, int size) {
  const glm::mat4 vp = glm::perspective(glm::radians(w.fov_deg), 1.0f, w.near, w.far) * glm::lookAt(w.eye, w.centre, w.up);
  volume::RayCamera cam;
  const glm::mat4 inv = glm::inverse(vp);
  std::memcpy(cam.inv_view_proj.data(), glm::value_ptr(inv), sizeof(float) * 16);
  cam.width = cam.height = size;
  return cam;
}

/// A MetaImage of the voxels as float32 (identity direction: the ray caster ignores it too) and
/// the frame's setup, for scripts/bench_raycast_vtk.py.
bool export_for_vtk(const std::string& dir, const volume::Volume& v, const View& w, int size, float step,
                    const std::vector<volume::TfPreset>& presets) {
  std::FILE* raw = std::fopen((dir + "/volume.raw").c_str(), "wb");
  if (!raw) return false;
  const bool ok = std::fwrite(v.data.data(), sizeof(float), v.data.size(), raw) == v.data.size();
  std::fclose(raw);
  std::FILE* mhd = std::fopen((dir + "/volume.mhd").c_str(), "w");
  if (!ok || !mhd) return false;
  std::fprintf(mhd,
               "ObjectType = Image\nNDims = 3\nDimSize = %d %d %d\nElementSpacing = %.9g %.9g %.9g\nOffset = %.9g %.9g %.9g\n"
               "ElementType = MET_FLOAT\nElementByteOrderMSB = False\nElementDataFile = volume.raw\n",
               v.dims[0], v.dims[1], v.dims[2], v.spacing.x, v.spacing.y, v.spacing.z, v.origin.x, v.origin.y, v.origin.z);
  std::fclose(mhd);
  std::FILE* js = std::fopen((dir + "/setup.json").c_str(), "w");
  if (!js) return false;
  std::fprintf(js,
               "{\n  \"image\": %d,\n  \"sample_distance\": %.9g,\n  \"reference_step\": %.9g,\n"
               "  \"camera\": {\"eye\": [%.9g, %.9g, %.9g], \"centre\": [%.9g, %.9g, %.9g], \"up\": [%g, %g, %g], "
               "\"fov_deg\": %g, \"near\": %.9g, \"far\": %.9g},\n  \"presets\": [\n",
               size, step * volume::reference_step(v), volume::reference_step(v), w.eye.x, w.eye.y, w.eye.z, w.centre.x, w.centre.y,
               w.centre.z, w.up.x, w.up.y, w.up.z, w.fov_deg, w.near, w.far);
  for (std::size_t n = 0; n < presets.size(); ++n) {
    // The table itself, entry by entry (VTK interpolates linearly between points, as lookup() does).
    const volume::TransferFunction tf = volume::tf_preset(presets[n]);
    std::fprintf(js, "    {\"name\": \"%s\", \"mip\": %s, \"points\": [", std::string(volume::tf_preset_name(presets[n])).c_str(),
                 tf.mip ? "true" : "false");
    for (int i = 0; i < volume::TransferFunction::kSize; ++i) {
      const float value = tf.lo + (tf.hi - tf.lo) * static_cast<float>(i) / (volume::TransferFunction::kSize - 1);
      const auto& e = tf.table[static_cast<std::size_t>(i)];
      std::fprintf(js, "%s[%.6g, %.6g, %.6g, %.6g, %.6g]", i ? ", " : "", value, e[0], e[1], e[2], e[3]);
    }
    std::fprintf(js, "]}%s\n", n + 1 < presets.size() ? "," : "");
  }
  std::fprintf(js, "  ]\n}\n");
  return std::fclose(js) == 0;
}

/// The ray caster's image over black as an 8-bit PNG (its rows are bottom first).
bool write_shot(const std::string& path, const volume::RgbaImage& img) {
  render::Image out{img.width, img.height, std::vector<std::uint8_t>(static_cast<std::size_t>(img.width) * img.height * 4)};
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x)
      for (int c = 0; c < 4; ++c) {
        const float f = img.rgba[(static_cast<std::size_t>(y) * img.width + x) * 4 + c];
        out.rgba[(static_cast<std::size_t>(img.height - 1 - y) * img.width + x) * 4 + c] =
            c == 3 ? 255 : static_cast<std::uint8_t>(std::clamp(f, 0.0f, 1.0f) * 255.0f + 0.5f);
      }
  return render::write_png(path, out);
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  int size = 512, frames = 5;
  std::string volume_path, export_dir, shot_prefix;
  for (int i = 1; i < argc; i += 2) {
    if (i + 1 >= argc) {
      std::fprintf(stderr, "lancet-bench-raycast: %s needs a value\n", argv[i]);
      return 2;
    }
    if (std::strcmp(argv[i], "--size") == 0) {
      size = std::max(16, std::atoi(argv[i + 1]));
    } else if (std::strcmp(argv[i], "--frames") == 0) {
      frames = std::max(1, std::atoi(argv[i + 1]));
    } else if (std::strcmp(argv[i], "--volume") == 0) {
      volume_path = argv[i + 1];
    } else if (std::strcmp(argv[i], "--vtk-export") == 0) {
      export_dir = argv[i + 1];
    } else if (std::strcmp(argv[i], "--screenshot") == 0) {
      shot_prefix = argv[i + 1];
    } else {
      std::fprintf(stderr, "lancet-bench-raycast: unknown option %s (--size N, --frames F, --volume PATH, --vtk-export DIR, --screenshot PREFIX)\n", argv[i]);
      return 2;
    }
  }
  auto window = render::Window::create({size, size, false, "bench"});
  if (!window) {
    std::fprintf(stderr, "lancet-bench-raycast: %s\n", window.error().message.c_str());
    return 1;
  }
  volume::Volume v;
  std::string volume_name;
  if (volume_path.empty()) {
    v = volume::make_phantom({}).volume;
    volume_name = "phantom";
  } else {
    auto loaded = tissue::load_ct(volume_path);
    if (!loaded) {
      std::fprintf(stderr, "lancet-bench-raycast: %s\n", loaded.error().message.c_str());
      return 1;
    }
    v = std::move(loaded.value());
    volume_name = volume_path;
  }
  const float step = volume::RaycastParams{}.step;
  const std::vector<volume::TfPreset> presets = {volume::TfPreset::kCtSkin, volume::TfPreset::kCtBone, volume::TfPreset::kMip};
  const View view = view_of(v);
  if (!export_dir.empty() && !export_for_vtk(export_dir, v, view, size, step, presets)) {
    std::fprintf(stderr, "lancet-bench-raycast: cannot write the VTK setup into %s\n", export_dir.c_str());
    return 1;
  }
  render::VolumeRaycaster gpu;
  gpu.set_volume(v);
  const volume::BrickGrid grid(v);
  const volume::RayCamera cam = camera(view, size);
  std::printf("{\n  \"gl\": \"%s\",\n  \"volume\": \"%s %dx%dx%d\",\n  \"image\": %d,\n  \"step\": %g,\n  \"presets\": [\n",
              window.value()->gl_description().c_str(), volume_name.c_str(), v.dims[0], v.dims[1], v.dims[2], size, step);
  for (std::size_t n = 0; n < presets.size(); ++n) {
    const volume::TransferFunction tf = volume::tf_preset(presets[n]);
    gpu.set_transfer_function(tf);
    double ms[2] = {0, 0};
    volume::RgbaImage shown[2];  // the last frame of each, by skip
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
      shown[skip] = gpu.read_back();
    }
    // Skipping must not change the picture: the largest difference of a channel between the two.
    float skip_diff = 0;
    for (std::size_t i = 0; i < shown[1].rgba.size(); ++i) skip_diff = std::max(skip_diff, std::abs(shown[1].rgba[i] - shown[0].rgba[i]));
    if (!shot_prefix.empty()) {  // the image with skipping, the one timed first
      const std::string name(volume::tf_preset_name(presets[n]));
      const std::string path = shot_prefix + "-" + name.substr(0, name.find(' ')) + ".png";
      if (!write_shot(path, shown[1])) std::fprintf(stderr, "lancet-bench-raycast: cannot write %s\n", path.c_str());
    }
    // The CPU reference on the same frame, with skipping, for scale.
    volume::RgbaImage img;
    volume::RaycastStats st;
    const auto t0 = Clock::now();
    volume::raycast_cpu(v, grid, tf, cam, volume::RaycastParams{}, {}, img, &st);
    const double cpu_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    std::printf("    {\"preset\": \"%s\", \"gpu_ms\": %.1f, \"gpu_ms_no_skipping\": %.1f, \"skipping_speedup\": %.2f, "
                "\"skip_vs_no_skip_max_diff\": %.2g, \"cpu_reference_ms\": %.0f, \"cpu_samples\": %llu, \"cpu_skipped_bricks\": %llu}%s\n",
                std::string(volume::tf_preset_name(presets[n])).c_str(), ms[1], ms[0], ms[1] > 0 ? ms[0] / ms[1] : 0.0, skip_diff, cpu_ms,
                static_cast<unsigned long long>(st.samples), static_cast<unsigned long long>(st.skipped_bricks), n + 1 < presets.size() ? "," : "");
  }
  std::printf("  ]\n}\n");
  return 0;
}
