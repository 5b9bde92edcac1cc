// servo_step: a pure function of its model, data and input — the same inputs give bit-identical
// data and outputs, a ToolSample holds every input it needs, a reset starts a session afresh, it
// never allocates, and a model from the wire is checked before use.
#include "servo/servo_step.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>

#include "malloc_guard.hpp"  // tests/support
#include "patch_sheet.hpp"  // tests/support

namespace lancet::servo {
namespace {

// Stamped at the end of the scripts (2500 ticks from t = 1 s), so it never goes stale in them.
constexpr std::int64_t kPatchTime = 3'500'000'000;

std::unique_ptr<TissuePatch> plane_patch(std::int64_t t_ns) {
  auto p = std::make_unique<TissuePatch>();
  constexpr int n = 8;
  constexpr float half = 0.04f, s = 2 * half / n;
  test::add_sheet(*p, n, n, -half, -half, s, s, [](float x, float y) { return Vec3f{x, y, 0}; });
  p->seq = 1;
  p->t_ns = t_ns;
  return p;
}

// A hand that comes down onto the plane, presses, and (as a scalpel) cuts along x; one tick's input.
ServoInput scripted_input(std::uint64_t i, const TissuePatch* patch, std::vector<std::uint8_t>& commands) {
  ServoInput in;
  in.deadline_ns = 1'000'000'000 + static_cast<std::int64_t>(i) * 1'000'000;
  in.woke_ns = in.deadline_ns + 15'000;
  const double t = static_cast<double>(i) * 1e-3;
  const double z = std::max(-0.006, 0.01 - 0.02 * t), x = t > 1.0 ? 0.02 * (t - 1.0) : 0.0;
  in.reading.n = 3;
  in.reading.q = {x, 0.001, z};
  in.reading.qd = {t > 1.0 ? 0.02 : 0.0, 0.0, z > -0.006 ? -0.02 : 0.0};
  commands.clear();
  if (i == 10) commands.push_back(pack_command(CommandKind::kSetToolMode, ToolMode::kScalpel));
  in.commands = commands;
  in.patch = patch;
  in.patch_version = 2;
  in.viz_alive = true;
  return in;
}

ServoModel stylus_model() {
  ServoModel m;
  m.max_joint_torque.fill(0);
  m.max_joint_torque[0] = m.max_joint_torque[1] = m.max_joint_torque[2] = m.haptic.safety.max_force;
  return m;
}

TEST(ServoStep, TheSameInputsGiveBitIdenticalDataAndOutputs) {
  const ServoModel m = stylus_model();
  const auto patch = plane_patch(kPatchTime);
  ServoData a, b;
  ServoOutput oa, ob;
  std::vector<std::uint8_t> cmds;
  bool cut = false;
  for (std::uint64_t i = 1; i <= 2500; ++i) {
    const ServoInput in = scripted_input(i, patch.get(), cmds);
    servo_step(m, a, in, oa);
    servo_step(m, b, in, ob);
    ASSERT_EQ(state_hash(a), state_hash(b)) << "tick " << i;
    ASSERT_EQ(std::memcmp(&oa.sample, &ob.sample, sizeof oa.sample), 0) << "tick " << i;
    cut = cut || oa.sample.stage == Stage::kCutting;
  }
  EXPECT_TRUE(cut) << "the script cuts, so every tool path of the step ran";
  EXPECT_GT(a.contact_ticks, 1000u);
}

// What a ToolSample records is enough: feeding the samples back gives the same state, tick for tick.
TEST(ServoStep, TheSamplesItPublishesReplayIt) {
  const ServoModel m = stylus_model();
  const auto patch = plane_patch(kPatchTime);
  ServoData live, again;
  ServoOutput out, out2;
  std::vector<std::uint8_t> cmds;
  for (std::uint64_t i = 1; i <= 2500; ++i) {
    servo_step(m, live, scripted_input(i, patch.get(), cmds), out);
    ServoInput in = input_from_sample(out.sample);
    in.patch = patch.get();
    servo_step(m, again, in, out2);
    ASSERT_EQ(out.sample.state_hash, out2.sample.state_hash) << "tick " << i;
    ASSERT_EQ(state_hash(live), state_hash(again)) << "tick " << i;
    ASSERT_EQ(out.sample.force, out2.sample.force);
    if (i % kServoHashEvery == 0) {
      ASSERT_NE(out.sample.state_hash, 0u);
    } else {
      ASSERT_EQ(out.sample.state_hash, 0u);
    }
  }
}

// A reset starts a session: whatever came before, the state is that of a fresh servo.
TEST(ServoStep, AResetStartsAFreshSession) {
  const ServoModel m = stylus_model();
  const auto patch = plane_patch(kPatchTime);
  ServoData used;
  ServoOutput out;
  std::vector<std::uint8_t> cmds;
  for (std::uint64_t i = 1; i <= 1800; ++i) servo_step(m, used, scripted_input(i, patch.get(), cmds), out);
  ASSERT_GT(used.contact_ticks, 0u);
  ASSERT_EQ(used.mode, ToolMode::kScalpel);
  ServoData fresh;
  fresh.tick = used.tick;
  ServoInput in = scripted_input(1801, patch.get(), cmds);
  const std::uint8_t reset[] = {pack_command(CommandKind::kSetToolMode, ToolMode::kDrill), pack_command(CommandKind::kReset, ToolMode::kProbe)};
  in.commands = reset;
  ServoOutput o1, o2;
  servo_step(m, used, in, o1);
  servo_step(m, fresh, in, o2);
  EXPECT_EQ(state_hash(used), state_hash(fresh));
  EXPECT_EQ(used.mode, ToolMode::kDrill) << "the tool in hand stays through the reset";
  EXPECT_EQ(o1.sample.reset_mode, static_cast<std::uint8_t>(ToolMode::kDrill));
  EXPECT_LE(used.contact_ticks, 1u) << "counted afresh from the reset";
  EXPECT_EQ(o1.fade_scale, o2.fade_scale) << "a session's force ramps in afresh";
  servo_step(m, used, scripted_input(1802, patch.get(), cmds), o1);
  EXPECT_EQ(o1.sample.reset_mode, kNoReset);
}

TEST(ServoStep, NeverAllocates) {
  const ServoModel m = stylus_model();
  const auto patch = plane_patch(kPatchTime);
  ServoData d;
  ServoOutput out;
  std::vector<std::uint8_t> cmds;
  cmds.reserve(4);
  std::vector<ServoInput> inputs;
  std::vector<std::vector<std::uint8_t>> keep(2500);
  for (std::uint64_t i = 1; i <= 2500; ++i) inputs.push_back(scripted_input(i, patch.get(), keep[i - 1]));
  test::MallocGuard guard;
  for (const ServoInput& in : inputs) servo_step(m, d, in, out);
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_TRUE(std::isfinite(norm(d.force)));
  EXPECT_LE(norm(d.force), m.haptic.safety.max_force);
}

// A fault in the reading or the watchdog means zero force, and each is counted.
TEST(ServoStep, NoReadingOrATrippedWatchdogMeansZeroForce) {
  const ServoModel m = stylus_model();
  const auto patch = plane_patch(kPatchTime);
  ServoData d;
  ServoOutput out;
  std::vector<std::uint8_t> cmds;
  for (std::uint64_t i = 1; i <= 1200; ++i) {
    ServoInput in = scripted_input(i, patch.get(), cmds);
    in.commands = {};  // the probe: pressing 6 mm deep
    servo_step(m, d, in, out);
  }
  ASSERT_GT(norm(d.force), 0.5);
  ServoInput in = scripted_input(1201, patch.get(), cmds);
  in.read_status = device::IoStatus::kTimeout;
  servo_step(m, d, in, out);
  EXPECT_EQ(d.force, Vec3{});
  EXPECT_NE(out.sample.events & event::kFault, 0u);
  EXPECT_EQ(d.device_error_ticks, 1u);
  in = scripted_input(1202, patch.get(), cmds);
  in.watchdog_tripped = true;
  servo_step(m, d, in, out);
  EXPECT_EQ(d.force, Vec3{});
  EXPECT_EQ(d.watchdog_faulted_ticks, 1u);
  // A re-arm in the same tick lets the force through again (and asks the caller to re-arm).
  const std::uint8_t rearm[] = {pack_command(CommandKind::kRearm, ToolMode::kProbe)};
  in = scripted_input(1203, patch.get(), cmds);
  in.watchdog_tripped = true;
  in.commands = rearm;
  servo_step(m, d, in, out);
  EXPECT_TRUE(out.rearm);
  EXPECT_GT(norm(d.force), 0.0);
}

TEST(ServoStep, AModelFromTheWireIsCheckedBeforeUse) {
  const ServoModel m = stylus_model();
  auto back = model_from_blob(to_blob(m));
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(std::memcmp(&back.value(), &m, sizeof m), 0);
  ServoModelBlob b = to_blob(m);
  b.layout ^= 1;
  auto r = model_from_blob(b);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kMismatch);
  b = to_blob(m);
  b.size = 12;
  EXPECT_FALSE(model_from_blob(b).ok());
  ServoModel bad = m;
  bad.haptic.materials[3].stiffness = std::nan("");
  r = model_from_blob(to_blob(bad));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("materials[3]"), std::string::npos) << r.error().message;
  bad = m;
  bad.period_ns = 0;
  r = model_from_blob(to_blob(bad));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("period_ns"), std::string::npos) << r.error().message;
  // A bool that is not 0 or 1 (a corrupted or hostile blob) is refused before it is read.
  b = to_blob(m);
  b.bytes[offsetof(ServoModel, haptic) + offsetof(haptics::HapticModel, safety) + offsetof(haptics::SafetyParams, passivity)] = 2;
  r = model_from_blob(b);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("passivity"), std::string::npos) << r.error().message;
  // The passivity controller's damping bound: finite and > 0.
  for (const double damping : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity()}) {
    bad = m;
    bad.haptic.safety.max_passivity_damping = damping;
    r = model_from_blob(to_blob(bad));
    ASSERT_FALSE(r.ok()) << damping;
    EXPECT_NE(r.error().message.find("max_passivity_damping"), std::string::npos) << r.error().message;
  }
  // A kinematic chain whose joint count was scribbled over: refused, never looped over.
  b = to_blob(m);
  const std::size_t at = offsetof(ServoModel, kinematics);
  std::memset(b.bytes + at, 0x7f, sizeof(arm::Kinematics));
  r = model_from_blob(b);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("kinematics"), std::string::npos) << r.error().message;
}

// The Falcon's delta kinematics in the step: the hand's path in the device frame, read back as
// thigh angles (the inverse), senses the same tool point and steps bit-identically twice; the
// model round-trips through the wire and a delta geometry scribbled into it is refused.
TEST(ServoStep, ADeltaArmSensesThroughItsKinematics) {
  ServoModel m = stylus_model();
  const arm::DeltaArm falcon(arm::DeltaGeometry::novint_falcon(), {0, 0, -0.111});
  m.kinematics = arm::Kinematics(falcon);
  m.max_joint_torque[0] = m.max_joint_torque[1] = m.max_joint_torque[2] = 1.0;
  const auto patch = plane_patch(kPatchTime);
  ServoData a, b;
  ServoOutput oa, ob;
  std::vector<std::uint8_t> cmds;
  for (std::uint64_t i = 1; i <= 1500; ++i) {
    ServoInput in = scripted_input(i, patch.get(), cmds);
    const Vec3 p{in.reading.q[0], in.reading.q[1], in.reading.q[2]};
    const auto q = falcon.inverse(p);
    ASSERT_TRUE(q.has_value()) << "tick " << i;
    in.reading.q = {(*q)[0], (*q)[1], (*q)[2]};
    in.reading.qd = {};
    servo_step(m, a, in, oa);
    servo_step(m, b, in, ob);
    ASSERT_EQ(state_hash(a), state_hash(b)) << "tick " << i;
    ASSERT_EQ(std::memcmp(&oa.sample, &ob.sample, sizeof oa.sample), 0) << "tick " << i;
    ASSERT_NEAR(norm(a.tool - p), 0.0, 1e-9) << "tick " << i;
    ASSERT_EQ(oa.command.n, 3);
  }
  EXPECT_GT(a.contact_ticks, 100u);
  EXPECT_GT(std::abs(oa.command.tau[0]) + std::abs(oa.command.tau[1]) + std::abs(oa.command.tau[2]), 0.0);
  auto back = model_from_blob(to_blob(m));
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back.value().kinematics.model(), arm::KinematicModel::kDelta);
  arm::DeltaGeometry coincident = arm::DeltaGeometry::novint_falcon();
  coincident.leg_angles[2] = coincident.leg_angles[0];
  m.kinematics = arm::Kinematics(arm::DeltaArm(coincident));
  auto r = model_from_blob(to_blob(m));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("kinematics (delta)"), std::string::npos) << r.error().message;
}

}  // namespace
}  // namespace lancet::servo
