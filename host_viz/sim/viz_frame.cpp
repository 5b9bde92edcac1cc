#include "sim/viz_frame.hpp"

#include <chrono>

namespace lancet::sim {

Result<FrameResult> run_frame(SceneSim& sim, FrameIo& io) {
  using Clock = std::chrono::steady_clock;
  const auto since = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  auto drained = io.drain();
  if (!drained.ok()) return drained.error();
  const FrameBatch& b = drained.value();
  FrameResult r;
  r.samples = b.samples.size();
  r.blood_dt = b.blood_dt;

  auto t0 = Clock::now();
  sim.apply(b.samples);
  r.scene_s = since(t0);

  // The patch around the newest tool position, from an empty one (no triangles, no brick), and
  // the header that says which frame and tick it reflects; published before the blood steps, so
  // the servo never waits for the blood (the blood changes nothing a patch holds). The blood's
  // preparation (what it reads of the scene) runs beside the patches.
  t0 = Clock::now();
  std::array<TissuePatch*, kHandCount> into{};
  std::array<Vec3, kHandCount> centres{};
  for (std::size_t h = 0; h < kHandCount; ++h) {
    into[h] = b.patches[h].patch;
    centres[h] = b.patches[h].centre;
    if (into[h] == nullptr) continue;
    into[h]->n_triangles = 0;
    into[h]->brick.valid = 0;
  }
  r.triangles = sim.export_patches_and_prepare_blood(into, centres, b.blood_dt);
  std::array<const TissuePatch*, kHandCount> out{};
  for (std::size_t h = 0; h < kHandCount; ++h) {
    const HandPatch& hp = b.patches[h];
    if (hp.patch == nullptr) continue;
    TissuePatch& p = *hp.patch;
    p.hand = static_cast<Hand>(h);
    p.seq = hp.header.seq;
    p.t_ns = hp.header.t_ns;
    p.samples_applied = hp.header.samples_applied;
    r.patch[h] = true;
    out[h] = &p;
  }
  io.publish(out);
  r.patch_s = since(t0);

  t0 = Clock::now();
  sim.step_blood();
  r.blood_s = since(t0);
  return r;
}

}  // namespace lancet::sim
