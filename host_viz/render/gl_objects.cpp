#include "render/gl_objects.hpp"

#include <stdexcept>
#include <vector>

namespace lancet::render {
namespace {

GLuint compile(GLenum kind, const std::string& src) {
  const GLuint s = glCreateShader(kind);
  const char* text = src.c_str();
  glShaderSource(s, 1, &text, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    GLint len = 0;
    glGetShaderiv(s, GL_INFO_LOG_LENGTH, &len);
    std::vector<char> log(static_cast<std::size_t>(len) + 1);
    glGetShaderInfoLog(s, len, nullptr, log.data());
    glDeleteShader(s);
    throw std::runtime_error(std::string(kind == GL_VERTEX_SHADER ? "vertex" : "fragment") +
                             " shader failed to compile: " + log.data());
  }
  return s;
}

}  // namespace

Program make_program(const std::string& vertex_src, const std::string& fragment_src) {
  const GLuint vs = compile(GL_VERTEX_SHADER, vertex_src);
  const GLuint fs = compile(GL_FRAGMENT_SHADER, fragment_src);
  const GLuint p = glCreateProgram();
  glAttachShader(p, vs);
  glAttachShader(p, fs);
  glLinkProgram(p);
  glDeleteShader(vs);
  glDeleteShader(fs);
  GLint ok = 0;
  glGetProgramiv(p, GL_LINK_STATUS, &ok);
  if (!ok) {
    GLint len = 0;
    glGetProgramiv(p, GL_INFO_LOG_LENGTH, &len);
    std::vector<char> log(static_cast<std::size_t>(len) + 1);
    glGetProgramInfoLog(p, len, nullptr, log.data());
    glDeleteProgram(p);
    throw std::runtime_error(std::string("program failed to link: ") + log.data());
  }
  return Program(p);
}

}  // namespace lancet::render
