#pragma once
// Window: one OpenGL 4.5 core context. Visible (the demo's window): GLFW, which needs a display.
// Headless: no window and no X server at all: an EGL context without a surface (Mesa's
// EGL_MESA_platform_surfaceless, else the first EGL device through EGL_EXT_platform_device), so
// rendering goes to framebuffer objects and is read back; DISPLAY is neither needed nor used.
// GLFW 3.3 cannot make such a context, hence EGL here (through libepoxy: its
// eglGetPlatformDisplayEXT, as eglGetPlatformDisplay aborts before a display exists).

#include <memory>
#include <string>

#include "lancet/shared_model/result.hpp"
#include "render/gl_objects.hpp"

struct GLFWwindow;

namespace lancet::render {

struct WindowParams {
  int width = 1280;
  int height = 720;
  bool visible = true;   ///< false: headless (EGL, no window, no display needed)
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

  /// The GLFW window; nullptr when headless.
  [[nodiscard]] GLFWwindow* handle() const noexcept { return window_; }
  [[nodiscard]] bool headless() const noexcept { return window_ == nullptr; }
  [[nodiscard]] bool should_close() const;
  /// Ends the frame: shows it and polls the window's events. Headless, where no swap paces the
  /// loop, it waits for the frame before this one to be drawn, so that the driver holds at most
  /// one frame besides the one being drawn (see window.cpp).
  void swap_and_poll();
  /// Framebuffer size in pixels.
  void framebuffer_size(int& w, int& h) const;
  /// GL_RENDERER and GL_VERSION strings of the context (and how it was made, when headless).
  [[nodiscard]] std::string gl_description() const;

 private:
  Window() = default;
  static Result<std::unique_ptr<Window>> create_headless(const WindowParams& params);
  GLFWwindow* window_ = nullptr;
  int width_ = 0, height_ = 0;
  // EGL (headless): display, context (void* so no EGL header leaks into users).
  void* egl_display_ = nullptr;
  void* egl_context_ = nullptr;
  std::string egl_platform_;
  Fence last_frame_;  ///< headless: the end of the frame before the one being drawn
};

}  // namespace lancet::render
