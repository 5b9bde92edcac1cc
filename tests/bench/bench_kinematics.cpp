// lancet-bench-kinematics: the time of one call of what the servo tick asks of the arm's model,
// position and Jacobian of the tool point from the joints (Kinematics::position_and_jacobian), for
// the delta arm (the Novint Falcon: Newton's method for the position) against the closed-form
// PHANToM arm and a 3-joint DH chain in the same run (the yardsticks), plus the delta's parts
// (position alone, jacobian(q) alone, the inverse). The joints cycle through 1 000 poses spread over
// the Falcon's reachable 90 mm cube (the others take the same joint values). Prints one JSON object:
// for each case the median and the fastest of the repeats, in ns per call.
//   lancet-bench-kinematics [--calls N] [--repeats R]

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "arm/kinematics.hpp"

namespace {

using namespace lancet;
using namespace lancet::arm;
using Clock = std::chrono::steady_clock;

struct Timing {
  double median_ns = 0, best_ns = 0;
};

// ns per call of `one(i)` for i = 0..calls−1, `repeats` times; the sink keeps the work alive.
Timing time_calls(int calls, int repeats, const std::function<double(int)>& one, double& sink) {
  std::vector<double> per_call;
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = Clock::now();
    double s = 0;
    for (int i = 0; i < calls; ++i) s += one(i);
    const auto t1 = Clock::now();
    sink += s;
    per_call.push_back(std::chrono::duration<double, std::nano>(t1 - t0).count() / calls);
  }
  std::sort(per_call.begin(), per_call.end());
  return {per_call[per_call.size() / 2], per_call.front()};
}

}  // namespace

int main(int argc, char** argv) {
  int calls = 1'000'000, repeats = 7;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--calls") == 0 && i + 1 < argc) {
      calls = std::max(1000, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--repeats") == 0 && i + 1 < argc) {
      repeats = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: %s [--calls N] [--repeats R]\n", argv[0]);
      return 2;
    }
  }
  const DeltaArm falcon(DeltaGeometry::novint_falcon(), {0, 0, -0.111});
  const Kinematics delta(falcon), phantom(PhantomArm{0.20955, 0.20955, {}});
  const std::vector<DhLink> links{{JointType::kRevolute, 0, 1.5707963267948966, 0.1, 0},
                                  {JointType::kRevolute, 0.25, 0, 0, 0},
                                  {JointType::kRevolute, 0.25, 0, 0, 0}};
  const Kinematics dh{DhChain(links)};
  // 1 000 poses: a 10 × 10 × 10 grid of the 90 mm cube about the device-frame origin.
  std::vector<std::array<double, 3>> qs;
  std::vector<Vec3> points;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j)
      for (int k = 0; k < 10; ++k) {
        const Vec3 p{-0.045 + 0.01 * i, -0.045 + 0.01 * j, -0.045 + 0.01 * k};
        if (const auto q = falcon.inverse(p)) qs.push_back(*q), points.push_back(p);
      }
  const auto q_of = [&](int i) { return std::span<const double>(qs[static_cast<std::size_t>(i) % qs.size()]); };
  const auto both = [&](const Kinematics& k) {
    return [&k, &q_of](int i) {
      Vec3 p{};
      const Jacobian j = k.position_and_jacobian(q_of(i), p);
      return p.x + j.column[2].z;
    };
  };
  double sink = 0;
  const Timing t_delta = time_calls(calls, repeats, both(delta), sink);
  const Timing t_phantom = time_calls(calls, repeats, both(phantom), sink);
  const Timing t_dh = time_calls(calls, repeats, both(dh), sink);
  const Timing t_position = time_calls(calls, repeats, [&](int i) { return falcon.position(q_of(i)).z; }, sink);
  const Timing t_jacobian = time_calls(calls, repeats, [&](int i) { return falcon.jacobian(q_of(i)).column[0].x; }, sink);
  const Timing t_inverse = time_calls(calls, repeats, [&](int i) {
    return falcon.inverse(points[static_cast<std::size_t>(i) % points.size()]).value_or(std::array<double, 3>{})[1];
  }, sink);
  const auto row = [](const char* name, Timing t, bool last = false) {
    std::printf("  \"%s\": {\"median_ns\": %.1f, \"best_ns\": %.1f}%s\n", name, t.median_ns, t.best_ns, last ? "" : ",");
  };
  std::printf("{\n  \"calls\": %d, \"repeats\": %d, \"poses\": %zu,\n", calls, repeats, qs.size());
  row("delta_position_and_jacobian", t_delta);
  row("phantom_position_and_jacobian", t_phantom);
  row("dh3_position_and_jacobian", t_dh);
  row("delta_position", t_position);
  row("delta_jacobian", t_jacobian);
  row("delta_inverse", t_inverse);
  std::printf("  \"delta_over_phantom\": %.2f, \"delta_over_dh3\": %.2f,\n", t_delta.median_ns / t_phantom.median_ns,
              t_delta.median_ns / t_dh.median_ns);
  std::printf("  \"sink\": %g\n}\n", sink);
  return 0;
}
