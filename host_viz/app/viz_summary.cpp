#include "app/viz_summary.hpp"

#include <cmath>
#include <cstdio>

namespace lancet::viz {

bool write_stats(const std::string& path, const VizSession& s, const sim::SceneSim& sim, const RunFigures& run) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return false;
  const tissue::TissueScene& scene = sim.scene();
  const score::TaskStatus* task = sim.task() != nullptr ? &sim.task()->status() : nullptr;
  const std::string scenario_name = sim.scenario() != nullptr ? sim.scenario()->name : "";
  const auto& st = s.stats();
  const auto& ev = scene.events();
  const auto cuts = scene.cut_figures();
  const auto grooves = scene.grooves();
  const blood::BloodFigures bf = sim.bleeding() != nullptr ? sim.bleeding()->figures() : blood::BloodFigures{};
  // Each cut's opening D (the width it was last opened to), in the order the cuts were made.
  std::string cut_widths = "[";
  for (const auto& c : scene.surface().cuts()) {
    char w[32];
    std::snprintf(w, sizeof w, "%s%.2f", cut_widths.size() > 1 ? ", " : "", c.opening * 1e3);
    cut_widths += w;
  }
  cut_widths += "]";
  tissue::GrooveFigures groove{};  // the widest
  for (const auto& g : grooves)
    if (g.top_gap >= groove.top_gap) groove = g;
  using ull = unsigned long long;
  std::fprintf(f,
               "{\n  \"frames\": %llu,\n  \"hands\": %zu,\n  \"connections\": %u,\n  \"rt_losses\": %u,\n  \"link\": \"%s\",\n"
               "  \"samples_received\": %llu,\n  \"samples_total\": %llu,\n  \"first_seq\": %llu,\n  \"last_seq\": %llu,\n"
               "  \"lost\": %llu,\n  \"out_of_order\": %llu,\n  \"discarded_on_attach\": %llu,\n  \"max_batch\": %llu,\n"
               "  \"patches_published\": %llu,\n  \"samples_rejected\": %llu,\n  \"sample_ring_resets\": %llu,\n"
               "  \"status_rejected\": %llu,\n  \"drill_removals\": %llu,\n  \"voxels_drilled\": %llu,\n  \"bone_updates\": %llu,\n"
               "  \"cuts\": %zu,\n  \"longest_cut_mm\": %.2f,\n"
               "  \"cut_opening_mm\": %.2f,\n  \"cut_from_mm\": [%.2f, %.2f, %.2f],\n  \"cut_to_mm\": [%.2f, %.2f, %.2f],\n"
               "  \"grooves\": %zu,\n  \"groove_width_mm\": %.2f,\n  \"groove_depth_mm\": %.2f,\n  \"groove_faces\": %zu,\n"
               "  \"contacts\": %llu,\n  \"contact_ends\": %llu,\n  \"ruptures\": %llu,\n  \"cut_steps\": %llu,\n"
               "  \"grabs\": %llu,\n  \"releases\": %llu,\n  \"pulls\": %llu,\n"
               "  \"clamped_ticks\": %llu,\n  \"faded_ticks\": %llu,\n  \"fault_ticks\": %llu,\n"
               "  \"scenario\": \"%s\",\n  \"task_progress\": %.3f,\n  \"task_damaged\": %zu,\n"
               "  \"blood_lost_ml\": %.4f,\n  \"blood_on_tissue_ml\": %.4f,\n  \"blood_swabbed_ml\": %.4f,\n"
               "  \"vessel_bleeding\": %s,\n  \"blood_ledger_error\": %.3g,\n  \"blood_cells\": %zu,\n  \"blood_ms_per_frame\": %.3f,\n"
               "  \"screenshot\": \"%s\",\n  \"screenshot_variance\": %.3f,\n  \"cut_widths_mm\": %s\n}\n",
               static_cast<ull>(run.frames), s.hands(), s.connections(), s.rt_losses(),
               s.link() == Link::kConnected ? "connected" : s.link() == Link::kLost ? "lost" : "waiting",
               static_cast<ull>(st.received), static_cast<ull>(s.samples_total()), static_cast<ull>(st.first_seq),
               static_cast<ull>(st.last_seq), static_cast<ull>(st.lost), static_cast<ull>(st.out_of_order),
               static_cast<ull>(st.discarded), static_cast<ull>(st.max_batch), static_cast<ull>(s.patches_published()),
               static_cast<ull>(st.rejected), static_cast<ull>(st.ring_resets), static_cast<ull>(st.status_rejected),
               static_cast<ull>(ev.drill_removals), static_cast<ull>(ev.voxels_drilled), static_cast<ull>(ev.bone_updates),
               cuts.cuts, cuts.longest * 1e3, cuts.opening * 1e3, cuts.from.x * 1e3, cuts.from.y * 1e3, cuts.from.z * 1e3,
               cuts.to.x * 1e3, cuts.to.y * 1e3, cuts.to.z * 1e3, grooves.size(), groove.top_gap * 1e3, groove.depth * 1e3,
               groove.faces, static_cast<ull>(ev.contacts), static_cast<ull>(ev.contact_ends), static_cast<ull>(ev.ruptures),
               static_cast<ull>(ev.cut_steps), static_cast<ull>(ev.grabs), static_cast<ull>(ev.releases),
               static_cast<ull>(ev.pulls), static_cast<ull>(ev.clamped_ticks), static_cast<ull>(ev.faded_ticks),
               static_cast<ull>(ev.fault_ticks), scenario_name.c_str(), task ? task->progress : 0.0,
               task ? task->damaged.size() : std::size_t{0}, bf.lost_ml, bf.on_tissue_ml, bf.swabbed_ml,
               bf.vessel_bleeding ? "true" : "false", bf.ledger_error, bf.cells, run.blood_ms_per_frame, run.screenshot.c_str(),
               std::isfinite(run.screenshot_variance) ? run.screenshot_variance : -1.0, cut_widths.c_str());
  return std::fclose(f) == 0;
}

int print_replay_verdict(const record::Replay& replay, const std::string& path, const std::string& error, bool headless) {
  using ull = unsigned long long;
  const record::ReplayCheck& ck = replay.check();
  const record::Recording& rec = replay.recording();
  // A verdict only for what was checked: a replay that stopped early says so, and one that
  // checked nothing is no evidence of anything.
  const bool all = error.empty() && replay.done();
  const char* verdict = !ck.exact()     ? "DIFFERS"
                        : ck.ticks == 0 ? "nothing replayed"
                        : !all          ? "bit-exact as far as it went"
                                        : "bit-exact";
  std::printf("lancet-viz: replay of %s: %llu of %zu ticks and %llu of %zu frames; servo state hashes %llu checked, %llu differ; "
              "samples differing %llu; scene hashes %llu checked, %llu differ: %s\n",
              path.c_str(), static_cast<ull>(ck.ticks), rec.samples.size(), static_cast<ull>(ck.frames), rec.frames.size(),
              static_cast<ull>(ck.servo_hashes), static_cast<ull>(ck.servo_hash_mismatches), static_cast<ull>(ck.sample_mismatches),
              static_cast<ull>(ck.scene_hashes), static_cast<ull>(ck.scene_hash_mismatches), verdict);
  if (rec.cut_short)
    std::printf("lancet-viz: the recording was cut short (its recorder never finished it: the viz was killed or the power "
                "lost): replayed up to where the file ends\n");
  if (ck.gap_seq != 0)
    std::printf("lancet-viz: %llu servo ticks are missing before tick %llu (the viz stalled longer than the sample ring holds): "
                "the servo was checked up to there, the scene throughout (%llu ticks after the gap drove it as recorded)\n",
                static_cast<ull>(ck.ticks_lost), static_cast<ull>(ck.gap_seq), static_cast<ull>(ck.ticks_unchecked));
  if (!error.empty()) std::printf("lancet-viz: the replay stopped: %s\n", error.c_str());
  int code = !error.empty() || (headless && (!all || ck.ticks == 0)) ? 1 : 0;
  if (!ck.exact()) {
    std::printf("lancet-viz: the first difference: servo tick %llu, frame %llu\n", static_cast<ull>(ck.first_bad_seq),
                static_cast<ull>(ck.first_bad_frame > 0 ? ck.first_bad_frame - 1 : 0));
    code = 1;
  }
  return code;
}

}  // namespace lancet::viz
