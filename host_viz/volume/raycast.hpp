#pragma once
// Direct volume rendering by ray casting: the transfer function, its presets, the min/max brick
// grid for empty-space skipping, and the CPU reference renderer that the GPU ray caster
// (render/volume_raycaster) must match. No OpenGL here (tested headless).
//
// The ray. For pixel (x, y) of a w×h image, the ray runs from the near to the far plane through
// the pixel's centre (the camera's inverse view-projection gives both, in the volume's world frame:
// m, position = origin + index · spacing; the direction matrix is not used). It is clipped to the
// box of voxel centres [0, n−1] on each axis, and to a per-pixel limit (the depth of the opaque
// meshes in front), and sampled at t = t_in + (k + j)·Δs, k = 0, 1, …, where j ∈ [0, 1) is a
// per-pixel hash (jitter: no wood-grain rings) and Δs = step · reference_step (m). The reference
// step is the smallest voxel spacing, so anisotropic voxels get one step length in metres.
//
// A sample. The value is interpolated trilinearly; the transfer function maps it to a colour and
// an opacity a defined per reference step; the opacity of one step of Δs is
// α = 1 − (1 − a)^(Δs / reference_step) (opacity correction: halving the step leaves the image's
// opacity unchanged). With shading, the colour is lit by a headlight with the gradient (central
// differences of the interpolated field, one voxel apart) as the normal: c · (0.3 + 0.7 |n·l|).
// Compositing is front to back (premultiplied); a ray stops once its opacity reaches
// early_stop (0.99). MIP: the largest value along the ray, coloured by the table (no opacity
// correction, no shading); a MIP ray stops once its maximum reaches a value above which the table
// is constant (TransferFunction::constant_from), since nothing further can change its colour.
//
// Empty space. The grid holds, per 8³ brick, the smallest and largest value of the voxels any
// sample inside it interpolates from (the brick and a one-voxel apron). A brick where the transfer
// function's opacity is zero over [min, max] is empty: a ray entering it jumps to the first sample
// past the brick's exit, on the same t lattice, so skipping never changes the image. For MIP, a
// brick is skipped once the ray's maximum so far is at least the brick's largest value (no sample
// in it can raise the maximum). Drilling or cutting a region updates the bricks over it (update()).

#include <array>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "lancet/shared_model/geometry.hpp"
#include "volume/live_isosurface.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// One control point of a transfer function: at `value`, colour (0..1) and opacity per
/// reference step (0..1).
struct TfPoint {
  float value;
  float r, g, b, a;
};

struct TransferFunction {
  static constexpr int kSize = 256;
  float lo = -1000, hi = 2000;                    ///< the table spans [lo, hi]; values outside clamp
  std::array<std::array<float, 4>, kSize> table{};  ///< rgba; alpha per reference step
  bool mip = false;                               ///< maximum-intensity projection instead of compositing

  /// The table from control points (sorted by value; linear between them, constant outside).
  static TransferFunction from_points(std::span<const TfPoint> points, float lo, float hi);
  /// The table at value v, linearly between entries.
  [[nodiscard]] std::array<float, 4> lookup(float v) const noexcept;
  /// The largest opacity the table gives any value in [a, b] (the entries lookup() may blend).
  [[nodiscard]] float max_alpha(float a, float b) const noexcept;
  /// A value from which lookup() gives the same colour for every larger value (infinity when
  /// the table's last two entries differ): a MIP ray may stop once its maximum reaches it.
  [[nodiscard]] float constant_from() const noexcept;
};

enum class TfPreset : std::uint8_t { kCtSkin, kCtSoftTissue, kCtBone, kCtVessels, kMip };
inline constexpr TfPreset kTfPresets[] = {TfPreset::kCtSkin, TfPreset::kCtSoftTissue, TfPreset::kCtBone, TfPreset::kCtVessels,
                                          TfPreset::kMip};
/// A table's control points (sorted by value) and range: what the transfer-function editor edits.
struct TfSpec {
  std::vector<TfPoint> points;
  float lo = -1000, hi = 3000;
  bool mip = false;
  [[nodiscard]] TransferFunction table() const;
};

/// 3D Slicer's names ("CT-Skin", ...), for the UI.
[[nodiscard]] std::string_view tf_preset_name(TfPreset p) noexcept;
/// The preset over HU (window/level shifts and scales its points: see apply_window).
[[nodiscard]] TransferFunction tf_preset(TfPreset p);
/// Moves a table's control points as a window/level drag does: `level` shifts (HU) and `width`
/// scales around the preset's centre (1 = as designed). Rebuilds from the preset's points.
[[nodiscard]] TransferFunction tf_preset(TfPreset p, float level_shift, float width_scale);
/// The preset's points after window/level, as tf_preset uses them.
[[nodiscard]] TfSpec tf_preset_spec(TfPreset p, float level_shift = 0, float width_scale = 1);

/// Per-brick value ranges for empty-space skipping.
class BrickGrid {
 public:
  static constexpr int kBrick = 8;
  BrickGrid() = default;
  explicit BrickGrid(const Volume& v);
  /// Recomputes the bricks that the voxels of `box` (and their apron) touch.
  void update(const Volume& v, VoxelBox box);
  [[nodiscard]] std::array<int, 3> dims() const noexcept { return dims_; }
  [[nodiscard]] std::span<const float> min() const noexcept { return min_; }
  [[nodiscard]] std::span<const float> max() const noexcept { return max_; }
  /// Bricks whose opacity is zero under tf.
  [[nodiscard]] std::vector<std::uint8_t> empty_mask(const TransferFunction& tf) const;

 private:
  void compute(const Volume& v, int bx, int by, int bz);
  std::array<int, 3> dims_{};
  std::vector<float> min_, max_;
};

/// The camera: column-major 4×4 inverse of projection · view (as glm stores it), mapping clip
/// coordinates to the volume's world frame (m).
struct RayCamera {
  std::array<float, 16> inv_view_proj{};
  int width = 0, height = 0;
};

struct RaycastParams {
  float step = 0.5f;        ///< sample distance in reference steps
  bool jitter = true;
  float early_stop = 0.99f;
  bool skip_empty = true;
  bool shade = true;
  bool opacity_correction = true;  ///< false: a sample's opacity is the table's whatever the step (reference only, for tests)
  /// A clipping plane (volume frame, m): only what lies where a·x + b·y + c·z + d <= 0 is drawn.
  bool clip = false;
  std::array<float, 4> clip_plane{0, 0, 1, 0};
};

struct RaycastStats {
  std::uint64_t samples = 0;         ///< samples taken (looked up in the table)
  std::uint64_t skipped_bricks = 0;  ///< empty bricks jumped over
  std::uint64_t early_stops = 0;     ///< rays stopped by opacity
};

/// Premultiplied RGBA, float, row 0 at the bottom (as GL reads back).
struct RgbaImage {
  int width = 0, height = 0;
  std::vector<float> rgba;
};

/// The smallest voxel spacing (m): the reference step.
[[nodiscard]] float reference_step(const Volume& v) noexcept;

/// The CPU reference. max_t (optional, width·height): per pixel, the ray parameter (m from the
/// near plane point) where an opaque surface stops it. Single-threaded; for tests and figures.
void raycast_cpu(const Volume& v, const BrickGrid& grid, const TransferFunction& tf, const RayCamera& camera,
                 const RaycastParams& params, std::span<const float> max_t, RgbaImage& out, RaycastStats* stats = nullptr);

/// The per-pixel jitter in [0, 1) (a 32-bit integer hash; the GPU computes the same).
[[nodiscard]] float ray_jitter(int x, int y) noexcept;

}  // namespace lancet::volume
