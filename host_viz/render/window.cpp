#include "render/window.hpp"

#include <epoxy/egl.h>
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

namespace lancet::render {
namespace {
std::string g_last_glfw_error;
void on_glfw_error(int code, const char* text) { g_last_glfw_error = std::to_string(code) + ": " + text; }
}  // namespace

namespace {

std::string egl_error_text() {
  char buf[32];
  std::snprintf(buf, sizeof buf, "EGL error 0x%04x", static_cast<unsigned>(eglGetError()));
  return buf;
}

bool has_extension(const char* list, const char* name) {
  if (list == nullptr) return false;
  const std::size_t n = std::strlen(name);
  for (const char* p = list; (p = std::strstr(p, name)) != nullptr; p += n)
    if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return true;
  return false;
}

}  // namespace

Result<std::unique_ptr<Window>> Window::create_headless(const WindowParams& p) {
  // Client extensions, before any display exists.
  const char* client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  if (client == nullptr || !has_extension(client, "EGL_EXT_platform_base"))
    return Error{ErrorCode::kUnsupported, "headless GL needs EGL with EGL_EXT_platform_base (Debian: libegl1 libegl-mesa0); "
                                          "this EGL offers: " + std::string(client ? client : "nothing (no EGL library?)")};
  EGLDisplay dpy = EGL_NO_DISPLAY;
  std::string platform;
  if (has_extension(client, "EGL_MESA_platform_surfaceless")) {
    dpy = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    platform = "EGL surfaceless";
  }
  if (dpy == EGL_NO_DISPLAY && has_extension(client, "EGL_EXT_platform_device") && has_extension(client, "EGL_EXT_device_enumeration")) {
    EGLDeviceEXT devices[8];
    EGLint n = 0;
    if (eglQueryDevicesEXT(8, devices, &n) == EGL_TRUE && n > 0) {
      dpy = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[0], nullptr);
      platform = "EGL device";
    }
  }
  if (dpy == EGL_NO_DISPLAY)
    return Error{ErrorCode::kUnsupported, "headless GL: EGL has neither EGL_MESA_platform_surfaceless nor a device "
                                          "(EGL_EXT_platform_device); install Mesa's EGL (libegl-mesa0)"};
  EGLint major = 0, minor = 0;
  if (eglInitialize(dpy, &major, &minor) != EGL_TRUE)
    return Error{ErrorCode::kSystem, "headless GL: eglInitialize failed on the " + platform + " platform (" + egl_error_text() + ")"};
  const auto fail = [&](const std::string& what) {
    const std::string text = "headless GL: " + what + " (" + egl_error_text() + ")";
    eglTerminate(dpy);
    return Error{ErrorCode::kSystem, text};
  };
  const char* ext = eglQueryString(dpy, EGL_EXTENSIONS);
  if (!has_extension(ext, "EGL_KHR_surfaceless_context")) return fail("EGL_KHR_surfaceless_context is missing");
  if (eglBindAPI(EGL_OPENGL_API) != EGL_TRUE) return fail("EGL cannot bind desktop OpenGL");
  EGLConfig config = nullptr;  // EGL_NO_CONFIG_KHR
  if (!has_extension(ext, "EGL_KHR_no_config_context")) {
    const EGLint want[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
    EGLint n = 0;
    if (eglChooseConfig(dpy, want, &config, 1, &n) != EGL_TRUE || n == 0) return fail("no EGL config for desktop OpenGL");
  }
  const EGLint attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 4, EGL_CONTEXT_MINOR_VERSION, 5, EGL_CONTEXT_OPENGL_PROFILE_MASK,
                            EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
  EGLContext ctx = eglCreateContext(dpy, config, EGL_NO_CONTEXT, attribs);
  if (ctx == EGL_NO_CONTEXT) return fail("cannot create an OpenGL 4.5 core context (Mesa's llvmpipe provides one)");
  if (eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx) != EGL_TRUE) {
    eglDestroyContext(dpy, ctx);
    return fail("cannot make the context current without a surface");
  }
  std::unique_ptr<Window> w(new Window());
  w->width_ = p.width;
  w->height_ = p.height;
  w->egl_display_ = dpy;
  w->egl_context_ = ctx;
  w->egl_platform_ = platform + " " + std::to_string(major) + "." + std::to_string(minor);
  return w;
}

Result<std::unique_ptr<Window>> Window::create(const WindowParams& p) {
  if (!p.visible) return create_headless(p);
  glfwSetErrorCallback(on_glfw_error);
  const char* display = std::getenv("DISPLAY");
  const char* wayland = std::getenv("WAYLAND_DISPLAY");
  if ((display == nullptr || *display == '\0') && (wayland == nullptr || *wayland == '\0')) {
    return Error{ErrorCode::kNotFound,
                 "no display (DISPLAY is not set). To run without a screen, use the headless mode (no X server "
                 "needed):\n  lancet-viz --headless --duration 5 --screenshot lancet.png\n"
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
  glfwSwapInterval(1);
  std::unique_ptr<Window> win(new Window());
  win->window_ = w;
  win->width_ = p.width;
  win->height_ = p.height;
  return win;
}

Window::~Window() {
  last_frame_.reset();  // while the context is current
  if (window_ != nullptr) {
    glfwDestroyWindow(window_);
    glfwTerminate();
  }
  if (egl_display_ != nullptr) {
    eglMakeCurrent(egl_display_, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(egl_display_, egl_context_);
    eglTerminate(egl_display_);
  }
}

bool Window::should_close() const { return window_ != nullptr && glfwWindowShouldClose(window_) == GLFW_TRUE; }

void Window::swap_and_poll() {
  if (window_ == nullptr) {
    // No swap paces a headless loop: without a wait, llvmpipe queues every flushed frame (up to
    // 64 scenes, each holding the frame's binned triangles) while the loop draws the next, and a
    // loop that draws faster than the rasterizer finishes holds dozens of frames
    // (docs/PERFORMANCE.md, "lancet-viz memory"). So, as a double-buffered swap does, this frame
    // is queued and the one before it waited for: the rasterizer still draws a frame while the
    // loop simulates the next, and the driver holds at most those two.
    Fence ended = Fence::insert();
    glFlush();
    (void)last_frame_.wait();
    last_frame_ = std::move(ended);
    return;
  }
  glfwSwapBuffers(window_);
  glfwPollEvents();
}

void Window::framebuffer_size(int& w, int& h) const {
  if (window_ == nullptr) {
    w = width_, h = height_;
    return;
  }
  glfwGetFramebufferSize(window_, &w, &h);
}

std::string Window::gl_description() const {
  const auto* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  const auto* version = reinterpret_cast<const char*>(glGetString(GL_VERSION));
  return std::string(renderer ? renderer : "?") + ", OpenGL " + (version ? version : "?") +
         (egl_platform_.empty() ? "" : ", headless (" + egl_platform_ + ")");
}

}  // namespace lancet::render
