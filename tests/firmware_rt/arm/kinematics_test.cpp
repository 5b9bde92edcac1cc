// Kinematics: DH chains and the closed-form PHANToM arm against numerical differentiation of their
// own forward kinematics, against each other where they coincide, Jᵀ·F against virtual work, and
// no allocation on the real-time path.

#include "arm/kinematics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "malloc_guard.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace lancet::arm {
namespace {

constexpr double kPi = std::numbers::pi;

std::vector<double> random_q(std::mt19937& rng, const DhChain& chain) {
  std::uniform_real_distribution<double> angle(-kPi, kPi), slide(-0.2, 0.2);
  std::vector<double> q;
  for (const DhLink& l : chain.links()) q.push_back(l.type == JointType::kRevolute ? angle(rng) : slide(rng));
  return q;
}

DhChain random_chain(std::mt19937& rng, int n) {
  std::uniform_real_distribution<double> len(-0.3, 0.3), ang(-kPi, kPi);
  std::bernoulli_distribution prismatic(0.25);
  std::vector<DhLink> links;
  for (int i = 0; i < n; ++i) {
    links.push_back({prismatic(rng) ? JointType::kPrismatic : JointType::kRevolute, len(rng), ang(rng), len(rng), ang(rng)});
  }
  return DhChain(links, Vec3{len(rng), len(rng), len(rng)}, Vec3{len(rng), len(rng), len(rng)});
}

// Central difference of a position function along joint j.
template <class F>
Vec3 central_difference(F&& position, std::vector<double> q, std::size_t j, double h = 1e-6) {
  const double q0 = q[j];
  q[j] = q0 + h;
  const Vec3 plus = position(q);
  q[j] = q0 - h;
  const Vec3 minus = position(q);
  return (1.0 / (2 * h)) * (plus - minus);
}

void expect_near(Vec3 a, Vec3 b, double tol, const std::string& what) {
  EXPECT_NEAR(a.x, b.x, tol) << what;
  EXPECT_NEAR(a.y, b.y, tol) << what;
  EXPECT_NEAR(a.z, b.z, tol) << what;
}

TEST(DhChain, PlanarTwoLinkMatchesClosedForm) {
  const double l1 = 0.3, l2 = 0.2;
  const std::vector<DhLink> links{{JointType::kRevolute, l1, 0, 0, 0}, {JointType::kRevolute, l2, 0, 0, 0}};
  const DhChain chain(links);
  for (const auto& [a, b] : std::vector<std::pair<double, double>>{{0, 0}, {0.5, -1.1}, {2.0, 2.5}}) {
    const std::vector<double> q{a, b};
    const Vec3 p = chain.position(q);
    expect_near(p, {l1 * std::cos(a) + l2 * std::cos(a + b), l1 * std::sin(a) + l2 * std::sin(a + b), 0}, 1e-14,
                "planar 2R");
    const Jacobian j = chain.jacobian(q);
    expect_near(j.column[1], {-l2 * std::sin(a + b), l2 * std::cos(a + b), 0}, 1e-14, "column 2");
  }
}

TEST(DhChain, PrismaticJointSlidesAlongPreviousZ) {
  // Yaw about z, then a prismatic joint along the (tilted) z1 axis.
  const std::vector<DhLink> links{{JointType::kRevolute, 0.1, kPi / 2, 0.05, 0}, {JointType::kPrismatic, 0, 0, 0.02, 0}};
  const DhChain chain(links);
  const std::vector<double> q{kPi / 2, 0.03};
  // Frame 1: origin (0, 0.1, 0.05), z1 = Rot_z(90°)·(0, -1, 0) = (1, 0, 0); slide 0.02 + 0.03 along it.
  expect_near(chain.position(q), {0.05, 0.1, 0.05}, 1e-14, "prismatic");
  expect_near(chain.jacobian(q).column[1], {1, 0, 0}, 1e-14, "prismatic column");
}

TEST(DhChain, JacobianMatchesCentralDifferenceForOneToSevenJoints) {
  std::mt19937 rng(20240611);
  for (int n = 1; n <= 7; ++n) {
    for (int trial = 0; trial < 20; ++trial) {
      const DhChain chain = random_chain(rng, n);
      const std::vector<double> q = random_q(rng, chain);
      const Jacobian j = chain.jacobian(q);
      ASSERT_EQ(j.n, n);
      for (int k = 0; k < n; ++k) {
        const Vec3 fd = central_difference([&](const std::vector<double>& x) { return chain.position(x); }, q,
                                           static_cast<std::size_t>(k));
        expect_near(j.column[static_cast<std::size_t>(k)], fd, 1e-8,
                    "n=" + std::to_string(n) + " trial " + std::to_string(trial) + " column " + std::to_string(k));
      }
      for (std::size_t k = static_cast<std::size_t>(n); k < static_cast<std::size_t>(kMaxJoints); ++k) {
        EXPECT_EQ(j.column[k], Vec3{}) << "unused columns are zero";
      }
    }
  }
}

TEST(DhChain, EightJointsAtTheLimit) {
  std::mt19937 rng(8);
  const DhChain chain = random_chain(rng, kMaxJoints);
  const std::vector<double> q = random_q(rng, chain);
  const Jacobian j = chain.jacobian(q);
  ASSERT_EQ(j.n, kMaxJoints);
  const Vec3 fd = central_difference([&](const std::vector<double>& x) { return chain.position(x); }, q, 7);
  expect_near(j.column[7], fd, 1e-8, "last column");
}

TEST(DhChain, AngularJacobianMatchesRotationDerivative) {
  std::mt19937 rng(77);
  for (int n = 1; n <= 7; ++n) {
    const DhChain chain = random_chain(rng, n);
    std::vector<double> q = random_q(rng, chain);
    const SpatialJacobian s = chain.spatial_jacobian(q);
    const Transform t0 = chain.forward_transform(q);
    for (std::size_t k = 0; k < static_cast<std::size_t>(n); ++k) {
      // Ṙ Rᵀ = [ω]ₓ: take the skew part's vector.
      const double h = 1e-6, qk = q[k];
      q[k] = qk + h;
      const auto rp = chain.forward_transform(q).r;
      q[k] = qk - h;
      const auto rm = chain.forward_transform(q).r;
      q[k] = qk;
      std::array<double, 9> w{};
      for (std::size_t a = 0; a < 3; ++a) {
        for (std::size_t b = 0; b < 3; ++b) {
          for (std::size_t c = 0; c < 3; ++c) w[3 * a + b] += (rp[3 * a + c] - rm[3 * a + c]) / (2 * h) * t0.r[3 * b + c];
        }
      }
      expect_near(s.angular[k], {w[7], w[2], w[3]}, 1e-8, "angular column " + std::to_string(k));
      expect_near(s.linear[k], chain.jacobian(q).column[k], 0, "linear part is jacobian()");
    }
  }
}

TEST(DhChain, ForwardPoseQuaternionMatchesRotationMatrix) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 200; ++trial) {
    const DhChain chain = random_chain(rng, 1 + trial % 7);
    const std::vector<double> q = random_q(rng, chain);
    const Transform t = chain.forward_transform(q);
    const Pose p = chain.forward(q);
    expect_near(p.position, t.p, 0, "position");
    EXPECT_NEAR(p.orientation.w * p.orientation.w + p.orientation.x * p.orientation.x +
                    p.orientation.y * p.orientation.y + p.orientation.z * p.orientation.z,
                1.0, 1e-12);
    const Vec3 v{u(rng), u(rng), u(rng)};
    expect_near(rotate(p.orientation, v), apply(Transform{t.r, {}}, v), 1e-12, "rotation");
  }
  // Half turns about each axis take the non-trace branches of the conversion.
  for (const auto& r : {std::array<double, 9>{1, 0, 0, 0, -1, 0, 0, 0, -1}, std::array<double, 9>{-1, 0, 0, 0, 1, 0, 0, 0, -1},
                        std::array<double, 9>{-1, 0, 0, 0, -1, 0, 0, 0, 1}}) {
    const Quat qt = to_quat(r);
    const Vec3 v{0.3, -0.7, 0.2};
    expect_near(rotate(qt, v), apply(Transform{r, {}}, v), 1e-12, "half turn");
  }
}

TEST(PhantomArm, HomePoseAndAxes) {
  const PhantomArm arm{0.2, 0.15, {}};
  expect_near(arm.position(std::vector<double>{0, 0, 0}), {0.2, 0, -0.15}, 1e-15, "home");
  // Yaw 90°: the reach turns to +y.
  expect_near(arm.position(std::vector<double>{kPi / 2, 0, 0}), {0, 0.2, -0.15}, 1e-15, "yaw");
  // Shoulder up 90°: the upper arm is vertical, the elbow above the shoulder.
  expect_near(arm.position(std::vector<double>{0, kPi / 2, 0}), {0, 0, 0.2 - 0.15}, 1e-15, "shoulder");
  // Elbow +90° (absolute): the forearm points outward, horizontal.
  expect_near(arm.position(std::vector<double>{0, 0, kPi / 2}), {0.35, 0, 0}, 1e-15, "elbow");
  const PhantomArm homed{0.2, 0.15, {-0.2, 0, 0.15}};
  expect_near(homed.position(std::vector<double>{0, 0, 0}), {}, 1e-15, "base_offset puts home at the origin");
  EXPECT_EQ(homed.forward(std::vector<double>{0.1, 0.2, 0.3}).orientation, Quat{});
}

TEST(PhantomArm, JacobianMatchesCentralDifference) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> angle(-kPi, kPi), len(0.05, 0.4);
  for (int trial = 0; trial < 200; ++trial) {
    const PhantomArm arm{len(rng), len(rng), {len(rng), -len(rng), len(rng)}};
    const std::vector<double> q{angle(rng), angle(rng), angle(rng)};
    const Jacobian j = arm.jacobian(q);
    ASSERT_EQ(j.n, 3);
    for (std::size_t k = 0; k < 3; ++k) {
      const Vec3 fd = central_difference([&](const std::vector<double>& x) { return arm.position(x); }, q, k);
      expect_near(j.column[k], fd, 1e-8, "column " + std::to_string(k));
    }
  }
}

TEST(PhantomArm, EqualsItsDhChainEquivalent) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> angle(-kPi, kPi), len(0.05, 0.4);
  for (int trial = 0; trial < 200; ++trial) {
    const PhantomArm arm{len(rng), len(rng), {len(rng), len(rng), -len(rng)}};
    const DhChain chain = arm.to_dh_chain();
    ASSERT_EQ(chain.joint_count(), 3);
    const std::vector<double> q{angle(rng), angle(rng), angle(rng)};
    const auto qd = PhantomArm::to_dh_joints(q);
    expect_near(arm.position(q), chain.position(qd), 1e-14, "position");
    // q_dh = M q with M = [1 0 0; 0 1 0; 0 -1 1], so J_phantom = J_dh M.
    const Jacobian jp = arm.jacobian(q);
    const Jacobian jd = chain.jacobian(qd);
    expect_near(jp.column[0], jd.column[0], 1e-14, "yaw column");
    expect_near(jp.column[1], jd.column[1] - jd.column[2], 1e-14, "shoulder column");
    expect_near(jp.column[2], jd.column[2], 1e-14, "elbow column");
  }
}

TEST(JointTorques, TransposeMatchesVirtualWork) {
  // τ·dq = F·dx for a small joint motion dq (central difference of the tool point along dq).
  std::mt19937 rng(99);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int n = 1; n <= 7; ++n) {
    for (int trial = 0; trial < 10; ++trial) {
      const DhChain chain = random_chain(rng, n);
      std::vector<double> q = random_q(rng, chain);
      std::vector<double> dq(q.size());
      for (double& x : dq) x = u(rng);
      const Vec3 force{10 * u(rng), 10 * u(rng), 10 * u(rng)};
      const JointArray tau = joint_torques(chain.jacobian(q), force);
      double power = 0;
      for (std::size_t k = 0; k < q.size(); ++k) power += tau[k] * dq[k];
      const double h = 1e-6;
      std::vector<double> qp = q, qm = q;
      for (std::size_t k = 0; k < q.size(); ++k) {
        qp[k] += h * dq[k];
        qm[k] -= h * dq[k];
      }
      const Vec3 dx = (1.0 / (2 * h)) * (chain.position(qp) - chain.position(qm));
      EXPECT_NEAR(power, dot(force, dx), 1e-6) << "n=" << n;
      for (std::size_t k = q.size(); k < static_cast<std::size_t>(kMaxJoints); ++k) EXPECT_EQ(tau[k], 0.0);
    }
  }
  const PhantomArm arm{0.21, 0.21, {}};
  const std::vector<double> q{0.3, -0.2, 0.4}, dq{0.5, -1, 0.25};
  const Vec3 force{1, -2, 3};
  const JointArray tau = joint_torques(arm.jacobian(q), force);
  const double h = 1e-6;
  std::vector<double> qp = q, qm = q;
  for (std::size_t k = 0; k < 3; ++k) {
    qp[k] += h * dq[k];
    qm[k] -= h * dq[k];
  }
  const Vec3 dx = (1.0 / (2 * h)) * (arm.position(qp) - arm.position(qm));
  EXPECT_NEAR(tau[0] * dq[0] + tau[1] * dq[1] + tau[2] * dq[2], dot(force, dx), 1e-7);
}

TEST(JointTorques, SpatialAddsTheMoment) {
  std::mt19937 rng(4);
  const DhChain chain = random_chain(rng, 5);
  const std::vector<double> q = random_q(rng, chain);
  const SpatialJacobian s = chain.spatial_jacobian(q);
  const Vec3 f{1, 2, 3}, m{-0.5, 0.25, 0.1};
  const JointArray linear = joint_torques(chain.jacobian(q), f);
  const JointArray both = joint_torques(s, f, m);
  for (std::size_t k = 0; k < 5; ++k) EXPECT_NEAR(both[k], linear[k] + dot(s.angular[k], m), 1e-15);
}

TEST(Kinematics, RealTimePathDoesNotAllocate) {
  std::mt19937 rng(1);
  const DhChain chain = random_chain(rng, kMaxJoints);
  const std::vector<double> q = random_q(rng, chain);
  const Kinematics dh(chain);
  const Kinematics ph(PhantomArm{0.2, 0.2, {}});
  const std::vector<double> q3{0.1, 0.2, 0.3};
  double sink = 0;
  lancet::test::MallocGuard guard;
  for (int i = 0; i < 100; ++i) {
    sink += dh.position(q).x + dh.forward(q).orientation.w + joint_torques(dh.jacobian(q), {1, 2, 3})[7];
    sink += joint_torques(chain.spatial_jacobian(q), {1, 2, 3}, {0, 0, 1})[0];
    sink += ph.position(q3).z + ph.forward(q3).position.x + joint_torques(ph.jacobian(q3), {0, 0, -1})[2];
  }
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_TRUE(std::isfinite(sink));
}

TEST(Kinematics, FromShippedConfigs) {
  const std::string dir = std::string(LANCET_SOURCE_DIR) + "/hw_configs/";
  struct Case {
    const char* file;
    KinematicModel model;
    int joints;
  };
  for (const Case& c : {Case{"sim_3dof.toml", KinematicModel::kPhantom, 3}, Case{"usb_arm.toml", KinematicModel::kPhantom, 3},
                        Case{"modbus_tcp_arm.toml", KinematicModel::kDh, 3},
                        Case{"canopen_arm.toml", KinematicModel::kDh, 4}}) {
    SCOPED_TRACE(c.file);
    auto config = load_arm_config(dir + c.file);
    ASSERT_TRUE(config.ok()) << config.error().message;
    auto k = make_kinematics(config.value());
    ASSERT_TRUE(k.ok()) << k.error().message;
    const Kinematics& kin = k.value();
    EXPECT_EQ(kin.model(), c.model);
    ASSERT_EQ(kin.joint_count(), c.joints);
    // Mid-range joint values: the Jacobian still matches the config model's own FK.
    std::vector<double> q;
    for (const JointConfig& j : config.value().joints) q.push_back(0.5 * (j.min + j.max) + 0.1 * (j.max - j.min));
    const Jacobian jac = kin.jacobian(q);
    for (std::size_t i = 0; i < q.size(); ++i) {
      const Vec3 fd = central_difference([&](const std::vector<double>& x) { return kin.position(x); }, q, i);
      expect_near(jac.column[i], fd, 1e-8, "column " + std::to_string(i));
    }
  }
  // The PHANToM configs put their home pose at the origin.
  auto sim = load_arm_config(dir + "sim_3dof.toml");
  ASSERT_TRUE(sim.ok());
  auto k = make_kinematics(sim.value());
  ASSERT_TRUE(k.ok());
  expect_near(k.value().position(std::vector<double>{0, 0, 0}), {}, 1e-12, "sim home");
  ASSERT_NE(k.value().phantom(), nullptr);
  EXPECT_NEAR(k.value().phantom()->l1, 0.20955, 1e-12);
  EXPECT_EQ(k.value().dh_chain(), nullptr);
  // The laparoscopic arm: at q = 0 the shaft points straight down from the pivot, tip 40 + 12 mm down.
  auto lap = load_arm_config(dir + "canopen_arm.toml");
  ASSERT_TRUE(lap.ok());
  auto kl = make_kinematics(lap.value());
  ASSERT_TRUE(kl.ok());
  expect_near(kl.value().position(std::vector<double>{0, 0, 0, 0}), {0, 0, -0.052}, 1e-12, "lap home");
  expect_near(kl.value().position(std::vector<double>{0, 0, 0.1, 1.0}), {0, 0, -0.152}, 1e-12, "insertion");
}

TEST(Kinematics, MakeKinematicsRejectsBrokenHandBuiltConfigs) {
  ArmConfig c;
  c.kinematics.model = KinematicModel::kPhantom;
  c.kinematics.l1 = 0.1;
  c.kinematics.l2 = 0;
  auto r = make_kinematics(c);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
  EXPECT_NE(r.error().message.find("l2"), std::string::npos);
  c.kinematics.model = KinematicModel::kDh;
  EXPECT_FALSE(make_kinematics(c).ok()) << "no links";
  c.kinematics.links.assign(static_cast<std::size_t>(kMaxJoints) + 1, DhLink{});
  EXPECT_FALSE(make_kinematics(c).ok()) << "too many links";
  c.kinematics.links.assign(2, DhLink{});
  c.kinematics.links[1].a = std::nan("");
  EXPECT_FALSE(make_kinematics(c).ok()) << "non-finite parameter";
  c.kinematics.links[1].a = 0.1;
  auto ok = make_kinematics(c);
  ASSERT_TRUE(ok.ok());
  EXPECT_EQ(ok.value().joint_count(), 2);
  // A delta geometry: the Falcon's builds; one whose shins cannot reach the legs' axis does not.
  c.kinematics.model = KinematicModel::kDelta;
  c.kinematics.delta = DeltaGeometry::novint_falcon();
  c.kinematics.base_offset = {0, 0, -0.111};
  EXPECT_EQ(c.kinematics.joint_count(), 3);
  auto delta = make_kinematics(c);
  ASSERT_TRUE(delta.ok()) << delta.error().message;
  ASSERT_NE(delta.value().delta(), nullptr);
  EXPECT_EQ(delta.value().delta()->base_offset().z, -0.111);
  c.kinematics.delta.b = 0.001;  // shorter than |f − s|
  auto bad = make_kinematics(c);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code, ErrorCode::kInvalid);
  EXPECT_NE(bad.error().message.find("kinematics (delta)"), std::string::npos) << bad.error().message;
  c.kinematics.delta = DeltaGeometry::novint_falcon();
  c.kinematics.base_offset.x = std::nan("");
  EXPECT_FALSE(make_kinematics(c).ok()) << "non-finite base offset";
}

TEST(Kinematics, ModelNames) {
  EXPECT_EQ(model_name(KinematicModel::kDh), "dh");
  EXPECT_EQ(model_name(KinematicModel::kPhantom), "phantom");
  EXPECT_EQ(model_name(KinematicModel::kCartesian), "cartesian");
  EXPECT_EQ(model_name(KinematicModel::kDelta), "delta");
}

TEST(Kinematics, PositionAndJacobianIsBothCallsInOne) {
  const std::vector<DhLink> links{{JointType::kRevolute, 0.3, 0.4, 0.1, 0}, {JointType::kPrismatic, 0.1, 0, 0.02, 0.3}};
  const std::vector<double> q2{0.4, 0.05}, q3{0.1, 0.2, 0.3};
  for (const auto& [kin, q] : {std::pair{Kinematics(DhChain(links)), q2}, std::pair{Kinematics(PhantomArm{0.2, 0.2, {}}), q3},
                               std::pair{Kinematics::cartesian(), q3},
                               std::pair{Kinematics(DeltaArm(DeltaGeometry::novint_falcon())), q3}}) {
    SCOPED_TRACE(std::string(model_name(kin.model())));
    Vec3 p{};
    const Jacobian both = kin.position_and_jacobian(q, p);
    const Jacobian j = kin.jacobian(q);
    const Vec3 alone = kin.position(q);
    EXPECT_EQ(p, alone);
    EXPECT_EQ(both.n, j.n);
    for (std::size_t i = 0; i < static_cast<std::size_t>(j.n); ++i) EXPECT_EQ(both.column[i], j.column[i]);
  }
}

}  // namespace
}  // namespace lancet::arm
