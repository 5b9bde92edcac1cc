// Golden images of what lancet-viz draws, on Mesa's llvmpipe (headless EGL): the meshes alone, the
// volume alone, and the two composited (soft tissue ray cast in front of an opaque bone mesh, the
// rays stopping at it). Compared with a tolerance that survives small rasteriser changes: mean
// channel difference under 1/255 and at most 1% of pixels off by more than 16/255.
// LANCET_UPDATE_GOLDEN=1 writes the images into tests/host_viz/render/golden/ instead (look at
// them before committing).

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "../volume/raycast_support.hpp"
#include "render/image.hpp"
#include "render/scene_renderer.hpp"
#include "render/volume_raycaster.hpp"
#include "headless_gl.hpp"
#include "volume/marching_cubes.hpp"

namespace lancet::render {
namespace {

const std::string kGolden = std::string(LANCET_SOURCE_DIR) + "/tests/host_viz/render/golden/";

using Golden = test::HeadlessGl<160, 120>;

surface::TriangleMesh iso_mesh(const volume::Volume& v, float iso) {
  volume::IsoOptions o;
  o.iso = iso;
  o.pad_border = true;
  auto s = volume::extract_isosurface(v, o);
  surface::TriangleMesh m;
  if (!s.ok()) return m;
  m.vertices = s.value().positions;
  m.normals = s.value().normals;
  m.triangles = s.value().triangles;
  m.material.assign(m.triangles.size(), iso > 0 ? 4 : 1);  // bone or skin
  return m;
}

void check(const std::string& name, const Image& img) {
  const std::string path = kGolden + name + ".png";
  if (const char* u = std::getenv("LANCET_UPDATE_GOLDEN"); u != nullptr && std::string(u) == "1") {
    ASSERT_TRUE(write_png(path, img)) << path;
    std::printf("[ golden   ] wrote %s\n", path.c_str());
    return;
  }
  const Image want = read_png(path);
  ASSERT_EQ(want.width, img.width) << path << " (LANCET_UPDATE_GOLDEN=1 makes it)";
  ASSERT_EQ(want.height, img.height) << path;
  double sum = 0;
  std::size_t far = 0;
  for (std::size_t p = 0; p < img.rgba.size(); p += 4) {
    int worst = 0;
    for (std::size_t c = 0; c < 3; ++c) {
      const int d = std::abs(static_cast<int>(img.rgba[p + c]) - static_cast<int>(want.rgba[p + c]));
      sum += d;
      worst = std::max(worst, d);
    }
    far += worst > 16;
  }
  const double pixels = static_cast<double>(img.rgba.size() / 4);
  const double mean = sum / (3 * pixels);
  std::printf("[ golden   ] %s: mean channel difference %.3f/255, %zu pixels off by more than 16\n", name.c_str(), mean, far);
  EXPECT_LT(mean, 1.0) << name;
  EXPECT_LE(static_cast<double>(far), 0.01 * pixels) << name;
}

TEST_F(Golden, MeshVolumeAndComposite) {
  const volume::Volume v = test::ball_volume(64);
  SceneRenderer r(160, 120);
  VolumeRaycaster caster;
  caster.set_volume(v);
  SceneInput in;
  in.camera_target = {0.0315, 0.0315, 0.04725};
  in.camera_distance = 0.13f;
  in.camera_yaw = 0.5f;
  in.camera_pitch = 0.4f;
  // The meshes: the ball's skin.
  r.set_mesh(iso_mesh(v, -300));
  r.render(in);
  check("mesh", r.read_back());
  // The volume alone, CT-Bone.
  caster.set_transfer_function(volume::tf_preset(volume::TfPreset::kCtBone));
  in.volume = &caster;
  in.draw_surface = false;
  r.render(in);
  check("volume", r.read_back());
  // Composite: soft tissue ray cast in front of the opaque bone mesh.
  r.set_mesh(iso_mesh(v, 300));
  caster.set_transfer_function(volume::tf_preset(volume::TfPreset::kCtSoftTissue));
  in.draw_surface = true;
  r.render(in);
  check("composite", r.read_back());
}

}  // namespace
}  // namespace lancet::render
