#include "render/gl_objects.hpp"

#include <initializer_list>
#include <stdexcept>
#include <vector>

namespace lancet::render {
namespace {

// The info log of a shader or program (get_iv/get_log: glGetShaderiv/glGetShaderInfoLog or the
// program pair).
template <class GetIv, class GetLog>
std::string info_log(GLuint id, GetIv get_iv, GetLog get_log) {
  GLint len = 0;
  get_iv(id, GL_INFO_LOG_LENGTH, &len);
  std::vector<char> log(static_cast<std::size_t>(len) + 1);
  get_log(id, len, nullptr, log.data());
  return log.data();
}

GLuint compile(GLenum kind, const std::string& src) {
  const GLuint s = glCreateShader(kind);
  const char* text = src.c_str();
  glShaderSource(s, 1, &text, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    const std::string log = info_log(s, glGetShaderiv, glGetShaderInfoLog);
    glDeleteShader(s);
    const char* name = kind == GL_VERTEX_SHADER ? "vertex" : kind == GL_FRAGMENT_SHADER ? "fragment" : kind == GL_COMPUTE_SHADER ? "compute" : "other";
    throw std::runtime_error(std::string(name) + " shader failed to compile: " + log);
  }
  return s;
}

}  // namespace

namespace {

// Links the compiled shaders into a program (deleting them); throws with the linker's log.
Program link_program(std::initializer_list<GLuint> shaders) {
  const GLuint p = glCreateProgram();
  for (GLuint sh : shaders) glAttachShader(p, sh);
  glLinkProgram(p);
  for (GLuint sh : shaders) glDeleteShader(sh);
  GLint ok = 0;
  glGetProgramiv(p, GL_LINK_STATUS, &ok);
  if (!ok) {
    const std::string log = info_log(p, glGetProgramiv, glGetProgramInfoLog);
    glDeleteProgram(p);
    throw std::runtime_error("program failed to link: " + log);
  }
  return Program(p);
}

}  // namespace

Program make_program(const std::string& vertex_src, const std::string& fragment_src) {
  return link_program({compile(GL_VERTEX_SHADER, vertex_src), compile(GL_FRAGMENT_SHADER, fragment_src)});
}

Program make_compute_program(const std::string& compute_src) { return link_program({compile(GL_COMPUTE_SHADER, compute_src)}); }

}  // namespace lancet::render
