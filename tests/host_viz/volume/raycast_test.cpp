// The CPU reference ray caster: opacity correction keeps the image when the step halves, empty
// space skipping never changes it, rays stop at full opacity and at the opaque surfaces' depth,
// the presets and the brick grid's update after drilling.

#include "volume/raycast.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "raycast_support.hpp"
#include "volume/drill.hpp"

namespace lancet::volume {
namespace {

using test::ball_volume;
using test::camera_on;
using test::mean_alpha;

TEST(Raycast, OpacityCorrectionKeepsTheMeanAlphaWhenTheStepHalves) {
  const Volume v = ball_volume();
  const BrickGrid grid(v);
  const RayCamera cam = camera_on(v, 128, 128);
  // A preset, and a faint table whose rays never saturate (where a wrong correction shows most).
  const TfPoint faint_points[] = {{-1000, 0, 0, 0, 0}, {-200, 1, 0.8f, 0.6f, 0}, {0, 1, 0.8f, 0.6f, 0.02f}, {3000, 1, 1, 1, 0.05f}};
  const TransferFunction faint = TransferFunction::from_points(faint_points, -1000, 3000);
  for (const TransferFunction& tf : {tf_preset(TfPreset::kCtSoftTissue), faint}) {
    RaycastParams p;
    RgbaImage a, b;
    p.step = 0.5f;
    raycast_cpu(v, grid, tf, cam, p, {}, a);
    p.step = 0.25f;
    raycast_cpu(v, grid, tf, cam, p, {}, b);
    const double ma = mean_alpha(a), mb = mean_alpha(b);
    ASSERT_GT(ma, 0.02) << "the ball covers part of the image";
    EXPECT_LT(std::abs(ma - mb) / ma, 0.005) << "mean alpha " << ma << " at half a step, " << mb << " at a quarter";
  }
  // Without the correction (each sample's opacity taken as the table's), halving the step makes
  // the faint image far more opaque: the test above can fail.
  RaycastParams p;
  RgbaImage a, b;
  p.opacity_correction = false;
  p.step = 0.5f;
  raycast_cpu(v, grid, faint, cam, p, {}, a);
  p.step = 0.25f;
  raycast_cpu(v, grid, faint, cam, p, {}, b);
  EXPECT_GT((mean_alpha(b) - mean_alpha(a)) / mean_alpha(a), 0.2);
}

TEST(Raycast, SkippingEmptyBricksNeverChangesTheImage) {
  const Volume v = ball_volume();
  const BrickGrid grid(v);
  const RayCamera cam = camera_on(v, 96, 80);
  for (TfPreset preset : kTfPresets) {
    const TransferFunction tf = tf_preset(preset);
    RaycastParams p;
    RgbaImage with, without;
    RaycastStats sw, so;
    raycast_cpu(v, grid, tf, cam, p, {}, with, &sw);
    p.skip_empty = false;
    raycast_cpu(v, grid, tf, cam, p, {}, without, &so);
    EXPECT_EQ(with.rgba, without.rgba) << tf_preset_name(preset);
    EXPECT_GT(mean_alpha(with), 0.01) << tf_preset_name(preset) << " shows something";
    // MIP too: a brick whose largest value the ray's maximum already reaches is jumped over.
    EXPECT_GT(sw.skipped_bricks, 1000u) << tf_preset_name(preset) << ": the air around the ball is skipped";
    EXPECT_LT(sw.samples, so.samples / 2) << tf_preset_name(preset);
  }
}

TEST(Raycast, AMipRayStopsWhereTheTableTurnsConstant) {
  const Volume v = ball_volume();
  const BrickGrid grid(v);
  const RayCamera cam = camera_on(v, 64, 64);
  // A MIP table that saturates low (at -500 HU, below the ball's values): every ray through the
  // ball stops at its first sample above the saturation, with the image unchanged.
  const TfPoint points[] = {{-1000, 0, 0, 0, 0}, {-500, 1, 1, 1, 1}};
  TransferFunction tf = TransferFunction::from_points(points, -1000, 3000);
  tf.mip = true;
  const float from = tf.constant_from();
  EXPECT_GT(from, -500.0f);
  EXPECT_LT(from, -500.0f + 2.5f * 4000.0f / 255.0f) << "within two entries of where the table stops changing";
  for (float x : {from, from + 1.0f, 2500.0f, 1e6f}) EXPECT_EQ(tf.lookup(x), tf.lookup(3000.0f)) << x;
  EXPECT_NE(tf.lookup(-600.0f), tf.lookup(3000.0f));
  // A table whose last two entries differ never stops a ray.
  const TfPoint rising[] = {{-1000, 0, 0, 0, 0}, {3000, 1, 1, 1, 1}};
  EXPECT_TRUE(std::isinf(TransferFunction::from_points(rising, -1000, 3000).constant_from()));

  RaycastParams p;
  p.skip_empty = false;
  RgbaImage img;
  RaycastStats st;
  raycast_cpu(v, grid, tf, cam, p, {}, img, &st);
  EXPECT_GT(st.early_stops, 100u) << "the rays through the ball stop";
  EXPECT_GT(mean_alpha(img), 0.05);
  // Against the same table with one more, higher point: identical colours, but no early stop.
  const TfPoint late[] = {{-1000, 0, 0, 0, 0}, {-500, 1, 1, 1, 1}, {2999, 1, 1, 1, 1}, {3000, 1, 1, 1, 0.999f}};
  TransferFunction tf_late = TransferFunction::from_points(late, -1000, 3000);
  tf_late.mip = true;
  RgbaImage full;
  RaycastStats st_full;
  raycast_cpu(v, grid, tf_late, cam, p, {}, full, &st_full);
  EXPECT_EQ(st_full.early_stops, 0u);
  EXPECT_GT(st_full.samples, st.samples);
  EXPECT_EQ(img.rgba, full.rgba);
}

TEST(Raycast, RaysStopAtFullOpacityAndAtTheSurfacesDepth) {
  const Volume v = ball_volume();
  const BrickGrid grid(v);
  const RayCamera cam = camera_on(v, 64, 64);
  const TransferFunction bone = tf_preset(TfPreset::kCtBone);
  RaycastParams p;
  RgbaImage img;
  RaycastStats st;
  raycast_cpu(v, grid, bone, cam, p, {}, img, &st);
  EXPECT_GT(st.early_stops, 100u);
  const std::size_t centre = 4 * (32 * 64 + 32);
  EXPECT_GE(img.rgba[centre + 3], 0.99f) << "the bone core is opaque";
  // An opaque surface 5 cm from the near plane everywhere: nothing of the ball (20 cm away) shows.
  std::vector<float> max_t(64 * 64, 0.05f);
  raycast_cpu(v, grid, bone, cam, p, max_t, img, &st);
  EXPECT_EQ(mean_alpha(img), 0.0);
  EXPECT_EQ(st.samples, 0u);
}

TEST(Raycast, AClippingPlaneCutsTheVolumeAway) {
  const Volume v = ball_volume();
  const BrickGrid grid(v);
  const TransferFunction bone = tf_preset(TfPreset::kCtBone);
  const RayCamera cam = camera_on(v, 64, 64, 0.0f, 0.0f);  // looking along +y at the ball
  RaycastParams p;
  RgbaImage whole, half, none;
  raycast_cpu(v, grid, bone, cam, p, {}, whole);
  p.clip = true;
  p.clip_plane = {1, 0, 0, -0.0315f};  // keep x <= the ball's centre
  raycast_cpu(v, grid, bone, cam, p, {}, half);
  p.clip_plane = {0, 0, 1, 1.0f};  // keep z <= -1 m: nothing
  raycast_cpu(v, grid, bone, cam, p, {}, none);
  EXPECT_NEAR(mean_alpha(half), 0.5 * mean_alpha(whole), 0.1 * mean_alpha(whole));
  EXPECT_EQ(mean_alpha(none), 0.0);
  // The kept half is the left one (x grows to the right of this camera).
  double left = 0, right = 0;
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x) (x < 32 ? left : right) += half.rgba[static_cast<std::size_t>(4 * (y * 64 + x) + 3)];
  EXPECT_GT(left, 5 * right);
}

TEST(Raycast, DrillingUpdatesTheBricksOverTheHole) {
  Volume v = ball_volume();
  BrickGrid grid(v);
  const TransferFunction bone = tf_preset(TfPreset::kCtBone);
  const auto before = grid.empty_mask(bone);
  DrillParams d;
  d.centre = {0.0315, 0.0315, 0.04725};  // the ball's centre
  d.radius = 0.012;                     // takes the whole bone core
  auto r = drill_sphere(v, d);
  ASSERT_TRUE(r.ok());
  grid.update(v, r.value().dirty);
  const auto after = grid.empty_mask(bone);
  std::size_t emptied = 0;
  for (std::size_t i = 0; i < after.size(); ++i) emptied += after[i] != 0 && before[i] == 0;
  EXPECT_GT(emptied, 8u) << "the bricks of the drilled core are empty under CT-Bone now";
  EXPECT_EQ(after, BrickGrid(v).empty_mask(bone)) << "the same as a grid made from scratch";
}

TEST(Raycast, WindowLevelMovesThePresetsPoints) {
  const TransferFunction base = tf_preset(TfPreset::kCtBone);
  const TransferFunction shifted = tf_preset(TfPreset::kCtBone, 200.0f, 1.0f);
  EXPECT_GT(base.lookup(400)[3], shifted.lookup(400)[3]) << "a higher level makes 400 HU less opaque";
  EXPECT_NEAR(shifted.lookup(600)[3], base.lookup(400)[3], 0.02);
  const TransferFunction narrow = tf_preset(TfPreset::kCtBone, 0.0f, 0.5f);
  EXPECT_NE(narrow.lookup(350)[3], base.lookup(350)[3]);
  EXPECT_EQ(tf_preset_name(TfPreset::kCtVessels), "CT-Vessels (contrast)");
}

}  // namespace
}  // namespace lancet::volume
