#pragma once
// Move-only RAII owners of OpenGL objects. The only OpenGL code in Lancet lives in host_viz/render.

#include <epoxy/gl.h>

#include <string>
#include <utility>

namespace lancet::render {

/// Owns one GL name; Deleter is a function deleting it.
template <void (*Deleter)(GLuint)>
class GlName {
 public:
  GlName() = default;
  explicit GlName(GLuint id) : id_(id) {}
  GlName(GlName&& o) noexcept : id_(std::exchange(o.id_, 0)) {}
  GlName& operator=(GlName&& o) noexcept {
    if (this != &o) {
      reset();
      id_ = std::exchange(o.id_, 0);
    }
    return *this;
  }
  GlName(const GlName&) = delete;
  GlName& operator=(const GlName&) = delete;
  ~GlName() { reset(); }
  void reset() {
    if (id_ != 0) Deleter(id_);
    id_ = 0;
  }
  [[nodiscard]] GLuint get() const { return id_; }

 private:
  GLuint id_ = 0;
};

namespace detail {
inline void delete_buffer(GLuint id) { glDeleteBuffers(1, &id); }
inline void delete_vertex_array(GLuint id) { glDeleteVertexArrays(1, &id); }
inline void delete_program(GLuint id) { glDeleteProgram(id); }
inline void delete_framebuffer(GLuint id) { glDeleteFramebuffers(1, &id); }
inline void delete_renderbuffer(GLuint id) { glDeleteRenderbuffers(1, &id); }
inline void delete_texture(GLuint id) { glDeleteTextures(1, &id); }
}  // namespace detail

using Buffer = GlName<detail::delete_buffer>;
using VertexArray = GlName<detail::delete_vertex_array>;
using Program = GlName<detail::delete_program>;
using Texture = GlName<detail::delete_texture>;
using Framebuffer = GlName<detail::delete_framebuffer>;
using Renderbuffer = GlName<detail::delete_renderbuffer>;

/// Owns one GL fence (glFenceSync): the point in the command stream it was inserted at. Move-only;
/// empty when default-made.
class Fence {
 public:
  Fence() = default;
  /// A fence after every command issued so far.
  [[nodiscard]] static Fence insert() { return Fence(glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0)); }
  Fence(Fence&& o) noexcept : sync_(std::exchange(o.sync_, nullptr)) {}
  Fence& operator=(Fence&& o) noexcept {
    if (this != &o) {
      reset();
      sync_ = std::exchange(o.sync_, nullptr);
    }
    return *this;
  }
  Fence(const Fence&) = delete;
  Fence& operator=(const Fence&) = delete;
  ~Fence() { reset(); }
  void reset() {
    if (sync_ != nullptr) glDeleteSync(sync_);
    sync_ = nullptr;
  }
  /// Blocks until every command before the fence has finished (flushing them first). Returns at
  /// once for an empty fence; false when GL reports the wait failed.
  bool wait() const {
    if (sync_ == nullptr) return true;
    GLenum r = GL_TIMEOUT_EXPIRED;
    while (r == GL_TIMEOUT_EXPIRED) r = glClientWaitSync(sync_, GL_SYNC_FLUSH_COMMANDS_BIT, 1'000'000'000);
    return r != GL_WAIT_FAILED;
  }
  [[nodiscard]] bool empty() const { return sync_ == nullptr; }

 private:
  explicit Fence(GLsync s) : sync_(s) {}
  GLsync sync_ = nullptr;
};

/// Compiles and links a vertex + fragment program; throws std::runtime_error with the GL info log
/// (configure time only).
Program make_program(const std::string& vertex_src, const std::string& fragment_src);
/// A compute program; throws std::runtime_error with the compiler's log.
Program make_compute_program(const std::string& compute_src);

}  // namespace lancet::render
