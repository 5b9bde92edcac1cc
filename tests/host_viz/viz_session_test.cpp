#include "app/viz_session.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "lancet/shared_model/validate.hpp"
#include "tissue/patch_export.hpp"
#include "tissue/tissue_scene.hpp"

namespace lancet::viz {
namespace {

std::string unique_name(const char* tag) {
  static int n = 0;
  return "/lancet-vs-" + std::string(tag) + "-" + std::to_string(getpid()) + "-" + std::to_string(++n);
}

ToolSample sample(std::uint64_t seq, Vec3 p, Hand hand = Hand::kRight) {
  ToolSample s{};
  s.seq = seq;
  s.tool.position = p;
  s.hand = hand;
  return s;
}

using SampleSink = std::function<void(std::span<const ToolSample> samples)>;
using PatchFill = std::function<void(Vec3 tool, TissuePatch& patch)>;

// One frame of the link as the live viz runs it (app/live_frame, sim::run_frame): the samples
// drained, handed on, each hand's patch filled around its newest tool position once attached with
// a sample of that hand (its header: the frame, its time, the hand's newest tick drained),
// published with the heartbeat.
void link_frame(VizSession& s, std::int64_t now, const SampleSink& sink, const PatchFill& fill) {
  const std::span<const ToolSample> batch = s.drain(now);
  if (sink && !batch.empty()) sink(batch);
  std::array<const TissuePatch*, kHandCount> out{};
  for (std::size_t h = 0; h < kHandCount; ++h) {
    const auto hand = static_cast<Hand>(h);
    if (!s.attached() || !s.has_sample(hand)) continue;
    TissuePatch* p = &s.patch_buffer(hand);
    p->n_triangles = 0;
    p->brick.valid = 0;
    fill(s.latest(hand).tool.position, *p);
    p->hand = hand;
    p->seq = s.frames();
    p->t_ns = now;
    p->samples_applied = s.samples_applied(hand);
    out[h] = p;
  }
  s.publish(out, now);
}

// The patch source of a plain mesh (no volume: no brick).
PatchFill mesh_patch(const surface::TriangleMesh& mesh) {
  auto scratch = std::make_shared<tissue::PatchExportScratch>();
  return [&mesh, scratch](Vec3 tool, TissuePatch& p) { (void)tissue::export_patch(mesh, tool, {}, *scratch, p); };
}

TEST(SampleStats, CountsLossAndDisorder) {
  SampleStats st;
  const ToolSample a[] = {sample(5, {}), sample(6, {}), sample(9, {}), sample(9, {}), sample(8, {}), sample(10, {})};
  st.ingest(a, 6);
  EXPECT_EQ(st.received, 4u);
  EXPECT_EQ(st.first_seq, 5u);
  EXPECT_EQ(st.last_seq, 10u);
  EXPECT_EQ(st.lost, 2u);  // 7 and 8 were skipped when 9 arrived
  EXPECT_EQ(st.out_of_order, 2u);
  EXPECT_EQ(st.max_batch, 6u);
}

TEST(VizSession, WaitsWithoutAPeerAndSaysSo) {
  VizSessionParams p;
  p.shm_name = unique_name("absent");
  VizSession s(p);
  const auto mesh = surface::make_tissue_block({});
  link_frame(s, 1'000'000'000, {}, mesh_patch(mesh));
  EXPECT_EQ(s.link(), Link::kWaiting);
  EXPECT_NE(s.link_message().find("does not exist"), std::string::npos) << s.link_message();
}

// lancet-rt's stream, drained by the session, drives the scene: a dent, a rupture and a cut
// along +x, then the lift; the published patch carries the cut.
TEST(VizSession, ToolSamplesCutTheSurfaceModel) {
  const std::string name = unique_name("cut");
  auto rt = SharedChannel::create(name, {}).value();
  SharedState& shared = rt.state();
  std::int64_t now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());
  VizSessionParams p;
  p.shm_name = name;
  VizSession session(p);
  tissue::SceneDescription d;
  d.source = tissue::SceneSource::kBlock;
  auto scene = std::move(tissue::TissueScene::create(std::move(d)).value());
  bool changed = false;
  const auto apply = [&](std::span<const ToolSample> batch) { changed |= scene->apply(batch); };
  const auto fill = [&](Vec3 tool, TissuePatch& patch) { (void)scene->export_patch(tool, patch); };
  const surface::SurfaceModel* model = &scene->surface();
  link_frame(session, now, apply, fill);  // attach
  ASSERT_EQ(session.link(), Link::kConnected) << session.link_message();
  const auto on_surface = [](double x, double y) { return Vec3{x, y, surface::tissue_block_height({}, x, y)}; };
  std::uint64_t seq = 0;
  const auto push = [&](Stage stage, Vec3 proxy, std::uint32_t events) {
    ToolSample t = sample(++seq, proxy + Vec3{0, 0, -0.001});
    t.t_ns = now + static_cast<std::int64_t>(seq) * 1'000'000;
    t.stage = stage;
    t.proxy.position = proxy;
    t.events = events;
    t.payload.position = proxy;
    ASSERT_TRUE(shared.samples.try_push(t));
  };
  push(Stage::kDeform, on_surface(-0.02, 0.0011), 0);
  push(Stage::kRupture, on_surface(-0.02, 0.0011), event::kRupture);
  // 3 cm at 0.1 mm a tick; lancet-rt marks every 0.5 mm of blade travel as cut progress.
  for (int i = 1; i <= 300; ++i)
    push(Stage::kCutting, on_surface(-0.02 + 0.0001 * i, 0.0011), i % 5 == 0 ? event::kCutProgress : 0u);
  now += 400'000'000;
  shared.rt_heartbeat.beat(now, getpid());
  link_frame(session, now, apply, fill);
  EXPECT_TRUE(changed);
  ASSERT_EQ(model->cuts().size(), 1u);
  EXPECT_TRUE(model->cutting());
  EXPECT_GE(model->cuts()[0].pairs.size(), 10u) << "2 mm cells over 3 cm";
  // The entry, the rupture, each 0.5 mm of progress (60), not each of the 300 ticks.
  EXPECT_GE(model->cuts()[0].path.size(), 61u);
  EXPECT_LE(model->cuts()[0].path.size(), 64u);
  push(Stage::kFree, on_surface(0.01, 0.0011), 0);
  now += 20'000'000;
  shared.rt_heartbeat.beat(now, getpid());
  link_frame(session, now, apply, fill);
  EXPECT_FALSE(model->cutting());
  EXPECT_EQ(model->cuts().size(), 1u);
  std::size_t on_cut = 0;
  for (std::size_t i = 0; i < session.patch().n_triangles; ++i)
    on_cut += (session.patch().triangles[i].flags & kTriangleOnCutEdge) != 0 ? 1 : 0;
  EXPECT_GT(on_cut, 0u) << "the patch at the cut's end flags the triangles on its lips";
  const auto st = model->stats();
  EXPECT_EQ(st.non_manifold_vertices, 0u);
  EXPECT_EQ(st.flipped_faces, 0u);
}

TEST(VizSession, AttachesDrainsPublishesAndNoticesTheRtLeaving) {
  const std::string name = unique_name("live");
  auto rt = std::make_optional(SharedChannel::create(name, {}).value());
  SharedState& shared = rt->state();
  // Backlog from before the viz attached is discarded.
  for (std::uint64_t i = 1; i <= 10; ++i) ASSERT_TRUE(shared.samples.try_push(sample(i, {})));
  std::int64_t now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());

  VizSessionParams p;
  p.shm_name = name;
  VizSession s(p);
  const auto mesh = surface::make_tissue_block({});
  link_frame(s, now, {}, mesh_patch(mesh));
  ASSERT_EQ(s.link(), Link::kConnected) << s.link_message();
  EXPECT_EQ(s.stats().discarded, 10u);
  EXPECT_EQ(s.stats().received, 0u);

  for (std::uint64_t i = 11; i <= 600; ++i) ASSERT_TRUE(shared.samples.try_push(sample(i, {0.0, 0.0, -0.001})));
  now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());
  std::size_t drained = 0, batches = 0;
  link_frame(s, now, [&](std::span<const ToolSample> b) { drained += b.size(), ++batches; }, mesh_patch(mesh));
  EXPECT_EQ(drained, 590u);
  EXPECT_EQ(batches, 1u) << "the frame's samples come as one batch, however many pops it took";
  EXPECT_EQ(s.stats().received, 590u);
  EXPECT_EQ(s.stats().lost, 0u);
  EXPECT_EQ(s.latest().seq, 600u);
  EXPECT_TRUE(shared.viz_heartbeat.fresh(now, 1'000'000));

  // The patch around the tool reached shared memory.
  auto patch = std::make_unique<TissuePatch>();
  ASSERT_EQ(shared.patch[0].try_read(*patch), ReadStatus::kOk);
  EXPECT_GT(patch->n_triangles, 0u);
  double nearest = 1e9;
  for (std::uint32_t i = 0; i < patch->n_triangles; ++i) nearest = std::min(nearest, norm(to_vec3(patch->triangles[i].v[0]) - Vec3{0.0, 0.0, -0.001}));
  EXPECT_LT(nearest, 0.02) << "the patch is cut around the newest tool position";
  EXPECT_EQ(patch->samples_applied, 600u) << "the newest sample whose events it reflects";
  EXPECT_EQ(patch->brick.valid, 0u) << "no volume, no brick";

  // Each sample (checked) is drained before the patch is filled around the newest tool position
  // (here with a brick).
  std::uint64_t sunk = 0, newest_sunk = 0;
  const auto sink = [&](std::span<const ToolSample> batch) {
    sunk += batch.size();
    newest_sunk = batch.back().seq;
  };
  Vec3 brick_centre{};
  const auto with_brick = [&, plain = mesh_patch(mesh)](Vec3 centre, TissuePatch& out) {
    plain(centre, out);
    VoxelBrick& b = out.brick;
    brick_centre = centre;
    b.valid = 1;
    b.dim = kBrickDim;
    b.spacing = {0.001, 0.001, 0.001};
    b.origin = centre;
  };
  for (std::uint64_t i = 601; i <= 620; ++i) ASSERT_TRUE(shared.samples.try_push(sample(i, {0.001, 0.0, -0.002})));
  now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());
  link_frame(s, now, sink, with_brick);
  EXPECT_EQ(sunk, 20u);
  EXPECT_EQ(newest_sunk, 620u);
  ASSERT_EQ(shared.patch[0].try_read(*patch), ReadStatus::kOk);
  EXPECT_EQ(patch->brick.valid, 1u);
  EXPECT_EQ(brick_centre, (Vec3{0.001, 0.0, -0.002}));
  EXPECT_EQ(patch->samples_applied, 620u);

  // Garbage in the ring's slots: a tick that goes back (a stale slot) or leaps ahead further than
  // the ring holds is rejected and counted, and the ticks after it are taken.
  std::vector<std::uint64_t> handed;
  const auto record_seqs = [&](std::span<const ToolSample> batch) {
    for (const ToolSample& t : batch) handed.push_back(t.seq);
  };
  const std::uint64_t rejected_before = s.stats().rejected;
  for (const std::uint64_t seq : {621ull, 615ull, 622ull, 622ull + 5 * kSampleRingCapacity, 623ull, 624ull})
    ASSERT_TRUE(shared.samples.try_push(sample(seq, {0.001, 0.0, -0.002})));
  now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());
  link_frame(s, now, record_seqs, with_brick);
  EXPECT_EQ(handed, (std::vector<std::uint64_t>{621, 622, 623, 624}));
  EXPECT_EQ(s.stats().rejected, rejected_before + 2);
  EXPECT_EQ(s.stats().lost, 0u);
  ASSERT_EQ(shared.patch[0].try_read(*patch), ReadStatus::kOk);
  EXPECT_EQ(patch->samples_applied, 624u);

  // Stylus target and commands travel the other way.
  s.set_stylus_target(Hand::kLeft, true, {0.01, 0.02, -0.003}, now);
  StylusTarget t{};
  EXPECT_EQ(shared.stylus_target[0].try_read(t), ReadStatus::kEmpty) << "the left hand's target goes to the left hand's slot";
  ASSERT_EQ(shared.stylus_target[1].try_read(t), ReadStatus::kOk);
  EXPECT_EQ(t.hand, Hand::kLeft);
  EXPECT_EQ(t.active, 1u);
  EXPECT_EQ(t.target.position, (Vec3{0.01, 0.02, -0.003}));
  Command c{};
  c.kind = CommandKind::kReset;
  EXPECT_TRUE(s.send(c, now));
  Command got{};
  ASSERT_TRUE(shared.commands.try_pop(got));
  EXPECT_EQ(got.kind, CommandKind::kReset);
  EXPECT_EQ(got.seq, 1u);

  // lancet-rt exits cleanly: the viz notices at its next frame and keeps running.
  shared.rt_heartbeat.stop();
  rt.reset();
  link_frame(s, monotonic_ns(), {}, mesh_patch(mesh));
  EXPECT_EQ(s.link(), Link::kLost);
  EXPECT_NE(s.link_message().find("lancet-rt is not running"), std::string::npos) << s.link_message();
  EXPECT_EQ(s.rt_losses(), 1u);

  // A new lancet-rt appears under the same name: the viz attaches again.
  rt.emplace(SharedChannel::create(name, {}).value());
  rt->state().rt_heartbeat.beat(monotonic_ns(), getpid());
  link_frame(s, monotonic_ns() + 2'000'000'000, {}, mesh_patch(mesh));  // past the retry interval
  EXPECT_EQ(s.link(), Link::kConnected) << s.link_message();
  EXPECT_EQ(s.connections(), 2u);
}

// Two hands: each tick brings a sample of each with the tick's seq; each hand's order is checked on
// its own, its patch is cut around its own tool and published to its own buffer, and the resets
// that start a recording reach the ring together.
TEST(VizSession, TwoHandsEachInOrderEachWithItsPatch) {
  const std::string name = unique_name("hands");
  auto rt = SharedChannel::create(name, {}).value();
  SharedState& shared = rt.state();
  RtStatus st{};
  st.period_ns = 1'000'000;
  st.hands = 2;
  shared.rt_status.write(st);
  std::int64_t now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());
  VizSessionParams p;
  p.shm_name = name;
  VizSession s(p);
  const auto mesh = surface::make_tissue_block({});
  link_frame(s, now, {}, mesh_patch(mesh));
  ASSERT_EQ(s.link(), Link::kConnected) << s.link_message();
  EXPECT_EQ(s.hands(), 2u);

  const Vec3 right{-0.01, 0.0, -0.001}, left{0.012, 0.01, -0.001};
  for (std::uint64_t i = 1; i <= 100; ++i) {
    ASSERT_TRUE(shared.samples.try_push(sample(i, right, Hand::kRight)));
    ASSERT_TRUE(shared.samples.try_push(sample(i, left, Hand::kLeft)));
  }
  // A stale slot of the left hand (its tick 50 again) is garbage; the right hand's 101 is not.
  ASSERT_TRUE(shared.samples.try_push(sample(50, left, Hand::kLeft)));
  ASSERT_TRUE(shared.samples.try_push(sample(101, right, Hand::kRight)));
  now = monotonic_ns();
  shared.rt_heartbeat.beat(now, getpid());
  std::size_t rights = 0, lefts = 0;
  link_frame(s, now, [&](std::span<const ToolSample> batch) {
    for (const ToolSample& t : batch) (t.hand == Hand::kLeft ? lefts : rights)++;
  }, mesh_patch(mesh));
  EXPECT_EQ(rights, 101u);
  EXPECT_EQ(lefts, 100u);
  EXPECT_EQ(s.stats().out_of_order, 0u) << "the two hands' samples of one tick share its seq";
  EXPECT_EQ(s.stats().rejected, 1u);
  EXPECT_EQ(s.stats().lost, 0u);
  EXPECT_EQ(s.samples_applied(Hand::kRight), 101u);
  EXPECT_EQ(s.samples_applied(Hand::kLeft), 100u);

  // Each hand's patch, in its own buffer, around its own tool, saying whose it is.
  for (const Hand hand : {Hand::kRight, Hand::kLeft}) {
    auto patch = std::make_unique<TissuePatch>();
    ASSERT_EQ(shared.patch[hand_index(hand)].try_read(*patch), ReadStatus::kOk) << hand_name(hand);
    EXPECT_EQ(patch->hand, hand);
    const Vec3 tool = hand == Hand::kRight ? right : left;
    double nearest = 1e9;
    for (std::uint32_t i = 0; i < patch->n_triangles; ++i) nearest = std::min(nearest, norm(to_vec3(patch->triangles[i].v[0]) - tool));
    EXPECT_LT(nearest, 0.003) << hand_name(hand) << ": the patch is cut around the hand's own tool";
    EXPECT_EQ(patch->samples_applied, hand == Hand::kRight ? 101u : 100u);
    EXPECT_EQ(s.patch_version(hand), shared.patch[hand_index(hand)].version());
  }

  // The resets of both hands arrive in the ring together, each for its hand, each newer than the last.
  ASSERT_TRUE(s.send_each_hand(CommandKind::kReset, 2, now));
  Command got[3]{};
  ASSERT_EQ(shared.commands.try_pop_n(got, 3), 2u);
  EXPECT_EQ(got[0].hand, Hand::kRight);
  EXPECT_EQ(got[1].hand, Hand::kLeft);
  EXPECT_EQ(got[0].kind, CommandKind::kReset);
  EXPECT_EQ(got[1].kind, CommandKind::kReset);
  EXPECT_LT(got[0].t_ns, got[1].t_ns);
  EXPECT_EQ(wire::check(got[0]), nullptr);
  EXPECT_EQ(wire::check(got[1]), nullptr);
}

}  // namespace
}  // namespace lancet::viz
