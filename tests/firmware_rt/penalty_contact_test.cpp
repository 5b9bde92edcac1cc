#include "haptics/penalty_contact.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <random>

namespace lancet::haptics {
namespace {

// A square of two triangles in the plane z = h, normals +z, spanning [-s, s]².
std::unique_ptr<TissuePatch> plane_patch(float h = 0.0f, float s = 0.05f) {
  auto p = std::make_unique<TissuePatch>();
  p->n_triangles = 2;
  p->triangles[0] = {{{-s, -s, h}, {s, -s, h}, {s, s, h}}, 1, 0};
  p->triangles[1] = {{{-s, -s, h}, {s, s, h}, {-s, s, h}}, 1, 0};
  return p;
}

TEST(ClosestPointOnTriangle, MatchesDenseSamplingInEveryRegion) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Vec3 a{u(rng), u(rng), u(rng)}, b{u(rng), u(rng), u(rng)}, c{u(rng), u(rng), u(rng)};
    const Vec3 p{2 * u(rng), 2 * u(rng), 2 * u(rng)};
    const Vec3 q = closest_point_on_triangle(p, a, b, c);
    // Brute force over barycentric samples: none may be closer than q (up to sampling error).
    double best = 1e300;
    constexpr int n = 120;
    for (int i = 0; i <= n; ++i) {
      for (int j = 0; i + j <= n; ++j) {
        const double s = static_cast<double>(i) / n, t = static_cast<double>(j) / n;
        const Vec3 x = a + s * (b - a) + t * (c - a);
        best = std::min(best, norm(p - x));
      }
    }
    EXPECT_LE(norm(p - q), best + 1e-9) << "trial " << trial;
    EXPECT_GE(norm(p - q), best - 0.05) << "trial " << trial;  // q lies on the triangle
  }
}

TEST(PenaltyContact, PressingAPlaneGivesStiffnessTimesDepth) {
  const auto patch = plane_patch();
  PenaltyParams params;
  params.stiffness = 400;
  params.damping = 0;
  for (double depth : {0.0005, 0.002, 0.007}) {
    const ContactResult r = penalty_contact(params, *patch, {0.01, -0.02, -depth}, {});
    EXPECT_TRUE(r.contact);
    EXPECT_NEAR(r.force.z, params.stiffness * depth, 1e-9);
    EXPECT_NEAR(r.force.x, 0, 1e-12);
    EXPECT_NEAR(r.force.y, 0, 1e-12);
  }
}

TEST(PenaltyContact, NoForceAboveTheSurfaceOrBeyondMaxDepth) {
  const auto patch = plane_patch();
  PenaltyParams params;
  EXPECT_FALSE(penalty_contact(params, *patch, {0, 0, 0.001}, {}).contact);
  EXPECT_EQ(penalty_contact(params, *patch, {0, 0, 0.001}, {}).force, Vec3{});
  EXPECT_FALSE(penalty_contact(params, *patch, {0, 0, -params.max_depth - 1e-4}, {}).contact);
}

TEST(PenaltyContact, DampingResistsPressingButNeverPulls) {
  const auto patch = plane_patch();
  PenaltyParams params;
  params.stiffness = 500;
  params.damping = 10;
  const double depth = 0.001;
  const ContactResult in = penalty_contact(params, *patch, {0, 0, -depth}, {0, 0, -0.1});
  EXPECT_NEAR(in.force.z, 500 * depth + 10 * 0.1, 1e-9);
  // Withdrawing fast: the damper would pull the tool in; the force stays at zero instead.
  const ContactResult out = penalty_contact(params, *patch, {0, 0, -depth}, {0, 0, 1.0});
  EXPECT_GE(out.force.z, 0.0);
  EXPECT_NEAR(out.force.z, 0.0, 1e-12);
}

TEST(PenaltyContact, EmptyAndDegeneratePatchesGiveNoForce) {
  auto patch = std::make_unique<TissuePatch>();
  EXPECT_FALSE(penalty_contact({}, *patch, {0, 0, -0.001}, {}).contact);
  patch->n_triangles = 1;
  patch->triangles[0] = {{{0, 0, 0}, {0, 0, 0}, {0, 0, 0}}, 1, 0};
  EXPECT_EQ(penalty_contact({}, *patch, {0, 0, -0.001}, {}).force, Vec3{});
}

}  // namespace
}  // namespace lancet::haptics
