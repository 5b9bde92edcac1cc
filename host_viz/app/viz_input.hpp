#pragma once
// The interactive window's keyboard and mouse: what the user is looking at (Interaction: camera,
// view, volume window/level and clip) and what they asked for this frame (InputActions). Keys act
// on the press, not while held: M mouse drives the stylus, H switches the hand the mouse and the
// keys drive (right or left), 1-5 pick that hand's tool, R reset that hand, W re-arm the watchdog
// (and that hand's arm), V next view, P next preset, T the patch's wireframe on or off, F9 record, F12
// screenshot, space pause a replay, Esc quit.
// Left drag rotates, right drag sets window/level, the wheel zooms (or sets the stylus depth).

#include <vector>

#include "lancet/shared_model/messages.hpp"

struct GLFWwindow;

namespace lancet::viz {

/// What the user is looking at, and how the mouse drives.
struct Interaction {
  bool mouse_drives_stylus = false;
  Hand hand = Hand::kRight;    ///< the hand the mouse and the tool keys drive (H switches)
  double depth_mm = 3.0;       ///< how far below the surface the mouse-driven stylus is pushed
  bool rotating = false, windowing = false;
  double last_x = 0, last_y = 0;  ///< cursor, window pixels
  int view = 0;                ///< 0 mesh, 1 mesh with the volume composited, 2 the volume alone
  int preset = 1;              ///< index into volume::kTfPresets
  float level = 0, width = 1;  ///< window/level: HU shift and width scale of the preset
  bool clip = false;           ///< the volume cut away above clip_mm (world z)
  float clip_mm = -10;
  bool show_patch = false;     ///< the TissuePatch sent to lancet-rt drawn as a wireframe (a developer's view)
  float yaw = 0.6f, pitch = 0.55f, distance = 0.26f;  ///< camera: rad, rad, m
};

/// What the keys asked for this frame.
struct InputActions {
  bool quit = false;              ///< Esc
  bool stylus_released = false;   ///< M turned mouse driving off, or H switched hands: release that hand's stylus target
  Hand released_hand = Hand::kRight;  ///< whose
  std::vector<Command> commands;  ///< for lancet-rt, in the order the keys were pressed
  bool snapshot = false;          ///< F12
  bool record = false;            ///< F9
  bool replay_pause = false;      ///< space
};

/// Polls the window once a frame.
class InputPoller {
 public:
  /// Makes the mouse wheel zoom the camera of `ui` (or set the stylus depth); ui outlives the window's use.
  InputPoller(GLFWwindow* window, Interaction& ui);
  ~InputPoller();
  InputPoller(const InputPoller&) = delete;
  InputPoller& operator=(const InputPoller&) = delete;

  /// The keys pressed since the last poll and the mouse drags (applied to ui). offered: the tools
  /// the keys may pick; presets: how many presets P cycles; mouse_taken: the panel has the mouse.
  [[nodiscard]] InputActions poll(Interaction& ui, const std::vector<ToolMode>& offered, int presets, bool mouse_taken);
  /// The window's size in window pixels (the cursor's position, polled, is ui.last_x, ui.last_y).
  void window_size(int& width, int& height) const;

 private:
  GLFWwindow* window_;
  bool key_down_[15] = {};
};

}  // namespace lancet::viz
