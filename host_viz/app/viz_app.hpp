#pragma once
// VizApp: lancet-viz's frame loop. Each frame: the simulation steps (live: sim::run_frame through
// the link, then the recording; replay: the recorded frames up to the replay's clock), what changed
// shape is sent to the GPU with the blood on it, the window's input is taken, the scene, the status
// lines and the panel are drawn, and what the panel or the keys asked for is done.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "app/live_frame.hpp"
#include "app/recorder_control.hpp"
#include "app/replay_clock.hpp"
#include "app/sample_trace.hpp"
#include "app/station.hpp"
#include "app/viz_cli.hpp"
#include "app/viz_input.hpp"
#include "app/viz_panel.hpp"
#include "app/viz_session.hpp"
#include "app/volume_view.hpp"
#include "record/replay.hpp"
#include "render/overlay.hpp"
#include "render/scene_renderer.hpp"
#include "render/window.hpp"
#include "sim/scene_sim.hpp"

namespace lancet::viz {

/// What lancet-viz runs on: its own simulation (live), or a replay's.
struct VizSources {
  std::unique_ptr<sim::SceneSim> sim;        ///< live (null when replaying)
  std::unique_ptr<record::Replay> replay;    ///< --replay (null when live)
  std::unique_ptr<SampleTrace> trace;        ///< --trace (null: none)
  std::string tool;                          ///< the tool to pick when connected ("" none)
  Station* station = nullptr;                ///< --trainee: where each recording goes (null: none); outlives the app
};

class VizApp {
 public:
  VizApp(const VizOptions& options, render::Window& window, VizSources sources, std::string lancet_version);
  ~VizApp();
  VizApp(const VizApp&) = delete;
  VizApp& operator=(const VizApp&) = delete;

  /// The frame loop, until `stop`, the window closes, Esc, the duration, or a headless replay's
  /// end; then the screenshot. Returns the exit code so far (4: the renderer failed).
  [[nodiscard]] int run(const std::atomic<bool>& stop);
  /// The run's end: the recording finished, the summary printed, the stats written. Returns the
  /// exit code (exit_code, or the first failure of these).
  [[nodiscard]] int finish(int exit_code);

 private:
  struct Screen;  // the GL side, made in run()

  [[nodiscard]] sim::SceneSim& sim() noexcept { return replay_ ? replay_->sim() : *sim_; }
  [[nodiscard]] bool time_up(double elapsed_s);
  void step_live(std::int64_t now, double wall_dt);
  void step_replay(double wall_dt);
  void upload_mesh_and_blood();
  [[nodiscard]] bool take_input(std::int64_t now);
  void draw(std::int64_t now);
  [[nodiscard]] render::PanelState panel_state(std::int64_t now, const ToolSample* latest);
  void do_panel_actions(const render::PanelActions& act, std::int64_t now);
  void arm_recording(const std::string& path);
  void manage_recording();
  void write_snapshot();

  const VizOptions& o_;
  render::Window& win_;
  std::unique_ptr<sim::SceneSim> sim_;
  std::unique_ptr<record::Replay> replay_;
  std::unique_ptr<SampleTrace> trace_;
  std::string tool_;
  Station* station_;
  VizSession session_;
  RecorderControl recorder_;
  LiveFrame live_;
  ReplayClock clock_;
  std::string replay_error_;  ///< why a replay stopped before its end
  std::array<std::vector<ToolMode>, kHandCount> offered_;  ///< by Hand: the tools its keys may pick
  std::array<std::string, kHandCount> keys_;
  std::vector<Vec3> guide_;   ///< the scenario's incision line on the surface
  std::vector<std::string> preset_names_;
  Interaction ui_;
  VolumeView volume_;
  PanelHistory history_;
  WakeWindow wake_;
  std::unique_ptr<Screen> screen_;
  std::uint64_t shown_revision_ = 0;
  bool shown_walls_off_ = false;
  std::uint32_t tool_sent_for_ = 0;  ///< the connection the starting tool was last sent on
  std::string left_tool_;            ///< the left hand's starting tool (the scenario's left_start_tool; "" none)
  std::uint32_t left_tool_sent_for_ = 0;
  bool screenshot_frame_ = false;    ///< the extra frame drawn in --screenshot-view
  bool want_snapshot_ = false, want_record_ = false;
  bool stop_ = false;
  std::string last_message_;
  std::chrono::steady_clock::time_point last_frame_;
  int fw_ = 0, fh_ = 0;              ///< framebuffer, pixels
  std::uint64_t frames_ = 0;
  double variance_ = -1;
  double blood_ms_ = 0;              ///< spent on the blood, all frames
  int exit_code_ = 0;
};

}  // namespace lancet::viz
