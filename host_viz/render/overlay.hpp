#pragma once
// Overlay: the on-screen status panel (Dear ImGui, drawn into the scene's framebuffer so that
// screenshots show it too).

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "volume/tf_editor.hpp"

struct GLFWwindow;

namespace lancet::render {

struct OverlayLine {
  std::string text;
  bool alert = false;  ///< drawn in red
};

/// The controls panel (right side): the task's progress, the tools on offer, the servo's
/// history, the volume's view and transfer function. What the user clicked comes back in
/// PanelActions (headless: nothing is clicked, the panel is drawn for the screenshot).
struct PanelState {
  /// lancet-viz --trainee: where the trainee stands in the curriculum, or that the records cannot
  /// be reached (alert); empty: no trainee.
  std::vector<OverlayLine> trainee;
  float task_progress = -1;             ///< 0..1; < 0: no task
  std::string task_label;
  std::vector<std::string> tools;       ///< offered, in key order
  std::vector<int> tool_keys;           ///< their ToolMode values
  int tool = -1;                        ///< the tool in use (ToolMode), -1 unknown
  std::vector<float> force_history;     ///< |F| in N, oldest first
  std::vector<float> wake_p99_history;  ///< µs, oldest first
  /// Wake-ups per RtStatus latency bin (kWakeBinLowerUs) over the last wake_window_s seconds;
  /// empty: no servo.
  std::vector<std::uint64_t> wake_bins;
  float wake_window_s = 0;
  bool watchdog_tripped = false, connected = false;
  int view = 0;                         ///< 0 mesh, 1 composite, 2 volume
  std::vector<std::string> presets;
  int preset = 0;
  float level = 0, width = 1;
  bool clip = false;                    ///< the volume is cut away above clip_mm (world z)
  float clip_mm = 0;
  bool show_patch = false;              ///< the patch sent to lancet-rt is drawn (wireframe)
  /// The volume's table, edited in place by the panel's editor (nullptr: no editor), drawn over
  /// the volume's histogram (same range as the editor; may be nullptr).
  /// The bleeding: blood loss and each bleeding vessel (alert: red); empty: no blood simulated.
  std::vector<OverlayLine> blood;
  volume::TfEditor* tf_editor = nullptr;
  const volume::Histogram* histogram = nullptr;
  /// Recording: whether a session is being recorded, and one line about it (file, ticks, lost).
  bool recording = false;
  bool can_record = false;              ///< a Record button is offered (not while replaying)
  std::string record_line;
  /// Replay: the timeline (0..1 of replay_duration_s; < 0: not replaying) and whether it is paused.
  float replay_position = -1;
  float replay_duration_s = 0;
  bool replay_paused = false;
  float replay_speed = 1;
};
struct PanelActions {
  int tool = -1;            ///< ToolMode picked, -1 none
  bool rearm = false, reset = false, screenshot = false;
  bool record = false;                     ///< the Record / Stop button
  bool replay_pause = false;               ///< pause or resume the replay
  float replay_speed = 0;                  ///< a new replay speed (0: unchanged)
  int view = -1, preset = -1;
  bool window_changed = false;
  float level = 0, width = 1;
  bool clip_changed = false, clip = false;
  float clip_mm = 0;
  bool patch_toggled = false;              ///< the "patch (T)" box was clicked
  bool tf_edited = false;                  ///< the editor changed the table: upload editor->table()
  std::array<float, 4> tf_canvas{};        ///< the editor's canvas on screen: x, y (top left), w, h in pixels
};

class Overlay {
 public:
  /// Needs the window's GL context current. install_callbacks: let ImGui see mouse/keyboard.
  /// window nullptr (headless): no input, the panel is drawn only.
  Overlay(GLFWwindow* window, bool install_callbacks);
  ~Overlay();
  Overlay(const Overlay&) = delete;
  Overlay& operator=(const Overlay&) = delete;

  /// Draws a titled panel with the lines (and, given a state, the controls panel) into the
  /// currently bound framebuffer (w×h pixels); returns what was clicked.
  PanelActions draw(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height,
                    const PanelState* panel = nullptr);
  /// The same panel laid out without drawing it (so the next draw has its final size).
  void layout(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height,
              const PanelState* panel = nullptr);
  /// True while ImGui wants the mouse (the scene should ignore it).
  [[nodiscard]] bool wants_mouse() const;

 private:
  bool glfw_ = false;  ///< the GLFW platform backend is in use (not headless)
  PanelActions build(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height,
                     const PanelState* panel);
};

}  // namespace lancet::render
