#pragma once
// Overlay: the on-screen status panel (Dear ImGui, drawn into the scene's framebuffer so that
// screenshots show it too).

#include <string>
#include <vector>

struct GLFWwindow;

namespace lancet::render {

struct OverlayLine {
  std::string text;
  bool alert = false;  ///< drawn in red
};

class Overlay {
 public:
  /// Needs the window's GL context current. install_callbacks: let ImGui see mouse/keyboard.
  /// window nullptr (headless): no input, the panel is drawn only.
  Overlay(GLFWwindow* window, bool install_callbacks);
  ~Overlay();
  Overlay(const Overlay&) = delete;
  Overlay& operator=(const Overlay&) = delete;

  /// Draws a titled panel with the lines into the currently bound framebuffer (w×h pixels).
  void draw(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height);
  /// The same panel laid out without drawing it (so the next draw has its final size).
  void layout(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height);
  /// True while ImGui wants the mouse (the scene should ignore it).
  [[nodiscard]] bool wants_mouse() const;

 private:
  bool glfw_ = false;  ///< the GLFW platform backend is in use (not headless)
  void build(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height);
};

}  // namespace lancet::render
