#include "render/volume_raycaster.hpp"

#include <algorithm>
#include <string>
#include <vector>

namespace lancet::render {
namespace {

// The reference's operations, in its order (volume/raycast.cpp). MIP, SHADE and SKIP are defined
// before this text: one program per combination, so that no invocation carries the code of the
// modes it does not run (a uniform branch costs the masked-out code too on a SIMD CPU such as
// llvmpipe).
constexpr const char* kCompute = R"(
layout(local_size_x = 8, local_size_y = 8) in;
layout(rgba32f, binding = 0) uniform writeonly image2D u_out;
uniform sampler2D u_depth;  // the opaque meshes' depth (same camera), when u_use_depth == 1
uniform sampler3D u_volume;  // R32F, trilinear: the texture unit's interpolation
layout(std430, binding = 2) readonly buffer Table { vec4 table[256]; };
layout(std430, binding = 3) readonly buffer Empty { uint empty_brick[]; };
uniform sampler3D u_brick_range;  // RG32F, one texel per brick: the smallest and largest value any sample in it interpolates from
uniform ivec3 u_dims;
uniform ivec3 u_bricks;
uniform vec3 u_origin;
uniform vec3 u_spacing;
uniform mat4 u_inv_vp;
uniform ivec2 u_size;
uniform float u_lo, u_hi, u_step, u_ref, u_early, u_mip_stop;
uniform int u_jitter, u_use_depth, u_clip;
uniform vec4 u_plane;

float mixf(float a, float b, float t) { return a + (b - a) * t; }
// The position in voxel indices, clamped to the voxel centres as the reference clamps it; texel
// centres lie at (index + 0.5) / dims.
float sample_at(vec3 p) {
  vec3 hi = vec3(u_dims - ivec3(1));
  return texture(u_volume, (clamp(p, vec3(0.0), hi) + 0.5) / vec3(u_dims)).r;
}
vec4 lookup(float v) {
  float x = clamp((v - u_lo) / (u_hi - u_lo) * 255.0, 0.0, 255.0);
  int i = min(int(x), 254);
  float f = x - float(i);
  vec4 a = table[i], b = table[i + 1];
  return vec4(mixf(a.x, b.x, f), mixf(a.y, b.y, f), mixf(a.z, b.z, f), mixf(a.w, b.w, f));
}
float jitter(int x, int y) {
  uint h = uint(x) * 1973u + uint(y) * 9277u + 26699u;
  h = (h ^ 61u) ^ (h >> 16);
  h *= 9u;
  h ^= h >> 4;
  h *= 0x27d4eb2du;
  h ^= h >> 15;
  return float(h >> 8) * (1.0 / 16777216.0);
}
#if MIP && SKIP
// A walk through the 8-voxel bricks that the ray q0 + t·qd crosses, face to face (a 3-D DDA).
struct BrickWalk {
  ivec3 b, dir;     // the brick, and the way the ray steps on each axis
  vec3 next, delta;  // the t of the next face on each axis, and the t between faces
};
BrickWalk walk_from(vec3 q0, vec3 qd, float t) {
  BrickWalk w;
  w.b = clamp(ivec3(clamp(q0 + t * qd, vec3(0.0), vec3(u_dims - ivec3(1))) * 0.125), ivec3(0), u_bricks - ivec3(1));
  w.dir = ivec3(sign(qd));
  w.next = vec3(3.402823466e+38);
  w.delta = vec3(0.0);
  for (int ax = 0; ax < 3; ++ax) {
    if (qd[ax] == 0.0) continue;
    w.next[ax] = (float((w.b[ax] + (qd[ax] > 0.0 ? 1 : 0)) * 8) - q0[ax]) / qd[ax];
    w.delta[ax] = 8.0 / abs(qd[ax]);
  }
  return w;
}
float walk_exit(BrickWalk w) { return min(min(w.next.x, w.next.y), w.next.z); }
// Into the brick across the nearest face; false once that is outside the grid.
bool walk_step(inout BrickWalk w) {
  int ax = w.next.x <= w.next.y && w.next.x <= w.next.z ? 0 : w.next.y <= w.next.z ? 1 : 2;
  w.b[ax] += w.dir[ax];
  w.next[ax] += w.delta[ax];
  return w.b[ax] >= 0 && w.b[ax] < u_bricks[ax];
}
// The stretch [x, y] of the ray outside which no sample can raise its maximum (empty, x > y, when
// it has none). First walk: the largest minimum of a brick that surely holds a sample (its stretch
// is longer than two steps): the ray's maximum reaches it, so a brick whose maximum is below it
// cannot matter; and the exit of the last brick whose maximum reaches that bound as known so far
// (it only grows: no later than needed). Second walk, to the first brick that reaches the bound.
vec2 mip_stretch(vec3 q0, vec3 qd, float t_in, float t_out, float ds) {
  float surely = -3.402823466e+38, last = -3.402823466e+38;
  BrickWalk w = walk_from(q0, qd, t_in);
  for (float t0 = t_in; t0 <= t_out;) {
    float t1 = min(walk_exit(w), t_out);
    vec2 range = texelFetch(u_brick_range, w.b, 0).rg;  // (min, max)
    if (t1 - t0 > 2.0 * ds) surely = max(surely, range.x);
    if (range.y >= surely) last = t1;
    if (t1 >= t_out || !walk_step(w)) break;
    t0 = t1;
  }
  w = walk_from(q0, qd, t_in);
  for (float t0 = t_in; t0 <= last;) {
    if (texelFetch(u_brick_range, w.b, 0).g >= surely) return vec2(t0, last);
    float t1 = walk_exit(w);
    if (!walk_step(w)) break;
    t0 = t1;
  }
  return vec2(1.0, 0.0);
}
#endif
void main() {
  ivec2 px = ivec2(gl_GlobalInvocationID.xy);
  if (px.x >= u_size.x || px.y >= u_size.y) return;
  float nx = 2.0 * (float(px.x) + 0.5) / float(u_size.x) - 1.0;
  float ny = 2.0 * (float(px.y) + 0.5) / float(u_size.y) - 1.0;
  vec4 a = u_inv_vp * vec4(nx, ny, -1.0, 1.0), b = u_inv_vp * vec4(nx, ny, 1.0, 1.0);
  vec3 pn = vec3(a.x / a.w, a.y / a.w, a.z / a.w), pf = vec3(b.x / b.w, b.y / b.w, b.z / b.w);
  vec3 dir = pf - pn;
  float len = sqrt(dir.x * dir.x + dir.y * dir.y + dir.z * dir.z);
  dir = (1.0 / len) * dir;
  vec3 q0 = vec3((pn.x - u_origin.x) / u_spacing.x, (pn.y - u_origin.y) / u_spacing.y, (pn.z - u_origin.z) / u_spacing.z);
  vec3 qd = vec3(dir.x / u_spacing.x, dir.y / u_spacing.y, dir.z / u_spacing.z);
  float t_in = 0.0, t_out = len;
  for (int ax = 0; ax < 3; ++ax) {
    float o = q0[ax], d = qd[ax], hi = float(u_dims[ax] - 1);
    if (d == 0.0) {
      if (o < 0.0 || o > hi) t_out = -1.0;
      continue;
    }
    float t0 = (0.0 - o) / d, t1 = (hi - o) / d;
    t_in = max(t_in, min(t0, t1));
    t_out = min(t_out, max(t0, t1));
  }
  if (u_use_depth == 1) {  // stop at the opaque surface: its depth back to a point on this ray
    float d = texelFetch(u_depth, px, 0).x;
    if (d < 1.0) {
      vec4 s = u_inv_vp * vec4(nx, ny, 2.0 * d - 1.0, 1.0);
      t_out = min(t_out, length(vec3(s.x / s.w, s.y / s.w, s.z / s.w) - pn));
    }
  }
  if (u_clip == 1) {
    float f0 = u_plane.x * pn.x + u_plane.y * pn.y + u_plane.z * pn.z + u_plane.w, fd = u_plane.x * dir.x + u_plane.y * dir.y + u_plane.z * dir.z;
    if (fd > 0.0) t_out = min(t_out, -f0 / fd);
    else if (fd < 0.0) t_in = max(t_in, -f0 / fd);
    else if (f0 > 0.0) t_out = -1.0;
  }
  float ds = u_step * u_ref;
  float j = u_jitter == 1 ? jitter(px.x, px.y) : 0.0;
  float cr = 0.0, cg = 0.0, cb = 0.0, ca = 0.0, vmax = -3.402823466e+38;
  bool any = false;
  int k_first = 0, k_end = 2147483647;
#if MIP && SKIP
  // MIP skips without a test per step (on a SIMD CPU each lane would pay it on every step, and
  // the lanes of one group would drift apart): walks through the bricks bound the stretch of the
  // ray that can hold its maximum, and only that stretch is sampled. One more sample at each end
  // covers rounding between the walk and the lattice.
  {
    vec2 span = mip_stretch(q0, qd, t_in, t_out, ds);
    if (span.x <= span.y) {
      k_first = max(int(floor((span.x - t_in) / ds - j)) - 1, 0);
      k_end = int(ceil((span.y - t_in) / ds - j)) + 1;
    } else {
      k_end = 0;
    }
  }
#endif
  for (int k = k_first; k < k_end;) {
    float t = t_in + (float(k) + j) * ds;
    if (!(t <= t_out)) break;
    vec3 p = q0 + t * qd;
#if SKIP && !MIP
    {
      int bx = clamp(int(floor(p.x / 8.0)), 0, u_bricks.x - 1);
      int by = clamp(int(floor(p.y / 8.0)), 0, u_bricks.y - 1);
      int bz = clamp(int(floor(p.z / 8.0)), 0, u_bricks.z - 1);
      int b = bx + u_bricks.x * (by + u_bricks.y * bz);
      if (empty_brick[b] != 0u) {
        float t_exit = 3.402823466e+38;
        ivec3 bi = ivec3(bx, by, bz);
        for (int ax = 0; ax < 3; ++ax) {
          float d = qd[ax], o = q0[ax];
          if (d > 0.0) t_exit = min(t_exit, (float((bi[ax] + 1) * 8) - o) / d);
          else if (d < 0.0) t_exit = min(t_exit, (float(bi[ax] * 8) - o) / d);
        }
        int next = int(ceil((t_exit - t_in) / ds - j));
        k = max(next, k + 1);
        continue;
      }
    }
#endif
    float value = sample_at(p);
    any = true;
#if MIP
    vmax = max(vmax, value);
    if (vmax >= u_mip_stop) break;
    ++k;
#else
    vec4 c = lookup(value);
    if (c.w > 0.0) {
      float alpha = 1.0 - pow(1.0 - c.w, u_step);
      float light = 1.0;
#if SHADE
      {
        float gx = (sample_at(p + vec3(1, 0, 0)) - sample_at(p - vec3(1, 0, 0))) * 0.5 / u_spacing.x;
        float gy = (sample_at(p + vec3(0, 1, 0)) - sample_at(p - vec3(0, 1, 0))) * 0.5 / u_spacing.y;
        float gz = (sample_at(p + vec3(0, 0, 1)) - sample_at(p - vec3(0, 0, 1))) * 0.5 / u_spacing.z;
        float gl = sqrt(gx * gx + gy * gy + gz * gz);
        if (gl > 1e-3) light = 0.3 + 0.7 * abs((gx * dir.x + gy * dir.y + gz * dir.z) / gl);
      }
#endif
      float w = (1.0 - ca) * alpha;
      cr += w * c.x * light;
      cg += w * c.y * light;
      cb += w * c.z * light;
      ca += w;
      if (ca >= u_early) break;
    }
    ++k;
#endif
  }
#if MIP
  if (any) {
    vec4 c = lookup(vmax);
    cr = c.x * c.w; cg = c.y * c.w; cb = c.z * c.w; ca = c.w;
  }
#endif
  imageStore(u_out, px, vec4(cr, cg, cb, ca));
}
)";

GLuint new_buffer() {
  GLuint b = 0;
  glCreateBuffers(1, &b);
  return b;
}

// A 3-D texture of one level (dims: texels on each axis, at least 1), clamped at its edges, with
// the given filter (GL_LINEAR: the texture unit interpolates; GL_NEAREST: texelFetch only).
Texture new_texture_3d(GLenum format, std::array<int, 3> dims, GLint filter) {
  GLuint t = 0;
  glCreateTextures(GL_TEXTURE_3D, 1, &t);
  Texture texture(t);
  glTextureStorage3D(t, 1, format, std::max(dims[0], 1), std::max(dims[1], 1), std::max(dims[2], 1));
  glTextureParameteri(t, GL_TEXTURE_MIN_FILTER, filter);
  glTextureParameteri(t, GL_TEXTURE_MAG_FILTER, filter);
  for (GLenum wrap : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTextureParameteri(t, wrap, GL_CLAMP_TO_EDGE);
  return texture;
}

}  // namespace

VolumeRaycaster::VolumeRaycaster() {
  for (int v = 0; v < 8; ++v) {
    const std::string defines = "#version 450 core\n#define MIP " + std::to_string(v & 1) + "\n#define SHADE " +
                                std::to_string((v >> 1) & 1) + "\n#define SKIP " + std::to_string((v >> 2) & 1) + "\n";
    programs_[static_cast<std::size_t>(v)] = make_compute_program(defines + kCompute);
  }
  mask_ = Buffer(new_buffer());
  table_ = Buffer(new_buffer());
  set_transfer_function(volume::tf_preset(volume::TfPreset::kCtSoftTissue));
}

void VolumeRaycaster::set_volume(const volume::Volume& v) {
  dims_ = v.dims;
  origin_ = v.origin;
  spacing_ = v.spacing;
  reference_ = volume::reference_step(v);
  voxels_ = new_texture_3d(GL_R32F, dims_, GL_LINEAR);
  const GLuint t = voxels_.get();
  if (!v.data.empty()) {
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glTextureSubImage3D(t, 0, 0, 0, 0, dims_[0], dims_[1], dims_[2], GL_RED, GL_FLOAT, v.data.data());
  }
  grid_ = volume::BrickGrid(v);
  upload_mask();
  upload_brick_range();
}

void VolumeRaycaster::update_region(const volume::Volume& v, volume::VoxelBox box) {
  if (box.empty() || v.dims != dims_) return;
  // Whole z-slabs of the box: one contiguous range of the voxels.
  const int k0 = std::clamp(box.lo[2], 0, dims_[2]), k1 = std::clamp(box.hi[2], 0, dims_[2]);
  if (k1 <= k0) return;
  const std::size_t slab = static_cast<std::size_t>(dims_[0]) * static_cast<std::size_t>(dims_[1]);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
  glTextureSubImage3D(voxels_.get(), 0, 0, 0, k0, dims_[0], dims_[1], k1 - k0, GL_RED, GL_FLOAT,
                      v.data.data() + slab * static_cast<std::size_t>(k0));
  grid_.update(v, box);
  upload_mask();
  upload_brick_range();
}

void VolumeRaycaster::set_transfer_function(const volume::TransferFunction& tf) {
  tf_ = tf;
  glNamedBufferData(table_.get(), static_cast<GLsizeiptr>(sizeof(tf.table)), tf.table.data(), GL_DYNAMIC_DRAW);
  upload_mask();
}

void VolumeRaycaster::upload_mask() {
  const std::vector<std::uint8_t> m = grid_.empty_mask(tf_);
  std::vector<std::uint32_t> u(m.begin(), m.end());
  if (u.empty()) u.push_back(0);
  glNamedBufferData(mask_.get(), static_cast<GLsizeiptr>(u.size() * sizeof(std::uint32_t)), u.data(), GL_DYNAMIC_DRAW);
}

void VolumeRaycaster::upload_brick_range() {
  const auto bricks = grid_.dims();
  if (bricks != brick_range_dims_) {
    brick_range_ = new_texture_3d(GL_RG32F, bricks, GL_NEAREST);
    brick_range_dims_ = bricks;
  }
  const auto lo = grid_.min(), hi = grid_.max();
  if (lo.empty()) return;
  std::vector<float> range(2 * lo.size());
  for (std::size_t b = 0; b < lo.size(); ++b) {
    range[2 * b] = lo[b];
    range[2 * b + 1] = hi[b];
  }
  glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
  glTextureSubImage3D(brick_range_.get(), 0, 0, 0, 0, bricks[0], bricks[1], bricks[2], GL_RG, GL_FLOAT, range.data());
}

void VolumeRaycaster::render(const volume::RayCamera& cam, const volume::RaycastParams& params, GLuint depth_texture) {
  if (cam.width != image_w_ || cam.height != image_h_) {
    GLuint t = 0;
    glCreateTextures(GL_TEXTURE_2D, 1, &t);
    glTextureStorage2D(t, 1, GL_RGBA32F, cam.width, cam.height);
    glTextureParameteri(t, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTextureParameteri(t, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    image_ = Texture(t);
    image_w_ = cam.width;
    image_h_ = cam.height;
  }
  const bool shade = params.shade && !tf_.mip;
  const GLuint p = programs_[(tf_.mip ? 1u : 0u) | (shade ? 2u : 0u) | (params.skip_empty ? 4u : 0u)].get();
  glUseProgram(p);
  const auto bricks = grid_.dims();
  glUniform3i(glGetUniformLocation(p, "u_dims"), dims_[0], dims_[1], dims_[2]);
  glUniform3i(glGetUniformLocation(p, "u_bricks"), bricks[0], bricks[1], bricks[2]);
  glUniform3f(glGetUniformLocation(p, "u_origin"), static_cast<float>(origin_.x), static_cast<float>(origin_.y), static_cast<float>(origin_.z));
  glUniform3f(glGetUniformLocation(p, "u_spacing"), static_cast<float>(spacing_.x), static_cast<float>(spacing_.y),
              static_cast<float>(spacing_.z));
  glUniformMatrix4fv(glGetUniformLocation(p, "u_inv_vp"), 1, GL_FALSE, cam.inv_view_proj.data());
  glUniform2i(glGetUniformLocation(p, "u_size"), cam.width, cam.height);
  glUniform1f(glGetUniformLocation(p, "u_lo"), tf_.lo);
  glUniform1f(glGetUniformLocation(p, "u_hi"), tf_.hi);
  glUniform1f(glGetUniformLocation(p, "u_step"), params.step);
  glUniform1f(glGetUniformLocation(p, "u_ref"), reference_);
  glUniform1f(glGetUniformLocation(p, "u_early"), params.early_stop);
  glUniform1f(glGetUniformLocation(p, "u_mip_stop"), tf_.constant_from());
  glUniform1i(glGetUniformLocation(p, "u_jitter"), params.jitter ? 1 : 0);
  glUniform1i(glGetUniformLocation(p, "u_use_depth"), depth_texture != 0 ? 1 : 0);
  glUniform1i(glGetUniformLocation(p, "u_clip"), params.clip ? 1 : 0);
  glUniform4f(glGetUniformLocation(p, "u_plane"), params.clip_plane[0], params.clip_plane[1], params.clip_plane[2], params.clip_plane[3]);
  glUniform1i(glGetUniformLocation(p, "u_depth"), 0);
  glUniform1i(glGetUniformLocation(p, "u_volume"), 1);
  glUniform1i(glGetUniformLocation(p, "u_brick_range"), 2);
  glBindTextureUnit(0, depth_texture);
  glBindTextureUnit(1, voxels_.get());
  glBindTextureUnit(2, brick_range_.get());
  glBindImageTexture(0, image_.get(), 0, GL_FALSE, 0, GL_WRITE_ONLY, GL_RGBA32F);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, table_.get());
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, mask_.get());
  glDispatchCompute(static_cast<GLuint>((cam.width + 7) / 8), static_cast<GLuint>((cam.height + 7) / 8), 1);
  glMemoryBarrier(GL_SHADER_IMAGE_ACCESS_BARRIER_BIT | GL_TEXTURE_FETCH_BARRIER_BIT | GL_TEXTURE_UPDATE_BARRIER_BIT);
}

volume::RgbaImage VolumeRaycaster::read_back() const {
  volume::RgbaImage img;
  img.width = image_w_;
  img.height = image_h_;
  img.rgba.resize(static_cast<std::size_t>(image_w_) * static_cast<std::size_t>(image_h_) * 4);
  if (image_.get() != 0)
    glGetTextureImage(image_.get(), 0, GL_RGBA, GL_FLOAT, static_cast<GLsizei>(img.rgba.size() * sizeof(float)), img.rgba.data());
  return img;
}

}  // namespace lancet::render
