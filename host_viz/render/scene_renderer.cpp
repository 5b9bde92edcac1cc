#include "render/scene_renderer.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/type_ptr.hpp>
#include <numbers>
#include <stdexcept>

namespace lancet::render {
namespace {

constexpr const char* kVertex = R"(#version 450 core
layout(location = 0) in vec3 a_pos;
layout(location = 1) in vec3 a_nrm;
layout(location = 2) in float a_mat;
layout(location = 3) in vec2 a_blood;  // the surface's blood: depth (m), mean age (s); (0, 0) elsewhere
uniform mat4 u_mvp;
uniform mat4 u_model;
out vec3 v_nrm;
out vec3 v_world;
out vec2 v_blood;
flat out int v_mat;
void main() {
  v_nrm = mat3(u_model) * a_nrm;
  v_world = (u_model * vec4(a_pos, 1.0)).xyz;
  v_blood = a_blood;
  v_mat = int(a_mat + 0.5);
  gl_Position = u_mvp * vec4(a_pos, 1.0);
}
)";

constexpr const char* kFragment = R"(#version 450 core
in vec3 v_nrm;
in vec3 v_world;
in vec2 v_blood;
flat in int v_mat;
uniform vec3 u_color;
uniform int u_mode;      // 0: lit by material id, 1: lit u_color, 2: flat u_color
uniform int u_face_materials;  // 1: the material of face gl_PrimitiveID from the buffer, 0: v_mat
uniform vec3 u_light;
uniform vec3 u_eye;
layout(std430, binding = 0) readonly buffer FaceMaterials { uint face_material[]; };
out vec4 o_color;
void main() {
  vec3 base = u_color;
  int mat = u_face_materials == 1 ? int(face_material[gl_PrimitiveID]) : v_mat;
  // By material (PhantomMaterial): air/skin, fat, muscle, cortical bone, marrow, vessel, vein.
  const vec3 palette[8] = vec3[8](vec3(0.93, 0.73, 0.63), vec3(0.93, 0.73, 0.63), vec3(0.95, 0.85, 0.45), vec3(0.70, 0.25, 0.22),
                                   vec3(0.92, 0.90, 0.82), vec3(0.80, 0.55, 0.40), vec3(0.72, 0.12, 0.16), vec3(0.35, 0.12, 0.30));
  if (u_mode == 0) base = palette[clamp(mat, 0, 7)];
  if (u_mode == 2) { o_color = vec4(base, 1.0); return; }
  vec3 n = normalize(v_nrm);
  vec3 l = normalize(u_light);
  if (dot(n, normalize(u_eye - v_world)) < 0.0) n = -n;  // two-sided
  float wet = 0.0;
  if (u_mode == 0 && v_blood.x > 0.0) {
    // Blood (thesis 5.5): its colour blended over the surface by depth (full from 0.2 mm; the
    // film that blood leaves where it passed stains at 30 %), the surface dimmed beneath, darker
    // as it ages; the normal tilted by the depth's slope (a bump map of the blood's height, from
    // screen-space derivatives); a wet specular highlight.
    float d = v_blood.x;
    wet = d > 1e-5 ? max(clamp(d / 0.0002, 0.0, 1.0), 0.3) : 0.0;
    vec3 fresh = vec3(0.62, 0.03, 0.04), old = vec3(0.30, 0.02, 0.03);
    vec3 blood = mix(fresh, old, clamp(v_blood.y / 120.0, 0.0, 1.0));
    base = mix(base * (1.0 - 0.5 * wet), blood, wet);
    vec3 dpdx = dFdx(v_world), dpdy = dFdy(v_world);
    vec3 r1 = cross(dpdy, n), r2 = cross(n, dpdx);
    float det = dot(dpdx, r1);
    vec3 grad = sign(det) * (dFdx(d) * r1 + dFdy(d) * r2);
    n = normalize(abs(det) * n - 15.0 * wet * grad);
  }
  float diffuse = abs(dot(n, l));
  float spec = pow(max(dot(reflect(-l, n), normalize(u_eye - v_world)), 0.0), 48.0);
  o_color = vec4(base * (0.25 + 0.75 * diffuse) + vec3(0.6 * wet * spec), 1.0);
}
)";

// The volume's image over what is drawn: a full-screen triangle, premultiplied blending.
constexpr const char* kCompositeVertex = R"(#version 450 core
out vec2 v_uv;
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  v_uv = p;
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
)";
constexpr const char* kCompositeFragment = R"(#version 450 core
in vec2 v_uv;
uniform sampler2D u_image;
out vec4 o_color;
void main() { o_color = texture(u_image, v_uv); }
)";

// Appends one vertex (position, normal, material) to an interleaved float buffer.
void push_vertex(std::vector<float>& out, glm::vec3 p, glm::vec3 n, float mat) {
  out.insert(out.end(), {p.x, p.y, p.z, n.x, n.y, n.z, mat});
}

std::vector<float> unit_sphere(int slices, int stacks) {
  std::vector<float> v;
  const auto point = [](float th, float ph) {
    return glm::vec3(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
  };
  const float pi = std::numbers::pi_v<float>;
  for (int i = 0; i < stacks; ++i) {
    const float t0 = pi * static_cast<float>(i) / static_cast<float>(stacks);
    const float t1 = pi * static_cast<float>(i + 1) / static_cast<float>(stacks);
    for (int j = 0; j < slices; ++j) {
      const float p0 = 2 * pi * static_cast<float>(j) / static_cast<float>(slices);
      const float p1 = 2 * pi * static_cast<float>(j + 1) / static_cast<float>(slices);
      const glm::vec3 a = point(t0, p0), b = point(t1, p0), c = point(t1, p1), d = point(t0, p1);
      for (glm::vec3 q : {a, b, c, a, c, d}) push_vertex(v, q, q, 0);
    }
  }
  return v;
}

// Unit cylinder of radius 1 from z = 0 to z = 1.
std::vector<float> unit_cylinder(int slices) {
  std::vector<float> v;
  const float pi = std::numbers::pi_v<float>;
  for (int j = 0; j < slices; ++j) {
    const float p0 = 2 * pi * static_cast<float>(j) / static_cast<float>(slices);
    const float p1 = 2 * pi * static_cast<float>(j + 1) / static_cast<float>(slices);
    const glm::vec3 n0(std::cos(p0), std::sin(p0), 0), n1(std::cos(p1), std::sin(p1), 0);
    const glm::vec3 a = n0, b = n1, c = n1 + glm::vec3(0, 0, 1), d = n0 + glm::vec3(0, 0, 1);
    push_vertex(v, a, n0, 0), push_vertex(v, b, n1, 0), push_vertex(v, c, n1, 0);
    push_vertex(v, a, n0, 0), push_vertex(v, c, n1, 0), push_vertex(v, d, n0, 0);
  }
  return v;
}

glm::vec3 gv(Vec3 v) { return {static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)}; }
glm::vec3 gv(Vec3f v) { return {v.x, v.y, v.z}; }

}  // namespace

SceneRenderer::SceneRenderer(int width, int height) : width_(0), height_(0) {
  program_ = make_program(kVertex, kFragment);
  composite_ = make_program(kCompositeVertex, kCompositeFragment);
  GLuint vao = 0;
  glCreateVertexArrays(1, &vao);
  empty_vao_ = VertexArray(vao);
  sphere_ = upload(unit_sphere(24, 16));
  cylinder_ = upload(unit_cylinder(20));
  lines_ = upload({});  // a streamed buffer, refilled every frame
  resize(width, height);
}

SceneRenderer::GpuMesh SceneRenderer::upload(const std::vector<float>& data) {
  GpuMesh m;
  GLuint vao = 0, vbo = 0;
  glCreateVertexArrays(1, &vao);
  glCreateBuffers(1, &vbo);
  m.vao = VertexArray(vao);
  m.vbo = Buffer(vbo);
  glNamedBufferData(vbo, static_cast<GLsizeiptr>(data.size() * sizeof(float)), data.data(), GL_STATIC_DRAW);
  glBindVertexArray(vao);
  glBindBuffer(GL_ARRAY_BUFFER, vbo);
  constexpr GLsizei stride = 7 * sizeof(float);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, stride, nullptr);
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, stride, reinterpret_cast<const void*>(3 * sizeof(float)));
  glEnableVertexAttribArray(2);
  glVertexAttribPointer(2, 1, GL_FLOAT, GL_FALSE, stride, reinterpret_cast<const void*>(6 * sizeof(float)));
  glBindVertexArray(0);
  m.count = static_cast<GLsizei>(data.size() / 7);
  return m;
}

namespace {

// Sends what differs between `now` and `before` (the buffer's contents) in blocks of 16 kB, or
// the whole when the size changed; returns the bytes sent. `before` becomes `now`.
template <class T>
std::size_t sync_buffer(Buffer& buffer, std::vector<T>& before, const std::vector<T>& now) {
  const GLuint id = buffer.get();
  if (now.size() != before.size()) {
    glNamedBufferData(id, static_cast<GLsizeiptr>(std::max<std::size_t>(now.size(), 1) * sizeof(T)), now.data(), GL_DYNAMIC_DRAW);
    before = now;
    return now.size() * sizeof(T);
  }
  constexpr std::size_t kBlock = 16384 / sizeof(T);
  std::size_t sent = 0;
  for (std::size_t at = 0; at < now.size();) {
    // A run of consecutive changed blocks goes in one call.
    std::size_t end = at;
    while (end < now.size()) {
      const std::size_t n = std::min(kBlock, now.size() - end);
      if (std::equal(now.begin() + static_cast<std::ptrdiff_t>(end), now.begin() + static_cast<std::ptrdiff_t>(end + n),
                     before.begin() + static_cast<std::ptrdiff_t>(end)))
        break;
      end += n;
    }
    if (end > at) {
      std::copy(now.begin() + static_cast<std::ptrdiff_t>(at), now.begin() + static_cast<std::ptrdiff_t>(end),
                before.begin() + static_cast<std::ptrdiff_t>(at));
      glNamedBufferSubData(id, static_cast<GLintptr>(at * sizeof(T)), static_cast<GLsizeiptr>((end - at) * sizeof(T)),
                           now.data() + at);
      sent += (end - at) * sizeof(T);
      at = end;
    } else {
      at += std::min(kBlock, now.size() - at);
    }
  }
  return sent;
}

}  // namespace

void SceneRenderer::set_mesh(const surface::TriangleMesh& mesh) {
  SurfaceBuffers& g = surface_;
  if (g.vao.get() == 0) {
    GLuint vao = 0, bufs[4] = {0, 0, 0, 0};
    glCreateVertexArrays(1, &vao);
    glCreateBuffers(4, bufs);
    g.vao = VertexArray(vao);
    g.vertices = Buffer(bufs[0]);
    g.indices = Buffer(bufs[1]);
    g.materials = Buffer(bufs[2]);
    g.blood = Buffer(bufs[3]);
    glVertexArrayVertexBuffer(vao, 1, bufs[3], 0, 2 * sizeof(float));
    glEnableVertexArrayAttrib(vao, 3);
    glVertexArrayAttribFormat(vao, 3, 2, GL_FLOAT, GL_FALSE, 0);
    glVertexArrayAttribBinding(vao, 3, 1);
    glVertexArrayVertexBuffer(vao, 0, bufs[0], 0, 6 * sizeof(float));
    glVertexArrayElementBuffer(vao, bufs[1]);
    glEnableVertexArrayAttrib(vao, 0);
    glVertexArrayAttribFormat(vao, 0, 3, GL_FLOAT, GL_FALSE, 0);
    glVertexArrayAttribBinding(vao, 0, 0);
    glEnableVertexArrayAttrib(vao, 1);
    glVertexArrayAttribFormat(vao, 1, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float));
    glVertexArrayAttribBinding(vao, 1, 0);
  }
  std::vector<float> v(mesh.vertices.size() * 6);
  for (std::size_t k = 0; k < mesh.vertices.size(); ++k) {
    const Vec3f p = mesh.vertices[k], n = k < mesh.normals.size() ? mesh.normals[k] : Vec3f{0, 0, 1};
    float* o = v.data() + 6 * k;
    o[0] = p.x, o[1] = p.y, o[2] = p.z, o[3] = n.x, o[4] = n.y, o[5] = n.z;
  }
  std::vector<std::uint32_t> idx(mesh.triangles.size() * 3), mat(mesh.triangles.size());
  for (std::size_t f = 0; f < mesh.triangles.size(); ++f) {
    for (std::size_t c = 0; c < 3; ++c) idx[3 * f + c] = mesh.triangles[f][c];
    mat[f] = f < mesh.material.size() ? mesh.material[f] : 1u;
  }
  last_upload_bytes_ = sync_buffer(g.vertices, g.v, v) + sync_buffer(g.indices, g.i, idx) + sync_buffer(g.materials, g.m, mat);
  // Dry until set_blood says otherwise (the blood buffer must cover every vertex).
  if (g.b.size() != 2 * mesh.vertices.size()) last_upload_bytes_ += sync_buffer(g.blood, g.b, std::vector<float>(2 * mesh.vertices.size(), 0.0f));
}

void SceneRenderer::set_blood(std::span<const float> depth, std::span<const float> age) {
  SurfaceBuffers& g = surface_;
  const std::size_t n = g.v.size() / 6;
  std::vector<float> b(2 * n, 0.0f);
  if (depth.size() == n && age.size() == n)
    for (std::size_t k = 0; k < n; ++k) b[2 * k] = depth[k], b[2 * k + 1] = age[k];
  last_upload_bytes_ += sync_buffer(g.blood, g.b, b);
}

std::size_t SceneRenderer::mesh_bytes() const noexcept {
  return (surface_.v.size() + surface_.b.size()) * sizeof(float) + (surface_.i.size() + surface_.m.size()) * sizeof(std::uint32_t);
}

void SceneRenderer::resize(int width, int height) {
  if (width == width_ && height == height_) return;
  width_ = width;
  height_ = height;
  GLuint fbo = 0, rb = 0, depth = 0;
  glCreateFramebuffers(1, &fbo);
  glCreateRenderbuffers(1, &rb);
  glCreateTextures(GL_TEXTURE_2D, 1, &depth);
  fbo_ = Framebuffer(fbo);
  color_ = Renderbuffer(rb);
  depth_ = Texture(depth);
  glNamedRenderbufferStorage(rb, GL_RGBA8, width, height);
  glTextureStorage2D(depth, 1, GL_DEPTH_COMPONENT32F, width, height);
  glTextureParameteri(depth, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTextureParameteri(depth, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  glNamedFramebufferRenderbuffer(fbo, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, rb);
  glNamedFramebufferTexture(fbo, GL_DEPTH_ATTACHMENT, depth, 0);
  if (glCheckNamedFramebufferStatus(fbo, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
    throw std::runtime_error("offscreen framebuffer " + std::to_string(width) + "x" + std::to_string(height) +
                             " is incomplete");
  }
}

void SceneRenderer::draw(const GpuMesh& m, GLenum primitive, GLint first, GLsizei count, const glm::mat4& model,
                         glm::vec3 color, int mode) const {
  if (count <= 0) return;
  const glm::mat4 mvp = proj_ * view_ * model;
  const GLuint p = program_.get();
  glUniformMatrix4fv(glGetUniformLocation(p, "u_mvp"), 1, GL_FALSE, glm::value_ptr(mvp));
  glUniformMatrix4fv(glGetUniformLocation(p, "u_model"), 1, GL_FALSE, glm::value_ptr(model));
  glUniform3fv(glGetUniformLocation(p, "u_color"), 1, glm::value_ptr(color));
  glUniform1i(glGetUniformLocation(p, "u_mode"), mode);
  glBindVertexArray(m.vao.get());
  glDrawArrays(primitive, first, count);
}

void SceneRenderer::render(const SceneInput& in) {
  const glm::vec3 target = gv(in.camera_target);
  const glm::vec3 eye = target + in.camera_distance * glm::vec3(std::cos(in.camera_pitch) * std::sin(in.camera_yaw),
                                                                -std::cos(in.camera_pitch) * std::cos(in.camera_yaw),
                                                                std::sin(in.camera_pitch));
  view_ = glm::lookAt(eye, target, glm::vec3(0, 0, 1));
  proj_ = glm::perspective(glm::radians(40.0f), static_cast<float>(width_) / static_cast<float>(height_), 0.005f, 3.0f);

  glBindFramebuffer(GL_FRAMEBUFFER, fbo_.get());
  glViewport(0, 0, width_, height_);
  glClearColor(0.11f, 0.13f, 0.16f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glUseProgram(program_.get());
  glUniform3f(glGetUniformLocation(program_.get(), "u_light"), eye.x, eye.y, eye.z + 0.2f);
  glUniform3f(glGetUniformLocation(program_.get(), "u_eye"), eye.x, eye.y, eye.z);

  if (!surface_.i.empty() && in.draw_surface) {
    const GLuint p = program_.get();
    const glm::mat4 mvp = proj_ * view_;
    glUniformMatrix4fv(glGetUniformLocation(p, "u_mvp"), 1, GL_FALSE, glm::value_ptr(mvp));
    glUniformMatrix4fv(glGetUniformLocation(p, "u_model"), 1, GL_FALSE, glm::value_ptr(glm::mat4(1.0f)));
    glUniform1i(glGetUniformLocation(p, "u_mode"), 0);
    glUniform1i(glGetUniformLocation(p, "u_face_materials"), 1);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, surface_.materials.get());
    glBindVertexArray(surface_.vao.get());
    glDrawElements(GL_TRIANGLES, static_cast<GLsizei>(surface_.i.size()), GL_UNSIGNED_INT, nullptr);
    glUniform1i(glGetUniformLocation(p, "u_face_materials"), 0);
  }

  // The volume, where no opaque mesh is in front: its rays stop at the meshes' depth.
  if (in.volume != nullptr) {
    glm::mat4 model;
    std::memcpy(glm::value_ptr(model), in.volume_to_world.data(), sizeof(float) * 16);
    const glm::mat4 inv = glm::inverse(proj_ * view_ * model);
    volume::RayCamera cam;
    std::memcpy(cam.inv_view_proj.data(), glm::value_ptr(inv), sizeof(float) * 16);
    cam.width = width_;
    cam.height = height_;
    glBindFramebuffer(GL_FRAMEBUFFER, 0);  // the depth is read, not attached, while the rays run
    in.volume->render(cam, in.volume_params, in.draw_surface ? depth_.get() : 0);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo_.get());
    glViewport(0, 0, width_, height_);
    glDisable(GL_DEPTH_TEST);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    glUseProgram(composite_.get());
    glBindTextureUnit(0, in.volume->texture());
    glUniform1i(glGetUniformLocation(composite_.get(), "u_image"), 0);
    glBindVertexArray(empty_vao_.get());
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glDisable(GL_BLEND);
    glEnable(GL_DEPTH_TEST);
    glUseProgram(program_.get());
  }

  // Lines: the patch wireframe (lifted 0.2 mm so it is not hidden by the surface) and the force.
  std::vector<float> lines;
  for (const TissuePatch* patch : in.patches) {
    if (patch == nullptr) continue;
    const glm::vec3 lift(0, 0, 0.0002f);
    const std::uint32_t n = std::min(patch->n_triangles, kPatchCapacity);
    for (std::uint32_t i = 0; i < n; ++i) {
      const auto& t = patch->triangles[i];
      for (int e = 0; e < 3; ++e) {
        push_vertex(lines, gv(t.v[e]) + lift, glm::vec3(0), 0);
        push_vertex(lines, gv(t.v[(e + 1) % 3]) + lift, glm::vec3(0), 0);
      }
    }
  }
  const std::size_t patch_floats = lines.size();
  for (const ToolView& tv : in.tools) {
    if (!tv.has_tool || norm(tv.force) <= 1e-6) continue;
    push_vertex(lines, gv(tv.tool), glm::vec3(0), 0);
    push_vertex(lines, gv(tv.tool + 0.01 * tv.force), glm::vec3(0), 0);  // 1 cm per newton
  }
  const std::size_t force_floats = lines.size() - patch_floats;
  if (in.guide != nullptr)  // the task's line, as segments, lifted like the wireframe
    for (std::size_t i = 1; i < in.guide->size(); ++i) {
      push_vertex(lines, gv((*in.guide)[i - 1]) + glm::vec3(0, 0, 0.0003f), glm::vec3(0), 0);
      push_vertex(lines, gv((*in.guide)[i]) + glm::vec3(0, 0, 0.0003f), glm::vec3(0), 0);
    }
  if (!lines.empty()) {
    glNamedBufferData(lines_.vbo.get(), static_cast<GLsizeiptr>(lines.size() * sizeof(float)), lines.data(),
                      GL_STREAM_DRAW);
    const auto patch_vertices = static_cast<GLsizei>(patch_floats / 7);
    const auto force_vertices = static_cast<GLsizei>(force_floats / 7);
    const auto guide_vertices = static_cast<GLsizei>((lines.size() - patch_floats - force_floats) / 7);
    draw(lines_, GL_LINES, 0, patch_vertices, glm::mat4(1.0f), glm::vec3(0.2f, 0.85f, 0.95f), 2);
    draw(lines_, GL_LINES, patch_vertices, force_vertices, glm::mat4(1.0f), glm::vec3(1.0f, 0.85f, 0.1f), 2);
    draw(lines_, GL_LINES, patch_vertices + force_vertices, guide_vertices, glm::mat4(1.0f), glm::vec3(0.2f, 0.35f, 0.95f), 2);
  }

  for (std::size_t h = 0; h < kHandCount; ++h) {
    const ToolView& tv = in.tools[h];
    if (!tv.has_tool) continue;
    const glm::vec3 tip = gv(tv.tool);
    const glm::vec3 colour(kHandColours[h][0], kHandColours[h][1], kHandColours[h][2]);
    draw(sphere_, GL_TRIANGLES, 0, sphere_.count, glm::scale(glm::translate(glm::mat4(1), tip), glm::vec3(0.0015f)),
         glm::vec3(0.75f, 0.78f, 0.82f), 1);
    draw(cylinder_, GL_TRIANGLES, 0, cylinder_.count, glm::scale(glm::translate(glm::mat4(1), tip), glm::vec3(0.0009f, 0.0009f, 0.07f)),
         colour, 1);
    if (norm(tv.proxy - tv.tool) > 1e-5) {
      draw(sphere_, GL_TRIANGLES, 0, sphere_.count, glm::scale(glm::translate(glm::mat4(1), gv(tv.proxy)), glm::vec3(0.001f)),
           glm::vec3(0.2f, 0.9f, 0.3f), 1);
    }
  }
  glBindVertexArray(0);
  glUseProgram(0);
}

void SceneRenderer::present(int window_width, int window_height) const {
  glBlitNamedFramebuffer(fbo_.get(), 0, 0, 0, width_, height_, 0, 0, window_width, window_height, GL_COLOR_BUFFER_BIT,
                         GL_LINEAR);
}

Image SceneRenderer::read_back() const {
  Image img;
  img.width = width_;
  img.height = height_;
  img.rgba.resize(static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_) * 4);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo_.get());
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, width_, height_, GL_RGBA, GL_UNSIGNED_BYTE, img.rgba.data());
  // GL's first row is the bottom one: flip so the image reads top-down.
  const std::size_t row = static_cast<std::size_t>(width_) * 4;
  for (int y = 0; y < height_ / 2; ++y) {
    std::swap_ranges(img.rgba.begin() + static_cast<std::ptrdiff_t>(y * row),
                     img.rgba.begin() + static_cast<std::ptrdiff_t>((y + 1) * row),
                     img.rgba.begin() + static_cast<std::ptrdiff_t>((height_ - 1 - y) * row));
  }
  return img;
}

bool SceneRenderer::pick_plane(double x, double y, int ww, int wh, Vec3& out) const {
  if (ww <= 0 || wh <= 0) return false;
  const glm::vec4 viewport(0, 0, static_cast<float>(ww), static_cast<float>(wh));
  const glm::vec3 win_near(static_cast<float>(x), static_cast<float>(wh - y), 0.0f);
  const glm::vec3 win_far(static_cast<float>(x), static_cast<float>(wh - y), 1.0f);
  const glm::vec3 a = glm::unProject(win_near, view_, proj_, viewport);
  const glm::vec3 b = glm::unProject(win_far, view_, proj_, viewport);
  if (std::abs(b.z - a.z) < 1e-9f) return false;
  const float s = -a.z / (b.z - a.z);
  if (s < 0) return false;
  const glm::vec3 p = a + s * (b - a);
  out = Vec3{p.x, p.y, 0.0};
  return true;
}

}  // namespace lancet::render
