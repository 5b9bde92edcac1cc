#pragma once
// The built-in phantom: the demo's default tissue, so the demo needs no data. A limb-like volume
// along z: skin, subcutaneous fat, muscle, a bone (cortex and marrow) off centre, two
// contrast-filled vessels winding beside it (kVessel) and a superficial vein in the fat under the
// top (kVein, unenhanced), in Hounsfield units with CT-like noise and partial-
// volume boundaries (each boundary a two-voxel ramp centred on its exact place). Deterministic
// from the seed: every voxel's noise comes from a hash of (seed, voxel index), so it is the same on
// every machine and independent of fill order. Allocating; configure time only.

#include <array>
#include <cstdint>
#include <vector>

#include "volume/volume.hpp"

namespace lancet::volume {

/// Material ids of the phantom's voxels (and of TissuePatch triangles cut from it).
enum PhantomMaterial : std::uint8_t {
  kAir = 0, kSkin = 1, kFat = 2, kMuscle = 3, kCorticalBone = 4, kMarrow = 5, kVessel = 6,
  kVein = 7,  ///< the superficial vein: blood without contrast
};

struct PhantomParams {
  std::array<int, 3> dims{128, 128, 160};
  double spacing = 0.001;          ///< m, isotropic
  double limb_radius = 0.045;      ///< m, outer skin radius at mid length (the limb tapers by 15 %)
  double skin = 0.002;             ///< m thick
  double fat = 0.008;              ///< m thick
  double bone_radius = 0.013;      ///< m, outer cortex
  double cortex = 0.004;           ///< m thick
  double noise_hu = 12;            ///< HU, standard deviation of the CT noise
  /// Boundaries blended over two voxels, as a CT's partial-volume effect and point spread blend
  /// them, so that isosurfaces through them are smooth instead of terraced; false: every voxel
  /// takes its material's HU (hard labels). The material labels are hard either way (by centre).
  bool partial_volume = true;
  std::uint64_t seed = 1;
  /// Threads that make it (1 or 2; a volume under 65 536 voxels takes one). The voxels are the
  /// same numbers either way: each slice depends on its own index alone.
  int threads = 2;
};

/// Nominal HU of each material (before noise).
float phantom_hu(PhantomMaterial m) noexcept;

/// The phantom's partial-volume blending: how much of a voxel of size `spacing` centred `d` from
/// a boundary (d > 0: inside it) counts as inside. A linear ramp two voxels wide, the box of the
/// voxel blurred by about a voxel more (a CT's point spread). Narrower, marching cubes' linear
/// interpolation meets the ramp's kinks on most edges and the surface facets; wider, the noise
/// moves it more.
double partial_volume_fraction(double d, double spacing) noexcept;

/// The built-in phantom: HU centred on (0, 0, 0), each voxel labelled with its PhantomMaterial.
LabelledVolume make_phantom(const PhantomParams& params);

}  // namespace lancet::volume
