// The transfer-function editor: the histogram under it, and the gestures on its canvas — drag a
// point within its neighbours, add one coloured as the table is there (nothing changes until it
// moves), remove an inner one, never the ends — each changing the table the ray caster gets.

#include "volume/tf_editor.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "raycast_support.hpp"

namespace lancet::volume {
namespace {

TEST(TfEditor, TheHistogramCountsEveryVoxelAndDrawsOnALogScale) {
  const Volume v = test::ball_volume(64);
  const Histogram h = histogram(v, -1000, 3000, 64);
  ASSERT_EQ(h.counts.size(), 64u);
  std::uint64_t total = 0;
  for (auto c : h.counts) total += c;
  EXPECT_EQ(total, v.voxel_count()) << "values outside the range clamp into the end bins";
  EXPECT_GT(h.counts[0], v.voxel_count() / 2) << "air, at -1000 HU, fills the first bin";
  const auto heights = h.log_heights();
  EXPECT_FLOAT_EQ(heights[0], 1.0f);
  // The ball's bone (about 1200 HU) is a few hundred voxels against tens of thousands of air,
  // yet its bar stands well above zero on the log scale.
  const std::size_t bone_bin = static_cast<std::size_t>((1200.0f + 1000.0f) / 4000.0f * 64.0f);
  EXPECT_GT(h.counts[bone_bin], 0u);
  EXPECT_GT(heights[bone_bin], 0.2f);
  EXPECT_EQ(heights[63], 0.0f);
}

TEST(TfEditor, StartsFromThePresetAfterWindowLevel) {
  const TfSpec spec = tf_preset_spec(TfPreset::kCtBone, 100.0f, 1.0f);
  const TfEditor e(spec);
  ASSERT_EQ(e.points().size(), spec.points.size());
  EXPECT_EQ(e.table().table, tf_preset(TfPreset::kCtBone, 100.0f, 1.0f).table);
  EXPECT_EQ(e.points()[1].value, tf_preset_spec(TfPreset::kCtBone).points[1].value + 100.0f);
}

TEST(TfEditor, DraggingAPointChangesTheTableWithinItsNeighbours) {
  TfEditor e(tf_preset_spec(TfPreset::kCtBone));
  const TfPoint p = e.points()[2];  // (300 HU, 0.4)
  const float r = 0.02f;
  ASSERT_TRUE(e.press(e.x_of(p.value) + 0.005f, p.a - 0.01f, r, r)) << "a press near the point takes it";
  EXPECT_EQ(e.selected(), 2);
  const TransferFunction before = e.table();
  ASSERT_TRUE(e.drag_to(e.x_of(500.0f), 0.8f));
  EXPECT_NEAR(e.points()[2].value, 500.0f, 1.0f);
  EXPECT_FLOAT_EQ(e.points()[2].a, 0.8f);
  EXPECT_GT(e.table().lookup(500.0f)[3], before.lookup(500.0f)[3] + 0.1f) << "more opaque where it was dragged";
  // Past its right neighbour (1000 HU) it stops short of it; the order never changes.
  ASSERT_TRUE(e.drag_to(e.x_of(2500.0f), 1.5f));
  EXPECT_LT(e.points()[2].value, e.points()[3].value);
  EXPECT_GT(e.points()[2].value, 990.0f);
  EXPECT_FLOAT_EQ(e.points()[2].a, 1.0f) << "opacity clamps to 1";
  e.release();
  EXPECT_FALSE(e.drag_to(0.5f, 0.5f)) << "released: nothing is held";
  // An end point moves only up and down.
  ASSERT_TRUE(e.press(e.x_of(3000.0f), 1.0f, r, r));
  ASSERT_TRUE(e.drag_to(0.5f, 0.3f));
  EXPECT_EQ(e.points().back().value, 3000.0f);
  EXPECT_FLOAT_EQ(e.points().back().a, 0.3f);
  // Empty canvas selects nothing.
  EXPECT_FALSE(e.press(0.3f, 0.9f, r, r));
  EXPECT_EQ(e.selected(), -1);
}

TEST(TfEditor, AnAddedPointChangesNothingUntilItMovesAndInnerPointsCanBeRemoved) {
  TfEditor e(tf_preset_spec(TfPreset::kCtSkin));
  const TransferFunction before = e.table();
  const std::size_t n = e.points().size();
  const float x = e.x_of(-500.0f);  // between -600 and -400
  const float alpha_there = before.lookup(-500.0f)[3];
  const int i = e.add(x, alpha_there);
  ASSERT_GE(i, 0);
  EXPECT_EQ(e.points().size(), n + 1);
  EXPECT_EQ(e.selected(), i);
  const TransferFunction same = e.table();
  for (std::size_t k = 0; k < before.table.size(); ++k)
    for (int c = 0; c < 4; ++c) EXPECT_NEAR(same.table[k][static_cast<std::size_t>(c)], before.table[k][static_cast<std::size_t>(c)], 1e-5f) << k;
  e.set_colour(i, 0.1f, 0.9f, 0.1f);
  EXPECT_GT(e.table().lookup(-500.0f)[1], before.lookup(-500.0f)[1] + 0.1f) << "greener there";
  // Not on top of an existing point's value, nor outside the ends.
  EXPECT_EQ(e.add(e.x_of(-400.0f), 0.5f), -1);
  EXPECT_EQ(e.add(-0.1f, 0.5f), -1);
  // Removal: an inner point yes, an end point no.
  EXPECT_TRUE(e.remove(i));
  EXPECT_EQ(e.points().size(), n);
  EXPECT_EQ(e.selected(), -1);
  EXPECT_FALSE(e.remove(0));
  EXPECT_FALSE(e.remove(static_cast<int>(e.points().size()) - 1));
  while (e.points().size() > 2) ASSERT_TRUE(e.remove(1));
  EXPECT_FALSE(e.remove(1)) << "two points are left: both ends";
}

}  // namespace
}  // namespace lancet::volume
