#include "app/viz_input.hpp"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <algorithm>
#include <cmath>

namespace lancet::viz {

namespace {

Interaction* g_scroll_ui = nullptr;  // GLFW's scroll callback has no user pointer of ours

void on_scroll(GLFWwindow*, double, double dy) {
  Interaction* ui = g_scroll_ui;
  if (ui == nullptr) return;
  if (ui->mouse_drives_stylus) {
    ui->depth_mm = std::clamp(ui->depth_mm + dy, -10.0, 15.0);
  } else {
    ui->distance = std::clamp(ui->distance * static_cast<float>(std::pow(0.9, dy)), 0.05f, 1.0f);
  }
}

// The keys, in the order their actions are taken within a frame.
enum Key { kH, kM, k1, k2, k3, k4, kR, kW, kV, kP, k5, kF12, kF9, kSpace, kT, kKeys };
constexpr int kKeyCodes[kKeys] = {GLFW_KEY_H, GLFW_KEY_M, GLFW_KEY_1,  GLFW_KEY_2,   GLFW_KEY_3,  GLFW_KEY_4,     GLFW_KEY_R, GLFW_KEY_W,
                                  GLFW_KEY_V, GLFW_KEY_P, GLFW_KEY_5, GLFW_KEY_F12, GLFW_KEY_F9, GLFW_KEY_SPACE, GLFW_KEY_T};
static_assert(kKeys == 15, "InputPoller::key_down_ holds one flag a key");

}  // namespace

InputPoller::InputPoller(GLFWwindow* window, Interaction& ui) : window_(window) {
  g_scroll_ui = &ui;
  glfwSetScrollCallback(window_, on_scroll);
}

InputPoller::~InputPoller() { g_scroll_ui = nullptr; }

InputActions InputPoller::poll(Interaction& ui, const std::vector<ToolMode>& offered, int presets, bool mouse_taken) {
  InputActions a;
  if (glfwGetKey(window_, GLFW_KEY_ESCAPE) == GLFW_PRESS) {
    a.quit = true;
    return a;
  }
  for (int k = 0; k < kKeys; ++k) {
    const bool down = glfwGetKey(window_, kKeyCodes[k]) == GLFW_PRESS;
    const bool pressed = down && !key_down_[k];
    key_down_[k] = down;
    if (!pressed) continue;
    Command c{};
    c.hand = ui.hand;
    switch (k) {
      case kH:
        // The other hand: the one the mouse drove lets go of its target (its script takes over).
        a.stylus_released = ui.mouse_drives_stylus;
        a.released_hand = ui.hand;
        ui.hand = ui.hand == Hand::kRight ? Hand::kLeft : Hand::kRight;
        break;
      case kV: ui.view = (ui.view + 1) % 3; break;
      case kT: ui.show_patch = !ui.show_patch; break;
      case kP:
        ui.preset = (ui.preset + 1) % presets;
        ui.level = 0, ui.width = 1;
        break;
      case kM:
        ui.mouse_drives_stylus = !ui.mouse_drives_stylus;
        a.stylus_released = !ui.mouse_drives_stylus;
        a.released_hand = ui.hand;
        break;
      case kR:
      case kW:
        c.kind = k == kR ? CommandKind::kReset : CommandKind::kRearm;
        a.commands.push_back(c);
        break;
      case kF12: a.snapshot = true; break;
      case kF9: a.record = true; break;
      case kSpace: a.replay_pause = true; break;
      default:  // 1-5: a tool, if the scenario offers it
        c.kind = CommandKind::kSetToolMode;
        c.mode = static_cast<ToolMode>(k == k5 ? 4 : k - k1);
        if (std::find(offered.begin(), offered.end(), c.mode) != offered.end()) a.commands.push_back(c);
        break;
    }
  }
  double mx = 0, my = 0;
  glfwGetCursorPos(window_, &mx, &my);
  const bool left = glfwGetMouseButton(window_, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS && !mouse_taken;
  if (left && ui.rotating) {
    ui.yaw += static_cast<float>(mx - ui.last_x) * 0.005f;
    ui.pitch = std::clamp(ui.pitch + static_cast<float>(my - ui.last_y) * 0.005f, 0.05f, 1.5f);
  }
  // Right drag: window/level, as in 3D Slicer (across: level, up and down: width).
  const bool right = glfwGetMouseButton(window_, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS && !mouse_taken;
  if (right && ui.windowing) {
    ui.level += static_cast<float>(mx - ui.last_x) * 2.0f;
    ui.width = std::clamp(ui.width * std::pow(1.005f, static_cast<float>(my - ui.last_y)), 0.05f, 20.0f);
  }
  ui.windowing = right;
  ui.rotating = left;
  ui.last_x = mx, ui.last_y = my;
  return a;
}

void InputPoller::window_size(int& width, int& height) const {
  glfwGetWindowSize(window_, &width, &height);
}

}  // namespace lancet::viz
