// lancet-bench-haptics: the cost of one haptic tick (proxy + friction + stage machine + safety)
// against TissuePatches of 64 to 16 384 triangles over 4 cm × 4 cm, with the tool sliding in
// contact (probe), cutting (scalpel), and sliding on tissue that moves under it (a new patch every
// 33 ticks, the sheet bobbing 1 mm and drifting sideways: those ticks also build the patch's search
// tree). Each as lancet-rt runs it (through the patch's search tree) and, for comparison, scanning
// every triangle (the step without a patch version; fewer ticks). Then what a patch's arrival
// costs lancet-rt once: the seqlock copy of the triangles in use, the validation, the tree.
// Then the whole servo step (servo_step: kinematics, haptics, fade, Jacobian-transpose, sample)
// for one hand and for two, as lancet-rt's tick steps them: two ServoData, each hand on its own
// patch with its own search tree, stepped back to back and timed together.
// Prints one JSON object: p50, p90, p99, max in ns.
//   lancet-bench-haptics [--ticks N] [--only hands|probe]
// --only probe: the probe sliding through the tree on both sheets at 1 024 and 16 384 triangles,
// nothing else (for a profiler).

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "haptics/haptic_step.hpp"
#include "haptics/patch_bvh.hpp"
#include "lancet/shared_model/seqlock.hpp"
#include "lancet/shared_model/units.hpp"
#include "lancet/shared_model/validate.hpp"
#include "patch_sheet.hpp"  // tests/support
#include "servo/servo_step.hpp"

namespace {

using namespace lancet;

// A flat sheet of n triangles (nx × ny cells × 2), raised by dz and shifted by dx: over 4 cm ×
// 4 cm (cell 0: denser as n grows), or of cells `cell` metres wide (larger as n grows: what a
// larger patch of the same surface is).
std::unique_ptr<TissuePatch> sheet(int n, float dz = 0, float dx = 0, float cell = 0) {
  auto p = std::make_unique<TissuePatch>();
  const int cells = n / 2;
  int nx = static_cast<int>(std::sqrt(cells));
  while (cells % nx != 0) --nx;
  const int ny = cells / nx;
  // Flat: the scalpel stays in its cut.
  const float w = cell > 0 ? cell * static_cast<float>(nx) : 0.04f, h = cell > 0 ? cell * static_cast<float>(ny) : 0.04f;
  test::add_sheet(*p, nx, ny, -w / 2, -h / 2, w / static_cast<float>(nx), h / static_cast<float>(ny),
                  [dx, dz](float x, float y) { return Vec3f{x + dx, y, dz}; });
  return p;
}

struct Stats {
  double p50, p90, p99, max;
};

Stats quantiles(std::vector<double>& ns) {
  std::sort(ns.begin(), ns.end());
  const auto q = [&](double p) { return ns[std::min(ns.size() - 1, static_cast<std::size_t>(p * static_cast<double>(ns.size())))]; };
  return {q(0.5), q(0.9), q(0.99), ns.back()};
}

enum class Run { kTree, kScan, kMoving };

// cell 0: the 4 cm sheet and a 12 mm circle; else cells of `cell` metres and a 6 mm circle.
Stats measure(int triangles, ToolMode mode, Run run, int ticks, float cell) {
  const double path = cell > 0 ? 0.006 : 0.012;
  // Moving: 8 patches of the sheet bobbing ±0.5 mm and drifting ±0.5 mm, one after the other.
  std::vector<std::unique_ptr<TissuePatch>> patches;
  for (int k = 0; k < (run == Run::kMoving ? 8 : 1); ++k) {
    const float phase = 6.2831853f * static_cast<float>(k) / 8.0f;
    patches.push_back(run == Run::kMoving ? sheet(triangles, 0.0005f * std::sin(phase), 0.0005f * std::cos(phase), cell)
                                          : sheet(triangles, 0, 0, cell));
  }
  const haptics::HapticModel model = haptics::HapticModel::defaults();
  auto data = std::make_unique<haptics::HapticData>();
  haptics::HapticInput in;
  in.patch = patches[0].get();
  in.patch_version = run == Run::kScan ? 0 : 1;
  in.mode = mode;
  haptics::HapticOutput out;
  std::vector<double> ns(static_cast<std::size_t>(ticks));
  for (int i = -1000; i < ticks; ++i) {  // 1000 warm-up ticks
    if (run == Run::kMoving && i >= 0 && i % 33 == 0) {
      in.patch_version = 2 + static_cast<std::uint64_t>(i / 33);
      in.patch = patches[static_cast<std::size_t>(in.patch_version % patches.size())].get();
    }
    const double t = i * 0.001;
    // Probe: 2 mm into the sheet, sliding. Scalpel: 5 mm in, past the yield force: cutting.
    // During warm-up the tool comes down from 5 mm above (a proxy that starts under the one-sided
    // sheet would rightly stay free).
    const double depth = mode == ToolMode::kScalpel ? -0.005 : -0.002;
    const double z = i < -500 ? 0.005 + (depth - 0.005) * (i + 1000) / 500.0 : depth;
    in.device = Vec3{path * std::sin(t * 1.3), path * std::cos(t * 0.7), z};
    in.velocity = Vec3{path * 1.3 * std::cos(t * 1.3), -path * 0.7 * std::sin(t * 0.7), 0};
    const std::int64_t t0 = monotonic_ns();
    haptics::haptic_step(model, *data, in, out);
    const std::int64_t t1 = monotonic_ns();
    if (i >= 0) ns[static_cast<std::size_t>(i)] = static_cast<double>(t1 - t0);
  }
  if (mode == ToolMode::kScalpel && data->stage != Stage::kCutting) std::fprintf(stderr, "warning: the scalpel is not cutting\n");
  if (mode == ToolMode::kProbe && !out.contact) std::fprintf(stderr, "warning: the probe lost contact\n");
  if (run == Run::kMoving && data->probe.carried == 0) std::fprintf(stderr, "warning: the moving tissue never carried the proxy\n");
  return quantiles(ns);
}

// A patch's arrival, once per patch in lancet-rt: the seqlock copy of the triangles in use
// (RtServo's read), wire::check, and the search tree.
struct Arrival {
  Stats copy, check, tree;
};

Arrival measure_arrival(int triangles, int reps) {
  const auto patch = sheet(triangles);
  patch->t_ns = monotonic_ns();
  auto lock = std::make_unique<Seqlock<TissuePatch>>();
  auto back = std::make_unique<TissuePatch>();
  auto bvh = std::make_unique<haptics::PatchBvh>();
  std::vector<double> copy, check, tree;
  const auto in_use = [](const TissuePatch& p) { return tissue_patch_bytes(p); };
  for (int r = 0; r < reps; ++r) {
    patch->seq = static_cast<std::uint64_t>(r);
    lock->write_prefix(*patch, tissue_patch_bytes(*patch));
    std::uint64_t seen = 0;
    const std::int64_t t0 = monotonic_ns();
    const ReadStatus st = lock->try_read_prefix_if_newer(*back, seen, offsetof(TissuePatch, triangles), in_use, 2);
    const std::int64_t t1 = monotonic_ns();
    const char* why = wire::check(*back, monotonic_ns());
    const std::int64_t t2 = monotonic_ns();
    haptics::build_patch_bvh(*bvh, *back, seen);
    const std::int64_t t3 = monotonic_ns();
    if (st != ReadStatus::kOk || why != nullptr) std::fprintf(stderr, "warning: the patch was not read or not valid\n");
    copy.push_back(static_cast<double>(t1 - t0)), check.push_back(static_cast<double>(t2 - t1)), tree.push_back(static_cast<double>(t3 - t2));
  }
  return {quantiles(copy), quantiles(check), quantiles(tree)};
}

// One tick of lancet-rt's servo for the hands [first, first + hands) (0: the right, 1: the left)
// on patches of n triangles (the 4 cm sheet), the probe sliding 2 mm deep, each hand on its own
// path (the left's is the right's shifted in phase): each hand has its own ServoData, patch and
// search tree (built before the loop, as the patch intake builds it off the tick); the hands are
// stepped back to back, and the time is the tick's, both steps together. `preempted`:
// the ticks over 1 ms (the host took the CPU away: on a shared VM these set the p99 of a long run).
Stats measure_hands(int triangles, int first, int hands, int ticks, int& preempted) {
  servo::ServoModel model;  // the built-in stylus: Cartesian kinematics, the tissue's origin at 0
  for (std::size_t j = 0; j < 3; ++j) model.max_joint_torque[j] = model.haptic.safety.max_force;
  struct HandRun {
    std::unique_ptr<TissuePatch> patch;
    std::unique_ptr<haptics::PatchBvh> tree;
    std::unique_ptr<servo::ServoData> data;
    servo::ServoOutput out;
  };
  std::vector<HandRun> run(static_cast<std::size_t>(hands));
  for (std::size_t h = 0; h < run.size(); ++h) {
    run[h].patch = sheet(triangles);
    run[h].tree = std::make_unique<haptics::PatchBvh>();
    haptics::build_patch_bvh(*run[h].tree, *run[h].patch, 1);
    run[h].data = std::make_unique<servo::ServoData>();
  }
  std::vector<double> ns(static_cast<std::size_t>(ticks));
  servo::ServoInput in;
  in.patch_version = 1;
  in.viz_alive = true;
  in.reading.n = 3;
  for (int i = -1000; i < ticks; ++i) {  // 1000 warm-up ticks: down from 5 mm above, then in contact
    in.deadline_ns = static_cast<std::int64_t>(i + 1000) * 1'000'000;
    in.woke_ns = in.deadline_ns + 20'000;
    const double t = i * 0.001;
    const double z = i < -500 ? 0.005 - 0.007 * (i + 1000) / 500.0 : -0.002;
    const std::int64_t t0 = monotonic_ns();
    for (std::size_t k = 0; k < run.size(); ++k) {
      const std::size_t h = k + static_cast<std::size_t>(first), r = k;
      const double phase = 1.5 * static_cast<double>(h);  // the left hand on a path of its own
      in.hand = static_cast<Hand>(h);
      in.patch = run[r].patch.get();
      in.patch_tree = run[r].tree.get();
      in.reading.q = {0.012 * std::sin(t * 1.3 + phase), 0.012 * std::cos(t * 0.7 + phase), z};
      in.reading.qd = {0.012 * 1.3 * std::cos(t * 1.3 + phase), -0.012 * 0.7 * std::sin(t * 0.7 + phase), 0};
      servo::servo_step(model, *run[r].data, in, run[r].out);
    }
    const std::int64_t t1 = monotonic_ns();
    if (i >= 0) ns[static_cast<std::size_t>(i)] = static_cast<double>(t1 - t0);
  }
  for (const HandRun& r : run)
    if (!r.data->contact) std::fprintf(stderr, "warning: a hand lost contact\n");
  preempted = static_cast<int>(std::count_if(ns.begin(), ns.end(), [](double t) { return t > 1e6; }));
  return quantiles(ns);
}

// The haptic step's rows and the arrival's (the JSON's "results" and "arrival").
void print_haptics(int ticks) {
  std::printf("  \"results\": [\n");
  // Which stage the scalpel run ends in is part of the result: it must be cutting.
  bool first = true;
  struct Case {
    ToolMode mode;
    Run run;
    const char* name;
  };
  const Case cases[] = {{ToolMode::kProbe, Run::kTree, "probe (sliding in contact)"},
                        {ToolMode::kScalpel, Run::kTree, "scalpel (cutting)"},
                        {ToolMode::kProbe, Run::kMoving, "probe, tissue moving under the tool (new patch every 33 ticks)"},
                        {ToolMode::kProbe, Run::kScan, "probe, scanning every triangle (no search tree)"}};
  // Two ways to grow a patch: the same 4 cm sheet in ever smaller cells (the old rows; the
  // triangles within the proxy's reach grow with n), and a sheet of 1 mm cells that grows in
  // area (what a larger patch of the same surface is: 16 384 triangles are 64 mm × 128 mm).
  for (const float cell : {0.0f, 0.001f}) {
    for (const Case& c : cases) {
      for (int n : {64, 256, 1024, 4096, 16384}) {
        if (cell > 0 && n < 1024) continue;  // smaller than the tool's circle
        // The scan is the old cost, linear in the patch: fewer ticks at the large sizes.
        const int run_ticks = c.run == Run::kScan && n > 1024 ? std::max(1000, ticks / 20) : ticks;
        const Stats s = measure(n, c.mode, c.run, run_ticks, cell);
        std::printf("%s    {\"triangles\": %d, \"sheet\": \"%s\", \"mode\": \"%s\", \"ticks\": %d, \"p50_ns\": %.0f, \"p90_ns\": %.0f, "
                    "\"p99_ns\": %.0f, \"max_ns\": %.0f}",
                    first ? "" : ",\n", n, cell > 0 ? "1 mm cells" : "40 mm square", c.name, run_ticks, s.p50, s.p90, s.p99, s.max);
        first = false;
      }
    }
  }
  std::printf("\n  ],\n  \"arrival\": [\n");
  first = true;
  for (int n : {1024, 4096, 16384}) {
    const Arrival a = measure_arrival(n, 2000);
    std::printf("%s    {\"triangles\": %d, \"bytes\": %zu, \"copy_p50_ns\": %.0f, \"copy_p99_ns\": %.0f, \"check_p50_ns\": %.0f, "
                "\"check_p99_ns\": %.0f, \"tree_p50_ns\": %.0f, \"tree_p99_ns\": %.0f}",
                first ? "" : ",\n", n, offsetof(TissuePatch, triangles) + static_cast<std::size_t>(n) * sizeof(PatchTriangle), a.copy.p50,
                a.copy.p99, a.check.p50, a.check.p99, a.tree.p50, a.tree.p99);
    first = false;
  }
  std::printf("\n  ],\n");
}

}  // namespace

int main(int argc, char** argv) {
  int ticks = 200'000;
  bool hands_only = false, probe_only = false;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--ticks") == 0 && i + 1 < argc) {
      ticks = std::max(1000, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--only") == 0 && i + 1 < argc && std::strcmp(argv[i + 1], "hands") == 0) {
      hands_only = true;
      ++i;
    } else if (std::strcmp(argv[i], "--only") == 0 && i + 1 < argc && std::strcmp(argv[i + 1], "probe") == 0) {
      probe_only = true;
      ++i;
    } else {
      std::fprintf(stderr, "usage: lancet-bench-haptics [--ticks N] [--only hands|probe]\n");
      return 2;
    }
  }
  std::printf("{\n  \"ticks\": %d,\n", ticks);
  if (probe_only) {
    for (const float cell : {0.001f, 0.0f})
      for (int n : {1024, 16384}) {
        const Stats s = measure(n, ToolMode::kProbe, Run::kTree, ticks, cell);
        std::printf("  \"probe_%s_%d\": {\"p50_ns\": %.0f, \"p90_ns\": %.0f, \"p99_ns\": %.0f, \"max_ns\": %.0f},\n", cell > 0 ? "1mm" : "40mm",
                    n, s.p50, s.p90, s.p99, s.max);
      }
    std::printf("  \"only\": \"probe\"\n}\n");
    return 0;
  }
  if (!hands_only) print_haptics(ticks);
  // One hand against two, each size measured twice in turn (right, left, both; again), so that a
  // neighbour's load that comes and goes shows as a spread between the two passes. Each figure is
  // [p50, p90, p99]: the right hand alone (one hand), the left hand alone (its own path), both;
  // the ratio is both hands' over the right hand's.
  std::printf("  \"servo_hands\": [\n");
  bool first = true;
  for (int n : {1024, 16384}) {
    for (int pass = 0; pass < 2; ++pass) {
      int one_preempted = 0, left_preempted = 0, two_preempted = 0;
      const Stats one = measure_hands(n, 0, 1, ticks, one_preempted), left = measure_hands(n, 1, 1, ticks, left_preempted),
                  two = measure_hands(n, 0, 2, ticks, two_preempted);
      std::printf("%s    {\"triangles\": %d, \"pass\": %d, \"right_hand_ns\": [%.0f, %.0f, %.0f], \"left_hand_ns\": [%.0f, %.0f, %.0f], "
                  "\"two_hands_ns\": [%.0f, %.0f, %.0f], \"two_over_right\": [%.2f, %.2f, %.2f], \"ticks_over_1ms\": [%d, %d, %d]}",
                  first ? "" : ",\n", n, pass + 1, one.p50, one.p90, one.p99, left.p50, left.p90, left.p99, two.p50, two.p90, two.p99,
                  two.p50 / one.p50, two.p90 / one.p90, two.p99 / one.p99, one_preempted, left_preempted, two_preempted);
      first = false;
    }
  }
  std::printf("\n  ]\n}\n");
  return 0;
}
