#pragma once
// What lancet-viz writes over the scene: the status lines (the link, the servo, the tool, the
// samples, the keys) and the controls panel's contents (the force and the servo's wake-up latency
// over the last seconds, the blood, the recording or the replay). Text only; Overlay draws it.

#include <array>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "app/viz_input.hpp"
#include "app/viz_session.hpp"
#include "blood/bleeding.hpp"
#include "tissue/scenario_scene.hpp"
#include "record/replay.hpp"
#include "render/overlay.hpp"

namespace lancet::viz {

/// The lines over the scene: the scenario and its task, the link, lancet-rt's servo and faults,
/// the tool, the tissue's last event, the samples; in a window, the keys (`keys`: the tools').
[[nodiscard]] std::vector<render::OverlayLine> status_lines(const VizSession& s, const Interaction& ui, bool headless,
                                                            const tissue::SceneEvents& events, const scenario::Scenario* scenario,
                                                            const score::TaskStatus* task, const std::string& keys);
/// A replay has no link: its line replaces the link's and the samples' ones.
void replace_link_lines(std::vector<render::OverlayLine>& lines, const VizSession& s, const record::Replay& replay,
                        const std::string& path, double speed, bool paused);
/// The volume's line (preset, window/level; the keys in a window).
[[nodiscard]] std::string volume_line(const Interaction& ui, const std::vector<std::string>& preset_names, bool headless);
/// "1: probe / 2: scalpel / ...": the keys of the offered tools.
[[nodiscard]] std::string tool_keys(const std::vector<ToolMode>& offered);
/// The panel's blood lines: the loss, and each vessel (bleeding ones as alerts).
[[nodiscard]] std::vector<render::OverlayLine> blood_lines(const blood::Bleeding& blood);
/// The replay's line and timeline on the panel.
void replay_panel(const record::Replay& replay, double speed, bool paused, render::PanelState& panel);

/// The force and the servo's p99 wake-up over the last kFrames frames, oldest first.
class PanelHistory {
 public:
  static constexpr std::size_t kFrames = 300;
  /// force: |F| in N; wake_p99_us: µs (0 without lancet-rt).
  void add(float force, float wake_p99_us);
  [[nodiscard]] const std::vector<float>& force() const noexcept { return force_; }
  [[nodiscard]] const std::vector<float>& wake_p99() const noexcept { return wake_; }

 private:
  std::vector<float> force_, wake_;
};

/// The servo's wake-up latency histogram over the last kWindowNs: RtStatus counts since lancet-rt
/// started, so today's counts less those of a snapshot at least that old.
class WakeWindow {
 public:
  static constexpr std::int64_t kWindowNs = 5'000'000'000;
  /// The frame's RtStatus (none: not connected) at now_ns.
  void update(const std::optional<RtStatus>& status, std::int64_t now_ns);
  [[nodiscard]] const std::vector<std::uint64_t>& bins() const noexcept { return recent_; }  ///< empty: none
  [[nodiscard]] float window_s() const noexcept { return window_s_; }  ///< 0: since lancet-rt started

 private:
  std::deque<std::pair<std::int64_t, std::array<std::uint64_t, kWakeBins>>> snapshots_;  ///< (time, bins)
  std::vector<std::uint64_t> recent_;
  float window_s_ = 0;
};

}  // namespace lancet::viz
