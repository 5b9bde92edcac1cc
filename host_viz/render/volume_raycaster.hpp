#pragma once
// VolumeRaycaster: GPU direct volume rendering, one GL 4.5 compute shader invocation per pixel,
// the same sampling, table, opacity correction, jitter, early termination, empty-space skipping
// and shading as volume::raycast_cpu (its reference; volume/raycast.hpp states the algorithm).
// MIP skips on a schedule of its own: walks through the brick grid first bound the stretch of the
// ray that can hold its maximum (from the first to the last brick whose largest value reaches the
// largest smallest value of a brick the ray surely samples), and only that stretch is sampled,
// with no test per step; the samples left out cannot raise the maximum, so the image is the
// reference's. The voxels are an R32F 3-D texture, interpolated by the texture unit (llvmpipe
// blends in float, so the two agree to rounding; a GPU's 8-bit blend weights differ from the
// reference by up to 1/256 of a voxel step). The bricks' empty mask and the table live in storage
// buffers, the bricks' (smallest, largest) values in an RG32F 3-D texture; the image is an RGBA32F
// texture, premultiplied. The shader is compiled once per combination of MIP, shading and
// skipping (no masked-out code for the modes not run). Needs a current GL 4.5 context.

#include <array>
#include <cstdint>

#include "render/gl_objects.hpp"
#include "volume/raycast.hpp"

namespace lancet::render {

class VolumeRaycaster {
 public:
  /// Compiles the compute shader. Throws std::runtime_error when GL refuses it.
  VolumeRaycaster();

  /// Uploads the voxels and builds the brick grid.
  void set_volume(const volume::Volume& v);
  /// After drilling or cutting changed the voxels of `box`: uploads those slabs again and
  /// recomputes the bricks over them.
  void update_region(const volume::Volume& v, volume::VoxelBox box);
  void set_transfer_function(const volume::TransferFunction& tf);

  /// Renders a camera.width × camera.height image. depth_texture (optional): the opaque meshes'
  /// depth buffer for the same camera and size; rays stop there (composited with the meshes).
  void render(const volume::RayCamera& camera, const volume::RaycastParams& params, GLuint depth_texture = 0);
  /// The last image (premultiplied RGBA, row 0 at the bottom).
  [[nodiscard]] volume::RgbaImage read_back() const;
  [[nodiscard]] GLuint texture() const noexcept { return image_.get(); }

 private:
  void upload_mask();         ///< the bricks that are empty under the table
  void upload_brick_range();  ///< each brick's (min, max)
  std::array<Program, 8> programs_;  ///< by MIP | SHADE << 1 | SKIP << 2
  Texture voxels_;
  Buffer mask_, table_;
  Texture brick_range_;  ///< RG32F, one texel per brick: (min, max)
  std::array<int, 3> brick_range_dims_{};
  Texture image_;
  int image_w_ = 0, image_h_ = 0;
  volume::BrickGrid grid_;
  volume::TransferFunction tf_;
  std::array<int, 3> dims_{};
  Vec3 origin_{}, spacing_{};
  float reference_ = 0;
};

}  // namespace lancet::render
