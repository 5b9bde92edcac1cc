// wire::check: what a peer wrote into the segment is checked before use. Valid messages pass;
// each kind of damage (not finite, out of range, unknown enum, capacity exceeded, from the future,
// unterminated or unprintable text, a check word that does not match) is caught; random bytes
// never pass for a command or an operator request.

#include "lancet/shared_model/validate.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>

namespace lancet::wire {
namespace {

constexpr std::int64_t kNow = 50'000'000'000;
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

Command good_command() {
  Command c{};
  c.seq = 3;
  c.t_ns = kNow;
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kDrill;
  seal(c);
  return c;
}

std::unique_ptr<TissuePatch> good_patch() {
  auto p = std::make_unique<TissuePatch>();
  p->t_ns = kNow - 1'000'000;
  p->n_triangles = 2;
  p->triangles[0] = {{{0, 0, 0}, {0.01f, 0, 0}, {0, 0.01f, 0}}, 1, kTriangleOnCutEdge, 0};
  p->triangles[1] = {{{0, 0, 0}, {0.01f, 0.01f, 0}, {0, 0.01f, 0}}, 2, 0, 1};
  p->brick.valid = 1;
  p->brick.dim = kBrickDim;
  p->brick.spacing = {0.0005, 0.0005, 0.001};
  return p;
}

TEST(WireCheck, ValidMessagesPass) {
  EXPECT_EQ(check(good_command()), nullptr);
  EXPECT_EQ(check(*good_patch(), kNow), nullptr);
  StylusTarget t{};
  t.t_ns = kNow;
  t.active = 1;
  t.target.position = {0.01, -0.02, 0.03};
  EXPECT_EQ(check(t, kNow), nullptr);
  ToolSample s{};
  s.n_joints = 3;
  s.events = event::kRupture | event::kFault;
  s.stage = Stage::kDrilling;
  EXPECT_EQ(check(s), nullptr);
  RtStatus st{};
  st.period_ns = 1'000'000;
  st.hands = 2;
  st.hand[0].force_scale = 1;
  st.hand[1].device_state = DeviceLifecycle::kFault;
  std::strcpy(st.hand[1].fault_text, "node 1: EMCY 0x2310 continuous over-current");
  EXPECT_EQ(check(st), nullptr);
  OperatorRequest r{};
  r.seq = 9;
  r.t_ns = kNow;
  r.kind = kOperatorRearm;
  r.hands = 0b10;
  seal(r);
  EXPECT_EQ(check(r, kNow), nullptr);
}

// Two hands: every message that names a hand names one that exists (left or right), and an
// operator request names at least one.
TEST(WireCheck, HandsMustBeRightOrLeft) {
  const auto bad_hand = static_cast<Hand>(2);
  Command c = good_command();
  c.hand = Hand::kLeft;
  seal(c);
  EXPECT_EQ(check(c), nullptr);
  c.hand = bad_hand;
  seal(c);
  EXPECT_STREQ(check(c), "command.hand: neither right nor left");

  StylusTarget t{};
  t.t_ns = kNow;
  t.active = 1;
  t.hand = Hand::kLeft;
  EXPECT_EQ(check(t, kNow), nullptr);
  std::memset(&t.hand, 0xff, 1);
  EXPECT_STREQ(check(t, kNow), "stylus_target.hand: neither right nor left");

  auto p = good_patch();
  p->hand = Hand::kLeft;
  EXPECT_EQ(check(*p, kNow), nullptr);
  p->hand = bad_hand;
  EXPECT_STREQ(check(*p, kNow), "patch.hand: neither right nor left");

  ToolSample s{};
  s.hand = Hand::kLeft;
  EXPECT_EQ(check(s), nullptr);
  s.hand = bad_hand;
  EXPECT_STREQ(check(s), "sample.hand: neither right nor left");

  OperatorRequest r{};
  r.seq = 1;
  r.t_ns = kNow;
  r.kind = kOperatorRearm;
  for (const std::uint8_t hands : {0b01, 0b10, 0b11}) {
    r.hands = hands;
    seal(r);
    EXPECT_EQ(check(r, kNow), nullptr) << int{hands};
  }
  for (const std::uint8_t hands : {0b000, 0b100, 0b101, 0xff}) {
    r.hands = hands;
    seal(r);
    EXPECT_STREQ(check(r, kNow), "operator_request.hands: no hand, or an unknown one") << int{hands};
  }
  r.hands = 0b01;
  seal(r);
  r.hands = 0b11;  // changed after sealing: which hands is covered by the check
  EXPECT_NE(check(r, kNow), nullptr);

  RtStatus st{};
  st.period_ns = 1'000'000;
  for (const std::uint32_t hands : {0u, 3u, 0xffffffffu}) {
    st.hands = hands;
    EXPECT_STREQ(check(st), "rt_status.hands: not 1 or 2") << hands;
  }
  st.hands = 1;
  EXPECT_EQ(check(st), nullptr);
  // Every HandStatus is checked, the unused one too (its bytes are printed like the others).
  st.hand[1].force = {kNan, 0, 0};
  EXPECT_NE(check(st), nullptr);
  st.hand[1].force = {};
  std::memset(&st.hand[1].mode, 40, 1);
  EXPECT_STREQ(check(st), "rt_status.hand[].mode: unknown tool");
}

TEST(WireCheck, CommandsMustBeSealedKnownAndPhysical) {
  Command c = good_command();
  c.mode = ToolMode::kProbe;  // changed after sealing
  EXPECT_NE(check(c), nullptr);
  c = good_command();
  c.mode = static_cast<ToolMode>(9);
  seal(c);
  EXPECT_NE(check(c), nullptr);
  c = good_command();
  c.kind = static_cast<CommandKind>(77);
  seal(c);
  EXPECT_NE(check(c), nullptr);
  c = good_command();
  c.kind = static_cast<CommandKind>(2);  // a number no kind has
  seal(c);
  EXPECT_NE(check(c), nullptr);
}

TEST(WireCheck, RandomBytesNeverPassForACommandOrAnOperatorRequest) {
  std::mt19937_64 rng(11);
  int passed = 0;
  for (int i = 0; i < 200'000; ++i) {
    Command c;
    OperatorRequest r;
    for (auto* p : {static_cast<void*>(&c), static_cast<void*>(&r)}) {
      const std::size_t n = p == &c ? sizeof c : sizeof r;
      for (std::size_t k = 0; k < n; ++k) static_cast<unsigned char*>(p)[k] = static_cast<unsigned char>(rng());
    }
    passed += check(c) == nullptr;
    passed += check(r, kNow) == nullptr;
  }
  EXPECT_EQ(passed, 0);
}

TEST(WireCheck, PatchDamageIsCaught) {
  auto p = good_patch();
  p->n_triangles = kPatchCapacity + 1;
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->triangles[1].v[2].y = std::numeric_limits<float>::infinity();
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->triangles[0].v[0].x = 1e6f;  // a kilometre away
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->triangles[0].material = 999;
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->triangles[0].flags = 0x8000;
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->t_ns = kNow + 1'000'000'000;  // from the future: would never go stale
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->t_ns = 0;
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->brick.dim = 300;
  EXPECT_NE(check(*p, kNow), nullptr);
  p = good_patch();
  p->brick.spacing.z = -1;
  EXPECT_NE(check(*p, kNow), nullptr);
  // Triangles past n_triangles are not the patch: garbage there is fine.
  p = good_patch();
  p->triangles[5].v[0].x = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(check(*p, kNow), nullptr);
}

TEST(WireCheck, SampleAndStatusDamageIsCaughtBeforeAnythingIsPrinted) {
  ToolSample s{};
  s.n_joints = 9;
  EXPECT_NE(check(s), nullptr);
  s = ToolSample{};
  s.n_joints = 2;
  s.q[1] = kNan;
  EXPECT_NE(check(s), nullptr);
  s = ToolSample{};
  s.force = {3e142, 0, 0};
  EXPECT_NE(check(s), nullptr);
  s = ToolSample{};
  s.stage = static_cast<Stage>(40);
  EXPECT_NE(check(s), nullptr);
  s = ToolSample{};
  s.tool.orientation = {0, 0, 0, 0};
  EXPECT_NE(check(s), nullptr);
  s = ToolSample{};
  s.tool.orientation = s.proxy.orientation = Quat{};
  s.read_status = IoStatus::kImplausible;
  EXPECT_EQ(check(s), nullptr);
  std::memset(&s.read_status, 200, 1);  // no status has this number
  EXPECT_NE(check(s), nullptr);
  s.read_status = IoStatus::kOk;
  std::memset(&s.write_status, 9, 1);
  EXPECT_NE(check(s), nullptr);
  // Events whose payload sets the viz's work: a drill removal of a 1 km burr would carve the
  // whole volume for every sample.
  s = ToolSample{};
  s.tool.orientation = s.proxy.orientation = Quat{};
  s.events = event::kDrillRemove;
  s.payload.magnitude = 0.0015;
  EXPECT_EQ(check(s), nullptr);
  s.payload.magnitude = 1000;
  EXPECT_NE(check(s), nullptr);
  s.payload.magnitude = 0;
  EXPECT_NE(check(s), nullptr);
  s.events = event::kPull;
  s.payload.magnitude = 0.012;
  EXPECT_EQ(check(s), nullptr);
  s.payload.magnitude = -0.01;
  EXPECT_NE(check(s), nullptr);

  RtStatus st{};
  st.period_ns = 1'000'000;
  st.hands = 2;
  HandStatus& left = st.hand[1];  // the left hand's damage is caught as the right's is
  left.force = {std::numeric_limits<double>::infinity(), 0, 0};  // what lancet-viz printed as "inf"
  EXPECT_NE(check(st), nullptr);
  left.force = {};
  left.force_scale = 1.5;
  EXPECT_NE(check(st), nullptr);
  left.force_scale = 1;
  std::memset(left.fault_text, 'A', sizeof left.fault_text);  // no terminator
  EXPECT_NE(check(st), nullptr);
  std::strcpy(left.fault_text, "\x1b[2Jgotcha");  // a terminal escape
  EXPECT_NE(check(st), nullptr);
  left.fault_text[0] = '\0';
  std::memset(&left.device_state, 9, 1);  // a peer's garbage in the state's byte
  EXPECT_NE(check(st), nullptr);
  left.device_state = DeviceLifecycle::kUnconfigured;
  std::memset(&left.device_fault_cause, 0x7f, 1);
  EXPECT_NE(check(st), nullptr);
  left.device_fault_cause = IoStatus::kOk;
  EXPECT_EQ(check(st), nullptr);
  st.hand[0].contact = 2;
  EXPECT_NE(check(st), nullptr);
  st.hand[0].contact = 1;
  std::memset(&st.watchdog_reason, 3, 1);
  EXPECT_NE(check(st), nullptr);
  st.watchdog_reason = WatchdogReason::kNone;
  st.period_ns = 0;
  EXPECT_NE(check(st), nullptr);
}

TEST(WireCheck, TargetsAndRequestsFromTheFutureOrStaleAreCaught) {
  StylusTarget t{};
  t.active = 1;
  t.t_ns = kNow + 10 * kFutureSlackNs;
  EXPECT_NE(check(t, kNow), nullptr);
  t.t_ns = kNow;
  t.active = 2;
  EXPECT_NE(check(t, kNow), nullptr);
  t.active = 1;
  t.target.position.z = kNan;
  EXPECT_NE(check(t, kNow), nullptr);
  OperatorRequest r{};
  r.seq = 1;
  r.t_ns = kNow + 10 * kFutureSlackNs;
  r.kind = kOperatorRearm;
  r.hands = 0b11;
  seal(r);
  EXPECT_NE(check(r, kNow), nullptr);
  r.t_ns = kNow;
  r.kind = 5;
  seal(r);
  EXPECT_NE(check(r, kNow), nullptr);
}

}  // namespace
}  // namespace lancet::wire
