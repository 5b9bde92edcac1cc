// The GPU ray caster against the CPU reference on a 64³ volume at 128² (headless EGL, llvmpipe):
// the same image within a small per-pixel tolerance, for every preset, and after a drilled region
// is updated; MIP's empty-space skipping (its own schedule on the GPU) on a noisy CT with air
// around the body.

#include "render/volume_raycaster.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <cstdlib>
#include <memory>

#include "../volume/raycast_support.hpp"
#include "headless_gl.hpp"
#include "volume/drill.hpp"
#include "volume/phantom.hpp"

namespace lancet::render {
namespace {

using VolumeRaycasterTest = test::HeadlessGl<128, 128>;

struct Diff {
  double max = 0, mean = 0;
  std::size_t over = 0;  ///< channels off by more than 2/255
};
Diff compare(const volume::RgbaImage& a, const volume::RgbaImage& b) {
  Diff d;
  for (std::size_t i = 0; i < a.rgba.size(); ++i) {
    const double e = std::abs(static_cast<double>(a.rgba[i]) - b.rgba[i]);
    d.max = std::max(d.max, e);
    d.mean += e;
    d.over += e > 2.0 / 255.0;
  }
  d.mean /= static_cast<double>(a.rgba.size());
  return d;
}

TEST_F(VolumeRaycasterTest, MatchesTheCpuReferenceForEveryPreset) {
  volume::Volume v = test::ball_volume(64);
  VolumeRaycaster gpu;
  gpu.set_volume(v);
  volume::BrickGrid grid(v);
  const volume::RayCamera cam = test::camera_on(v, 128, 128);
  const volume::RaycastParams p;
  for (volume::TfPreset preset : volume::kTfPresets) {
    const volume::TransferFunction tf = volume::tf_preset(preset);
    gpu.set_transfer_function(tf);
    gpu.render(cam, p);
    const volume::RgbaImage g = gpu.read_back();
    volume::RgbaImage c;
    volume::raycast_cpu(v, grid, tf, cam, p, {}, c);
    ASSERT_EQ(g.rgba.size(), c.rgba.size());
    const Diff d = compare(g, c);
    std::printf("[ info     ] %s: GPU vs CPU mean |d| %.2e, max %.2e, %zu of %zu channels off by > 2/255\n",
                std::string(volume::tf_preset_name(preset)).c_str(), d.mean, d.max, d.over, c.rgba.size());
    EXPECT_GT(test::mean_alpha(c), 0.01) << volume::tf_preset_name(preset);
    // The same operations in the same order, the trilinear blend done by the texture unit:
    // rounding apart on llvmpipe, which blends in float (below 1e-6). A hardware texture unit
    // blends with 8-bit weights and would be further off; these tests run on llvmpipe.
    EXPECT_LT(d.max, 1e-3) << volume::tf_preset_name(preset);
    EXPECT_EQ(d.over, 0u) << volume::tf_preset_name(preset);
  }
  {  // with a clipping plane through the ball
    volume::RaycastParams clipped;
    clipped.clip = true;
    clipped.clip_plane = {0.6f, 0.0f, 0.8f, -0.045f};
    const volume::TransferFunction tf = volume::tf_preset(volume::TfPreset::kCtSoftTissue);
    gpu.set_transfer_function(tf);
    gpu.render(cam, clipped);
    volume::RgbaImage c;
    volume::raycast_cpu(v, grid, tf, cam, clipped, {}, c);
    const Diff d = compare(gpu.read_back(), c);
    EXPECT_LT(d.max, 1e-3);
    EXPECT_GT(test::mean_alpha(c), 0.01);
  }
  // Every compiled variant (the shader is specialised by MIP, shading and skipping): unshaded and
  // unskipped images agree too.
  for (int variant = 0; variant < 4; ++variant) {
    volume::RaycastParams q;
    q.shade = (variant & 1) != 0;
    q.skip_empty = (variant & 2) != 0;
    for (volume::TfPreset preset : {volume::TfPreset::kCtSkin, volume::TfPreset::kMip}) {
      const volume::TransferFunction tf = volume::tf_preset(preset);
      gpu.set_transfer_function(tf);
      gpu.render(cam, q);
      volume::RgbaImage c;
      volume::raycast_cpu(v, grid, tf, cam, q, {}, c);
      const Diff d = compare(gpu.read_back(), c);
      EXPECT_LT(d.max, 1e-3) << volume::tf_preset_name(preset) << " shade " << q.shade << " skip " << q.skip_empty;
      EXPECT_GT(test::mean_alpha(c), 0.01);
    }
  }
  // Drill out the core: after update_region, GPU and CPU agree again (and the hole shows).
  volume::DrillParams dp;
  dp.centre = {0.0315, 0.0315, 0.04725};
  dp.radius = 0.012;
  auto r = volume::drill_sphere(v, dp);
  ASSERT_TRUE(r.ok());
  gpu.update_region(v, r.value().dirty);
  grid.update(v, r.value().dirty);
  const volume::TransferFunction bone = volume::tf_preset(volume::TfPreset::kCtBone);
  gpu.set_transfer_function(bone);
  gpu.render(cam, p);
  volume::RgbaImage c;
  volume::raycast_cpu(v, grid, bone, cam, p, {}, c);
  EXPECT_LT(test::mean_alpha(c), 0.01) << "no bone left";
  EXPECT_LT(compare(gpu.read_back(), c).mean, 1e-3);
}

// The GPU skips differently for MIP (it marches the bricks first and samples only the stretch of
// the ray that can hold its maximum), so test it where that matters: noise everywhere (no brick is
// flat), air in front of and behind the body, rays along an axis, a drilled hole.
TEST_F(VolumeRaycasterTest, MipSkippingLeavesTheImageAsItIs) {
  volume::PhantomParams pp;
  pp.dims = {64, 64, 80};
  pp.spacing = 0.002;
  volume::Volume v = volume::make_phantom(pp).volume;
  v.origin = {0, 0, 0};  // camera_on aims at the box from its corner at the origin
  VolumeRaycaster gpu;
  gpu.set_volume(v);
  volume::BrickGrid grid(v);
  const volume::TransferFunction tf = volume::tf_preset(volume::TfPreset::kMip);
  gpu.set_transfer_function(tf);
  const auto check = [&](const volume::RayCamera& cam, const char* what) {
    volume::RaycastParams skip, no_skip;
    no_skip.skip_empty = false;
    gpu.render(cam, no_skip);
    const volume::RgbaImage all = gpu.read_back();
    gpu.render(cam, skip);
    const volume::RgbaImage skipped = gpu.read_back();
    volume::RgbaImage c;
    volume::raycast_cpu(v, grid, tf, cam, skip, {}, c);
    EXPECT_GT(test::mean_alpha(c), 0.01) << what;
    // The same samples where any can matter: the same maximum, the same colour.
    EXPECT_LT(compare(skipped, all).max, 1e-6) << what;
    const Diff d = compare(skipped, c);
    EXPECT_LT(d.max, 1e-3) << what;
    EXPECT_EQ(d.over, 0u) << what;
  };
  check(test::camera_on(v, 128, 128, 0.5f, 0.4f, 0.35f), "oblique");
  check(test::camera_on(v, 128, 128, 0.0f, 0.0f, 0.35f), "along y");
  check(test::camera_on(v, 128, 128, 0.3f, 1.5f, 0.35f), "nearly down the limb");
  // Drill into the bone: the bricks over the hole change, and the GPU's copy with them.
  volume::DrillParams dp;
  dp.centre = {0.063 + 0.006, 0.063 - 0.004, 0.079};  // the bone's axis, half way along
  dp.radius = 0.015;
  auto r = volume::drill_sphere(v, dp);
  ASSERT_TRUE(r.ok());
  gpu.update_region(v, r.value().dirty);
  grid.update(v, r.value().dirty);
  check(test::camera_on(v, 128, 128, 0.5f, 0.4f, 0.35f), "drilled");
}

}  // namespace
}  // namespace lancet::render
