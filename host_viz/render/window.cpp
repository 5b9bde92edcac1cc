#include "render/window.hpp"

#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <cstdlib>

namespace lancet::render {
namespace {
std::string g_last_glfw_error;
void on_glfw_error(int code, const char* text) { g_last_glfw_error = std::to_string(code) + ": " + text; }
}  // namespace

Result<std::unique_ptr<Window>> Window::create(const WindowParams& p) {
  glfwSetErrorCallback(on_glfw_error);
  const char* display = std::getenv("DISPLAY");
  const char* wayland = std::getenv("WAYLAND_DISPLAY");
  if ((display == nullptr || *display == '\0') && (wayland == nullptr || *wayland == '\0')) {
    return Error{ErrorCode::kNotFound,
                 "no display (DISPLAY is not set). To run without a screen, use the headless mode under a "
                 "virtual display:\n  xvfb-run -a lancet-viz --headless --duration 5 --screenshot lancet.png\n"
                 "or run `./lancet demo`, which does this for you when there is no display."};
  }
  if (glfwInit() != GLFW_TRUE) {
    return Error{ErrorCode::kSystem, "GLFW could not initialise (" + g_last_glfw_error +
                                         "); is the X server in DISPLAY reachable?"};
  }
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  glfwWindowHint(GLFW_VISIBLE, p.visible ? GLFW_TRUE : GLFW_FALSE);
  glfwWindowHint(GLFW_SAMPLES, 0);
  GLFWwindow* w = glfwCreateWindow(p.width, p.height, p.title.c_str(), nullptr, nullptr);
  if (w == nullptr) {
    glfwTerminate();
    return Error{ErrorCode::kSystem, "cannot create an OpenGL 4.5 core window (" + g_last_glfw_error +
                                         "); Lancet needs GL 4.5 (Mesa llvmpipe provides it: apt-get install "
                                         "libgl1-mesa-dri)"};
  }
  glfwMakeContextCurrent(w);
  glfwSwapInterval(p.visible ? 1 : 0);
  return std::unique_ptr<Window>(new Window(w));
}

Window::~Window() {
  if (window_ != nullptr) glfwDestroyWindow(window_);
  glfwTerminate();
}

bool Window::should_close() const { return glfwWindowShouldClose(window_) == GLFW_TRUE; }

void Window::swap_and_poll() {
  glfwSwapBuffers(window_);
  glfwPollEvents();
}

void Window::framebuffer_size(int& w, int& h) const { glfwGetFramebufferSize(window_, &w, &h); }

std::string Window::gl_description() const {
  const auto* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  const auto* version = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  return std::string(renderer ? renderer : "?") + ", OpenGL " + (version ? version : "?");
}

}  // namespace lancet::render
