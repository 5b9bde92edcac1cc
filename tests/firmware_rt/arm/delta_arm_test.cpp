// DeltaArm, the Novint Falcon's three-leg parallel mechanism: forward and inverse kinematics round
// trips over the workspace, the inverse against libnifalcon's published formula (re-derived here),
// the Jacobian against central differences and virtual work, determinism, the workspace and its
// conditioning, what a forward solve does where the legs cannot be assembled, no allocation, and
// the model inside Kinematics.

#include "arm/delta_arm.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "arm/kinematics.hpp"
#include "malloc_guard.hpp"

namespace lancet::arm {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180;
constexpr double kInch = 0.0254;

// The Falcon's workspace, found for the published geometry (see DeltaArm in hw_configs/README.md):
// the largest axis-aligned cube centred on the legs' axis is 91 mm wide at z = 111 mm.
constexpr Vec3 kCubeCentre{0, 0, 0.111};
constexpr double kReachableHalf = 0.045;  // m: a 90 mm cube, inside the 91 mm one

DeltaArm falcon(Vec3 base_offset = {}) { return DeltaArm(DeltaGeometry::novint_falcon(), base_offset); }

std::vector<double> vec(const std::array<double, 3>& q) { return {q[0], q[1], q[2]}; }

// n³ points of the cube of half-width `half` about `centre`.
std::vector<Vec3> cube_grid(Vec3 centre, double half, int n) {
  std::vector<Vec3> out;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        const auto at = [&](int t) { return -half + 2 * half * t / (n - 1); };
        out.push_back(centre + Vec3{at(i), at(j), at(k)});
      }
  return out;
}

void expect_near(Vec3 a, Vec3 b, double tol, const std::string& what) {
  EXPECT_NEAR(a.x, b.x, tol) << what;
  EXPECT_NEAR(a.y, b.y, tol) << what;
  EXPECT_NEAR(a.z, b.z, tol) << what;
}

std::string str(Vec3 p) {
  return "(" + std::to_string(p.x * 1e3) + ", " + std::to_string(p.y * 1e3) + ", " + std::to_string(p.z * 1e3) + ") mm";
}

// libnifalcon's inverse kinematics (FalconKinematicStamper::IK) written out again from its
// formula: θ3 = acos((v + f) / b); l0, l1, l2 the coefficients of the quadratic in T = tan(θ1/2);
// θ1 = 2 atan of the "−" root. An independent reference: it shares no code with DeltaArm.
std::optional<std::array<double, 3>> reference_inverse(const DeltaGeometry& g, Vec3 p) {
  std::array<double, 3> theta{};
  for (std::size_t i = 0; i < 3; ++i) {
    const double phi = g.leg_angles[i];
    const double u = std::cos(phi) * p.x + std::sin(phi) * p.y - g.r;
    const double v = -std::sin(phi) * p.x + std::cos(phi) * p.y - g.s;
    const double w = p.z;
    const double theta3 = std::acos((v + g.f) / g.b);
    const double s3 = std::sin(theta3);
    const double common = w * w + u * u + 2 * g.c * u + g.a * g.a + g.c * g.c - g.d * g.d - g.e * g.e -
                          g.b * g.b * s3 * s3 - 2 * g.b * g.e * s3 - 2 * g.b * g.d * s3 - 2 * g.d * g.e;
    const double l0 = common - 2 * g.a * u - 2 * g.a * g.c;
    const double l1 = -4 * g.a * w;
    const double l2 = common + 2 * g.a * u + 2 * g.a * g.c;
    const double disc = l1 * l1 - 4 * l0 * l2;
    if (!(disc >= 0) || !std::isfinite(theta3)) return std::nullopt;
    theta[i] = 2 * std::atan((-l1 - std::sqrt(disc)) / (2 * l2));
  }
  return theta;
}

TEST(DeltaArm, FalconGeometryIsValidAndCentredOnItsAxis) {
  const DeltaGeometry g = DeltaGeometry::novint_falcon();
  EXPECT_EQ(delta_geometry_problem(g), nullptr);
  const DeltaArm arm = falcon();
  // The middle of the reach along the axis: between z = 59.7 mm (folded) and 183.2 mm (stretched).
  EXPECT_EQ(arm.centre().x, 0.0);
  EXPECT_EQ(arm.centre().y, 0.0);
  EXPECT_NEAR(arm.centre().z, 0.5 * (0.0597400 + 0.1832064), 1e-6);
  EXPECT_TRUE(arm.inverse({0, 0, 0.0598}).has_value());
  EXPECT_FALSE(arm.inverse({0, 0, 0.0596}).has_value()) << "folded past the thighs";
  EXPECT_TRUE(arm.inverse({0, 0, 0.1831}).has_value());
  EXPECT_FALSE(arm.inverse({0, 0, 0.1833}).has_value()) << "stretched past the legs";
}

TEST(DeltaArm, OnTheAxisAllThighAnglesAreEqual) {
  const DeltaArm arm = falcon();
  for (double z = 0.065; z < 0.18; z += 0.005) {
    const auto q = arm.inverse({0, 0, z});
    ASSERT_TRUE(q.has_value()) << z;
    EXPECT_NEAR((*q)[0], (*q)[1], 1e-13) << z;
    EXPECT_NEAR((*q)[0], (*q)[2], 1e-13) << z;
    // And the other way: equal thigh angles put the effector on the axis.
    const std::vector<double> same{(*q)[0], (*q)[0], (*q)[0]};
    const Vec3 p = arm.position(same);
    EXPECT_NEAR(p.x, 0, 1e-12);
    EXPECT_NEAR(p.y, 0, 1e-12);
    EXPECT_NEAR(p.z, z, 1e-12);
  }
  // At the cube's centre (the device-frame origin the Falcon's config asks for) the thighs are at
  // 16.98° (and the shins 91.07° from the motor axes).
  const auto q = arm.inverse(kCubeCentre);
  ASSERT_TRUE(q.has_value());
  EXPECT_NEAR((*q)[0] / kDeg, 16.9757, 1e-3);
}

TEST(DeltaArm, InverseMatchesLibnifalconsFormula) {
  const DeltaGeometry g = DeltaGeometry::novint_falcon();
  const DeltaArm arm(g);
  int compared = 0;
  for (const Vec3 p : cube_grid(kCubeCentre, 2 * kInch, 13)) {
    const auto ours = arm.inverse(p);
    const auto ref = reference_inverse(g, p);
    ASSERT_EQ(ours.has_value(), ref.has_value()) << str(p);
    if (!ours) continue;
    ++compared;
    for (std::size_t i = 0; i < 3; ++i) EXPECT_NEAR((*ours)[i], (*ref)[i], 1e-10) << str(p) << " leg " << i;
  }
  EXPECT_GT(compared, 13 * 13 * 13 * 3 / 4);
}

TEST(DeltaArm, ForwardOfInverseIsTheIdentityOverTheWorkspace) {
  const DeltaArm arm = falcon();
  // The reachable cube, and whatever the legs reach of the 4-inch cube about the same centre.
  for (const double half : {kReachableHalf, 2 * kInch}) {
    for (const Vec3 p : cube_grid(kCubeCentre, half, 11)) {
      const auto q = arm.inverse(p);
      if (half == kReachableHalf) {
        ASSERT_TRUE(q.has_value()) << str(p);
      }
      if (!q) continue;
      const DeltaSolve s = arm.solve(vec(*q));
      EXPECT_TRUE(s.converged) << str(p) << " residual " << s.residual;
      EXPECT_LE(s.iterations, 8) << str(p);
      expect_near(s.position, p, 1e-9, str(p));
    }
  }
}

// Whether every knee of q is on the outside, the branch the inverse picks (libnifalcon's "−" root):
// in leg i's frame the knee (a cos θ1, a sin θ1) lies clockwise of the effector point (u + c, w),
// i.e. (u + c) sin θ1 − w cos θ1 < 0 (the same sign as ∂g_i/∂θ1; 0 where the leg is stretched
// straight or folded flat, and the branches meet).
bool knees_outside(const DeltaGeometry& g, Vec3 p, const std::vector<double>& q) {
  for (std::size_t i = 0; i < 3; ++i) {
    const double phi = g.leg_angles[i];
    const double u = std::cos(phi) * p.x + std::sin(phi) * p.y - g.r;
    if (!((u + g.c) * std::sin(q[i]) - p.z * std::cos(q[i]) < 0)) return false;
  }
  return true;
}

TEST(DeltaArm, InverseOfForwardIsTheIdentity) {
  const DeltaGeometry g = DeltaGeometry::novint_falcon();
  const DeltaArm arm(g);
  int checked = 0, other_branch = 0, stalled = 0;
  // The thighs' range over the reachable cube (−79.5° to 100.9°), every 15°.
  for (double a = -80; a <= 100; a += 15)
    for (double b = -80; b <= 100; b += 15)
      for (double c = -80; c <= 100; c += 15) {
        const std::vector<double> q{a * kDeg, b * kDeg, c * kDeg};
        const DeltaSolve s = arm.solve(q);
        // A few extreme triples (one thigh far back, two far forward) put the effector below the
        // workspace, across a near-singular region Newton does not get through from the centre.
        if (!s.converged) {
          ++stalled;
          continue;
        }
        const Vec3 d = s.position - kCubeCentre;
        // Joint triples whose tool point lies in the 4-inch box about the centre.
        if (std::abs(d.x) > 2 * kInch || std::abs(d.y) > 2 * kInch || std::abs(d.z) > 2 * kInch) continue;
        // A thigh swung past the stretched (or folded) leg puts that knee inside: the same tool
        // point then has another, outside-knee q, which is what the inverse gives.
        if (!knees_outside(g, s.position, q)) {
          ++other_branch;
          continue;
        }
        const auto back = arm.inverse(s.position);
        ASSERT_TRUE(back.has_value()) << a << " " << b << " " << c;
        for (std::size_t i = 0; i < 3; ++i) EXPECT_NEAR((*back)[i], q[i], 1e-9) << a << " " << b << " " << c;
        ++checked;
      }
  EXPECT_GT(checked, 150);
  EXPECT_GT(other_branch, 0) << "the grid reaches past the knees' flip";
  EXPECT_LE(stalled, 3);
}

TEST(DeltaArm, JacobianMatchesCentralDifferencesAndVirtualWork) {
  const DeltaArm arm = falcon();
  const Vec3 force{0.7, -1.3, 2.1};
  for (const Vec3 p : cube_grid(kCubeCentre, kReachableHalf, 5)) {
    const auto q0 = arm.inverse(p);
    ASSERT_TRUE(q0.has_value()) << str(p);
    const std::vector<double> q = vec(*q0);
    const Jacobian j = arm.jacobian(q);
    ASSERT_EQ(j.n, 3);
    const double h = 1e-6;
    for (std::size_t k = 0; k < 3; ++k) {
      std::vector<double> plus = q, minus = q;
      plus[k] += h, minus[k] -= h;
      const Vec3 fd = (arm.position(plus) - arm.position(minus)) * (1 / (2 * h));
      expect_near(j.column[k], fd, 1e-8, str(p) + " column " + std::to_string(k));
    }
    // Virtual work: τ = Jᵀ F does the work F does, τ · δq = F · δp, along any joint motion.
    const JointArray tau = joint_torques(j, force);
    const std::array<double, 3> dq{0.3, -0.5, 0.8};
    std::vector<double> plus = q, minus = q;
    for (std::size_t k = 0; k < 3; ++k) plus[k] += h * dq[k], minus[k] -= h * dq[k];
    const Vec3 dp = (arm.position(plus) - arm.position(minus)) * (1 / (2 * h));
    EXPECT_NEAR(tau[0] * dq[0] + tau[1] * dq[1] + tau[2] * dq[2], dot(force, dp), 1e-8) << str(p);
  }
}

TEST(DeltaArm, ForwardIsDeterministicWhateverCameBefore) {
  const DeltaArm arm = falcon();
  const std::vector<double> q{0.31, -0.17, 0.52};
  const Vec3 first = arm.position(q);
  const Jacobian j1 = arm.jacobian(q);
  // Other points, near and far, and a failed solve in between.
  for (const Vec3 p : cube_grid(kCubeCentre, kReachableHalf, 4))
    if (const auto other = arm.inverse(p)) (void)arm.position(vec(*other));
  (void)arm.solve(std::vector<double>{-3, -3, -3});
  const Vec3 again = arm.position(q);
  const Jacobian j2 = arm.jacobian(q);
  EXPECT_EQ(std::memcmp(&first, &again, sizeof(Vec3)), 0);
  EXPECT_EQ(std::memcmp(j1.column.data(), j2.column.data(), 3 * sizeof(Vec3)), 0);
  // A copy of the model gives the same bits too (the servo holds it by value).
  const DeltaArm copy = arm;
  const Vec3 from_copy = copy.position(q);
  EXPECT_EQ(std::memcmp(&first, &from_copy, sizeof(Vec3)), 0);
}

TEST(DeltaArm, TheReachableCubeIsWellConditioned) {
  const DeltaArm arm = falcon();
  double worst = 0;
  for (const Vec3 p : cube_grid(kCubeCentre, kReachableHalf, 11)) {
    const auto q = arm.inverse(p);
    ASSERT_TRUE(q.has_value()) << str(p);
    const double cond = arm.condition_number(vec(*q));
    EXPECT_LT(cond, 20) << str(p);
    worst = std::max(worst, cond);
  }
  EXPECT_GE(worst, 1.0);
  // The centre itself is close to isotropic.
  const auto qc = arm.inverse(kCubeCentre);
  ASSERT_TRUE(qc.has_value());
  EXPECT_LT(arm.condition_number(vec(*qc)), 2);
}

TEST(DeltaArm, ThePublishedGeometryMissesTheFourInchCubesFarCorners) {
  // Marketing gives the Falcon a 4-inch cube; with libnifalcon's dimensions the legs reach about
  // 4 inches along each axis through the centre but not the cube's corners away from the motors.
  const DeltaArm arm = falcon();
  const double h = 2 * kInch;
  EXPECT_FALSE(arm.inverse(kCubeCentre + Vec3{h, h, h}).has_value());
  EXPECT_FALSE(arm.inverse(kCubeCentre + Vec3{-h, -h, h}).has_value());
  EXPECT_TRUE(arm.inverse(kCubeCentre + Vec3{h, 0, 0}).has_value());
  EXPECT_TRUE(arm.inverse(kCubeCentre + Vec3{0, -h, 0}).has_value());
  EXPECT_TRUE(arm.inverse(kCubeCentre + Vec3{0, 0, h}).has_value());
  EXPECT_TRUE(arm.inverse(kCubeCentre + Vec3{0, 0, -h + 0.001}).has_value());
}

TEST(DeltaArm, BaseOffsetMovesTheModel) {
  const Vec3 offset{0.01, -0.02, -0.111};
  const DeltaArm moved = falcon(offset), plain = falcon();
  const std::vector<double> q{0.2, 0.4, -0.1};
  expect_near(moved.position(q), plain.position(q) + offset, 1e-15, "position");
  expect_near(moved.centre(), plain.centre() + offset, 0, "centre");
  const auto a = moved.inverse(plain.position(q) + offset);
  ASSERT_TRUE(a.has_value());
  for (std::size_t i = 0; i < 3; ++i) EXPECT_NEAR((*a)[i], q[i], 1e-10);
  const Jacobian jm = moved.jacobian(q), jp = plain.jacobian(q);
  for (std::size_t i = 0; i < 3; ++i) expect_near(jm.column[i], jp.column[i], 1e-13, "jacobian");
  EXPECT_EQ(moved.forward(q).orientation, Quat{});
}

TEST(DeltaArm, ForwardWithoutASolutionGivesAFiniteBestGuess) {
  const DeltaArm arm = falcon();
  // The legs' tori are large next to the base, so some effector position fits almost any thigh
  // angles (even thighs turned right back); joints that are not numbers have none.
  EXPECT_TRUE(arm.solve(std::vector<double>{-3, -3, -3}).converged);
  const double nan = std::nan(""), inf = std::numeric_limits<double>::infinity();
  for (const std::vector<double>& q : {std::vector<double>{nan, 0.2, 0.2}, std::vector<double>{0.2, inf, 0.2}}) {
    const DeltaSolve s = arm.solve(q);
    EXPECT_FALSE(s.converged);
    EXPECT_GT(s.residual, DeltaArm::kTolerance);
    EXPECT_EQ(s.iterations, 0);
    EXPECT_EQ(s.position, arm.centre()) << "the start point, the best iterate";
    EXPECT_EQ(arm.condition_number(q), inf);
    const Vec3 again = arm.position(q);
    EXPECT_EQ(std::memcmp(&s.position, &again, sizeof(Vec3)), 0);
  }
  // Outside the reach: no inverse.
  EXPECT_FALSE(arm.inverse({0, 0, 0}).has_value());
  EXPECT_FALSE(arm.inverse({0.5, 0, 0.1}).has_value());
  EXPECT_FALSE(arm.inverse({0, 0, 0.3}).has_value());
  EXPECT_FALSE(arm.inverse({nan, 0, 0.1}).has_value());
}

TEST(DeltaArm, GeometryProblemsAreNamed) {
  const auto problem = [](auto&& change) {
    DeltaGeometry g = DeltaGeometry::novint_falcon();
    change(g);
    const char* p = delta_geometry_problem(g);
    return std::string(p == nullptr ? "" : p);
  };
  EXPECT_NE(problem([](DeltaGeometry& g) { g.a = 0; }).find("a (the thigh)"), std::string::npos);
  EXPECT_NE(problem([](DeltaGeometry& g) { g.b = -1; }).find("b (the shin)"), std::string::npos);
  EXPECT_NE(problem([](DeltaGeometry& g) { g.c = std::nan(""); }).find("not finite"), std::string::npos);
  EXPECT_NE(problem([](DeltaGeometry& g) { g.d = -0.001; }).find("d and e"), std::string::npos);
  EXPECT_NE(problem([](DeltaGeometry& g) { g.leg_angles[2] = g.leg_angles[0] + 2 * kPi; }).find("coincide"),
            std::string::npos);
  EXPECT_NE(problem([](DeltaGeometry& g) { g.f = 0.2; }).find("common axis"), std::string::npos);
  // Legs all on one side are not wrong as such; three legs 120° apart in any order are fine.
  EXPECT_EQ(problem([](DeltaGeometry& g) { g.leg_angles = {0, 120 * kDeg, 240 * kDeg}; }), "");
}

TEST(DeltaArm, ConditionNumberOfKnownMatrices) {
  Jacobian j;
  j.n = 3;
  j.column[0] = {2, 0, 0}, j.column[1] = {0, 2, 0}, j.column[2] = {0, 0, 2};
  EXPECT_NEAR(condition_number(j), 1, 1e-12);
  j.column[1] = {0, 0.5, 0};
  EXPECT_NEAR(condition_number(j), 4, 1e-12);
  j.column[2] = {0, 0, 1e-6};
  EXPECT_NEAR(condition_number(j) / 2e6, 1, 1e-9);
  j.column[2] = {1, 0.5, 0};  // in the plane of the other two
  EXPECT_EQ(condition_number(j), std::numeric_limits<double>::infinity());
  // A rotated diagonal keeps its condition number.
  const double c = std::cos(0.7), s = std::sin(0.7);
  j.column[0] = {3 * c, 3 * s, 0}, j.column[1] = {-1 * s, 1 * c, 0}, j.column[2] = {0, 0, 2};
  EXPECT_NEAR(condition_number(j), 3, 1e-12);
}

TEST(DeltaArm, NoAllocationOnTheRealTimePath) {
  const DeltaArm arm = falcon({0, 0, -0.111});
  const Kinematics kin(arm);
  const std::vector<double> q{0.3, 0.2, 0.4};
  double sink = 0;
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 50; ++i) {
    sink += arm.position(q).z + arm.jacobian(q).column[1].x + arm.condition_number(q);
    sink += arm.inverse({0.01, 0.02, 0.0}).value_or(std::array<double, 3>{})[2];
    Vec3 p{};
    sink += kin.position_and_jacobian(q, p).column[2].z + p.x + kin.forward(q).position.y;
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_TRUE(std::isfinite(sink));
}

TEST(DeltaArm, InsideKinematics) {
  const DeltaArm arm = falcon({0, 0, -0.111});
  const Kinematics kin(arm);
  EXPECT_EQ(kin.model(), KinematicModel::kDelta);
  EXPECT_EQ(model_name(kin.model()), "delta");
  EXPECT_EQ(kin.joint_count(), 3);
  ASSERT_NE(kin.delta(), nullptr);
  EXPECT_EQ(kin.phantom(), nullptr);
  EXPECT_EQ(kin.dh_chain(), nullptr);
  const std::vector<double> q{0.3, 0.2, 0.4};
  Vec3 p{};
  const Jacobian both = kin.position_and_jacobian(q, p);
  const Vec3 alone = kin.position(q);
  const Jacobian j = kin.jacobian(q);
  EXPECT_EQ(std::memcmp(&p, &alone, sizeof(Vec3)), 0);
  EXPECT_EQ(std::memcmp(both.column.data(), j.column.data(), sizeof(both.column)), 0);
  EXPECT_EQ(kin.forward(q).position, alone);
  // The device-frame origin is the cube's centre: the thighs at 16.98° put the tool there.
  const double t = 16.97566307268439 * kDeg;
  expect_near(kin.position(std::vector<double>{t, t, t}), {}, 1e-12, "origin");
}

// axes = "z_up": the same mechanism, its device frame turned so that z is up (device (x, y, z) =
// model (x, −z, y)) and the offset added after the turn; positions, Jacobian columns and the
// inverse all turn alike, and the shipped Falcon config puts the reachable cube's centre at the
// origin with the grip's travel toward the user along −y.
TEST(DeltaArm, TheZUpAxesTurnPositionsJacobiansAndTheInverse) {
  const DeltaArm model = falcon({0, 0, -0.111});
  const DeltaArm up(DeltaGeometry::novint_falcon(), {0, 0.111, 0}, DeltaAxes::kZUp);
  const auto turned = [](Vec3 v) { return Vec3{v.x, -v.z, v.y}; };
  for (const Vec3 p : cube_grid({}, kReachableHalf, 4)) {
    const auto q = model.inverse(p);
    ASSERT_TRUE(q) << str(p);
    expect_near(up.position(vec(*q)), turned(p), 1e-12, "position");
    const Jacobian jm = model.jacobian(vec(*q)), ju = up.jacobian(vec(*q));
    for (std::size_t i = 0; i < 3; ++i) expect_near(ju.column[i], turned(jm.column[i]), 1e-9, "column");
    const auto back = up.inverse(turned(p));
    ASSERT_TRUE(back);
    for (std::size_t i = 0; i < 3; ++i) EXPECT_NEAR((*back)[i], (*q)[i], 1e-12);
  }
  expect_near(up.centre(), turned(model.centre()), 1e-15, "centre");
  // The shipped config: the origin at the centre (all thighs at 16.98°), the grip pulled toward
  // the user (the model's +z) reads as −y.
  auto cfg = load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/novint_falcon.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  EXPECT_EQ(cfg.value().kinematics.delta_axes, DeltaAxes::kZUp);
  auto kin = make_kinematics(cfg.value());
  ASSERT_TRUE(kin.ok());
  const auto centre = kin.value().delta()->inverse({0, 0, 0});
  ASSERT_TRUE(centre);
  for (const double t : *centre) EXPECT_NEAR(t, 16.98 * kDeg, 0.01 * kDeg);
  const auto toward_user = kin.value().delta()->inverse({0, -0.02, 0});
  ASSERT_TRUE(toward_user);
  const auto q_model = model.inverse({0, 0, 0.02});
  ASSERT_TRUE(q_model);
  for (std::size_t i = 0; i < 3; ++i) EXPECT_NEAR((*toward_user)[i], (*q_model)[i], 1e-12);
}

}  // namespace
}  // namespace lancet::arm
