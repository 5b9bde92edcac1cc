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

/// Compiles and links a vertex + fragment program; throws std::runtime_error with the GL info log
/// (configure time only).
Program make_program(const std::string& vertex_src, const std::string& fragment_src);
/// A compute program; throws std::runtime_error with the compiler's log.
Program make_compute_program(const std::string& compute_src);

}  // namespace lancet::render
