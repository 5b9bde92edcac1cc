#pragma once
// Window: GLFW initialisation and one OpenGL 4.5 core context, visible (the demo) or hidden
// (headless: rendering goes to an offscreen framebuffer and is read back). Needs an X display;
// headless runs use Xvfb (xvfb-run), where Mesa's llvmpipe provides GL 4.5 core.

#include <memory>
#include <string>

#include "lancet/shared_model/result.hpp"

struct GLFWwindow;

namespace lancet::render {

struct WindowParams {
  int width = 1280;
  int height = 720;
  bool visible = true;
  std::string title = "Lancet";
};

class Window {
 public:
  /// Creates the window and makes its context current. Errors say why (no display, no GL 4.5)
  /// and what to do.
  static Result<std::unique_ptr<Window>> create(const WindowParams& params);
  ~Window();
  Window(const Window&) = delete;
  Window& operator=(const Window&) = delete;

  [[nodiscard]] GLFWwindow* handle() const noexcept { return window_; }
  [[nodiscard]] bool should_close() const;
  void swap_and_poll();
  /// Framebuffer size in pixels.
  void framebuffer_size(int& w, int& h) const;
  /// GL_RENDERER and GL_VERSION strings of the context.
  [[nodiscard]] std::string gl_description() const;

 private:
  explicit Window(GLFWwindow* w) : window_(w) {}
  GLFWwindow* window_ = nullptr;
};

}  // namespace lancet::render
