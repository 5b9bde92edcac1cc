#include "app/viz_panel.hpp"

#include <algorithm>
#include <cstdio>
#include <iterator>
#include <numeric>

namespace lancet::viz {

std::vector<render::OverlayLine> status_lines(const VizSession& s, const Interaction& ui, bool headless,
                                              const tissue::SceneEvents& events, const scenario::Scenario* scenario,
                                              const score::TaskStatus* task, const std::string& keys) {
  using render::OverlayLine;
  std::vector<OverlayLine> lines;
  if (scenario != nullptr) {
    lines.push_back({"scenario " + scenario->name + ": " + scenario->description});
    if (task != nullptr) lines.push_back({task->line, !task->damaged.empty()});
  }
  lines.push_back({s.link_message(), s.link() != Link::kConnected});
  char buf[256];
  if (const auto& st = s.rt_status(); st && s.link() == Link::kConnected) {
    std::snprintf(buf, sizeof buf, "servo: tick %llu at %.0f Hz%s, missed %llu, wake p50 %.0f us, p99 %.0f us, max %.0f us",
                  static_cast<unsigned long long>(st->tick), 1e9 / static_cast<double>(st->period_ns),
                  st->fifo ? " (SCHED_FIFO)" : " (not real-time)", static_cast<unsigned long long>(st->missed),
                  static_cast<double>(st->wake_p50_ns) / 1e3, static_cast<double>(st->wake_p99_ns) / 1e3,
                  static_cast<double>(st->wake_max_ns) / 1e3);
    lines.push_back({buf});
    if (st->watchdog_tripped) lines.push_back({"WATCHDOG TRIPPED: force held at zero; press W to re-arm", true});
    const std::size_t hands = std::min<std::size_t>(st->hands, kHandCount);
    for (std::size_t h = 0; h < hands; ++h) {
      const HandStatus& hs = st->hand[h];
      const char* name = hands > 1 ? hand_name(static_cast<Hand>(h)) : "";
      if (hs.has_arm != 0 && hs.device_state == DeviceLifecycle::kFault) {
        std::snprintf(buf, sizeof buf, "%s%sARM FAULT: %s; its force held at zero; press W to re-arm%s", name, hands > 1 ? " " : "",
                      hs.fault_text, hs.link_lost ? " (bus link lost: reconnecting)" : "");
        lines.push_back({buf, true});
      }
      std::snprintf(buf, sizeof buf, "%s%sforce %.2f N (scale %.2f)%s", name, hands > 1 ? ": " : "", norm(hs.force), hs.force_scale,
                    hs.contact ? "  in contact" : "");
      lines.push_back({buf});
    }
  }
  for (std::size_t h = 0; h < kHandCount; ++h) {
    const auto hand = static_cast<Hand>(h);
    if (!s.has_sample(hand)) continue;
    const auto& t = s.latest(hand);
    const bool both = s.has_sample(Hand::kLeft);
    std::snprintf(buf, sizeof buf, "%s%s%s at (%.1f, %.1f, %.1f) mm%s", both ? hand_name(hand) : "", both ? " hand: " : "tool ",
                  tool_name(t.mode), t.tool.position.x * 1e3, t.tool.position.y * 1e3, t.tool.position.z * 1e3,
                  both && hand == ui.hand && !headless ? "  (keys and mouse: H switches)" : "");
    lines.push_back({buf});
  }
  if (!events.last.empty()) lines.push_back({events.last, events.last_is_warning});
  const auto& st = s.stats();
  std::snprintf(buf, sizeof buf, "samples %llu received, %llu lost, %llu out of order; patch %u triangles",
                static_cast<unsigned long long>(st.received), static_cast<unsigned long long>(st.lost),
                static_cast<unsigned long long>(st.out_of_order), s.patch(Hand::kRight).n_triangles + s.patch(Hand::kLeft).n_triangles);
  lines.push_back({buf, st.lost > 0 || st.out_of_order > 0});
  if (st.rejected + st.ring_resets + st.status_rejected > 0) {
    std::snprintf(buf, sizeof buf, "shared segment: %llu samples and %llu status reads rejected, ring reset %llu times (%s)",
                  static_cast<unsigned long long>(st.rejected), static_cast<unsigned long long>(st.status_rejected),
                  static_cast<unsigned long long>(st.ring_resets), st.last_reject != nullptr ? st.last_reject : "-");
    lines.push_back({buf, true});
  }
  if (!headless) {
    lines.push_back({ui.mouse_drives_stylus ? "M: mouse drives the stylus (scroll: depth), M again: script"
                                            : "M: drive the stylus with the mouse; drag: rotate; scroll: zoom"});
    lines.push_back({keys + "   H: other hand   V: volume view   R: reset   W: re-arm watchdog   F9: record   Esc: quit"});
  }
  return lines;
}

void replace_link_lines(std::vector<render::OverlayLine>& lines, const VizSession& s, const record::Replay& replay,
                        const std::string& path, double speed, bool paused) {
  std::erase_if(lines, [&](const render::OverlayLine& l) {
    return l.text == s.link_message() || l.text.rfind("samples ", 0) == 0;  // no link: its figures say nothing
  });
  char buf[160];
  std::snprintf(buf, sizeof buf, "REPLAY %s  %.1f / %.1f s at %gx%s; patch %u triangles", path.c_str(), replay.time_s(),
                replay.duration_s(), speed, paused ? " (paused: space)" : "",
                replay.patch() != nullptr ? replay.patch()->n_triangles : 0u);
  lines.insert(lines.begin(), {buf});
}

std::string volume_line(const Interaction& ui, const std::vector<std::string>& preset_names, bool headless) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "volume: %s, level %+.0f HU, width x%.2f%s", preset_names[static_cast<std::size_t>(ui.preset)].c_str(),
                static_cast<double>(ui.level), static_cast<double>(ui.width),
                headless ? "" : "   V: view, P: preset, right drag: window/level");
  return buf;
}

std::string tool_keys(const std::vector<ToolMode>& offered) {
  std::string keys;
  for (auto m : offered) {
    keys += keys.empty() ? "" : " / ";
    keys += std::to_string(static_cast<int>(m) + 1) + ": " + tool_name(m);
  }
  return keys;
}

std::vector<render::OverlayLine> blood_lines(const blood::Bleeding& blood) {
  std::vector<render::OverlayLine> lines;
  const blood::BloodFigures bf = blood.figures();
  char buf[160];
  std::snprintf(buf, sizeof buf, "blood lost %.2f mL (on the tissue %.2f, swabbed %.2f)", bf.lost_ml, bf.on_tissue_ml, bf.swabbed_ml);
  lines.push_back({buf, false});
  for (const auto& src : blood.sources()) {
    if (src.kind != blood::BloodSource::Kind::kVessel) continue;
    std::snprintf(buf, sizeof buf, "%s: %s", src.name.c_str(),
                  src.stopped ? "stopped" : src.pressed_s > 0 ? "pressed..." : "BLEEDING: press it 3 s with the probe");
    lines.push_back({buf, !src.stopped});
  }
  return lines;
}

void replay_panel(const record::Replay& replay, double speed, bool paused, render::PanelState& panel) {
  const record::ReplayCheck& ck = replay.check();
  char buf[200];
  std::snprintf(buf, sizeof buf, "replay: %llu ticks, %llu frames, %s", static_cast<unsigned long long>(ck.ticks),
                static_cast<unsigned long long>(ck.frames), ck.exact() ? "bit-exact so far" : "DIFFERS from the recording");
  panel.record_line = buf;
  panel.replay_duration_s = static_cast<float>(replay.duration_s());
  panel.replay_position = panel.replay_duration_s > 0 ? static_cast<float>(replay.time_s() / replay.duration_s()) : 1.0f;
  panel.replay_paused = paused;
  panel.replay_speed = static_cast<float>(speed);
}

void PanelHistory::add(float force, float wake_p99_us) {
  force_.push_back(force);
  wake_.push_back(wake_p99_us);
  for (auto* h : {&force_, &wake_})
    if (h->size() > kFrames) h->erase(h->begin(), h->begin() + static_cast<std::ptrdiff_t>(h->size() - kFrames));
}

void WakeWindow::update(const std::optional<RtStatus>& rs, std::int64_t now) {
  recent_.clear();
  window_s_ = 0;
  if (!rs) {
    snapshots_.clear();
    return;
  }
  std::array<std::uint64_t, kWakeBins> bins{};
  std::copy(std::begin(rs->wake_histogram), std::end(rs->wake_histogram), bins.begin());
  const auto total = [](const auto& b) { return std::accumulate(b.begin(), b.end(), std::uint64_t{0}); };
  if (!snapshots_.empty() && total(bins) < total(snapshots_.back().second)) snapshots_.clear();  // lancet-rt restarted
  snapshots_.emplace_back(now, bins);
  while (snapshots_.size() > 1 && now - snapshots_[1].first >= kWindowNs) snapshots_.pop_front();
  if (snapshots_.size() == 1) {  // nothing older yet: since lancet-rt started
    recent_.assign(bins.begin(), bins.end());
    return;
  }
  const auto& old = snapshots_.front();
  recent_.resize(kWakeBins);
  for (std::size_t i = 0; i < kWakeBins; ++i) recent_[i] = bins[i] >= old.second[i] ? bins[i] - old.second[i] : 0;
  window_s_ = static_cast<float>(static_cast<double>(now - old.first) * 1e-9);
}

}  // namespace lancet::viz
