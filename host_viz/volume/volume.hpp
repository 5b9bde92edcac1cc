#pragma once
// Volume: a 3-D scalar image (CT) as every part of host_viz/volume uses it. Values are floats
// (HU when the source says the scan is CT, else the file's values), x fastest; geometry is in
// metres. Allocating; not for the real-time path.

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "lancet/shared_model/geometry.hpp"
#include "volume/build_arrays.hpp"

namespace lancet::volume {

enum class VoxelType : std::uint8_t { kU8, kI16, kU16, kF32 };

/// A volume's values: a std::vector<float> whose resize() does not zero what it adds.
using VoxelArray = ScratchVector<float>;
/// Value by value against a plain vector (either way round).
inline bool operator==(const VoxelArray& a, const std::vector<float>& b) { return std::equal(a.begin(), a.end(), b.begin(), b.end()); }

struct Volume {
  std::array<int, 3> dims{};                        ///< nx, ny, nz
  Vec3 spacing{};                                   ///< m between voxel centres along x, y, z
  Vec3 origin{};                                    ///< m, world position of voxel (0, 0, 0)'s centre
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};  ///< row-major 3×3: column a = world direction of axis a
  VoxelType source_type = VoxelType::kF32;          ///< what the file stored
  std::string value_unit = "raw";                   ///< "HU" when values are Hounsfield units (CT only), else "raw"
  std::string modality;                             ///< "CT", "MR", ... when the file says (DICOM Modality, MetaImage Modality); else empty
  /// nx·ny·nz values, x fastest. resize() leaves new values unset (a loader writes each voxel once,
  /// on both cores, rather than after zeros): assign(n, value) to fill.
  VoxelArray data;
  /// What the loader noticed and accepted (files it skipped, fields it inferred), one sentence
  /// each naming the file; the library never prints them, a program shows them to its user.
  std::vector<std::string> warnings;

  [[nodiscard]] std::size_t voxel_count() const noexcept {
    return static_cast<std::size_t>(dims[0]) * static_cast<std::size_t>(dims[1]) * static_cast<std::size_t>(dims[2]);
  }
  [[nodiscard]] std::size_t index(int i, int j, int k) const noexcept {
    return static_cast<std::size_t>(i) +
           static_cast<std::size_t>(dims[0]) * (static_cast<std::size_t>(j) + static_cast<std::size_t>(dims[1]) * static_cast<std::size_t>(k));
  }
  [[nodiscard]] float at(int i, int j, int k) const noexcept { return data[index(i, j, k)]; }
  /// World position of voxel (i, j, k)'s centre (m).
  [[nodiscard]] Vec3 position(double i, double j, double k) const noexcept {
    const Vec3 l{i * spacing.x, j * spacing.y, k * spacing.z};
    return origin + Vec3{direction[0] * l.x + direction[1] * l.y + direction[2] * l.z,
                         direction[3] * l.x + direction[4] * l.y + direction[5] * l.z,
                         direction[6] * l.x + direction[7] * l.y + direction[8] * l.z};
  }
};

/// Progress of a long load, 0..1; may be empty.
using Progress = std::function<void(double fraction)>;

/// A volume with a material label per voxel (the tissue scene's: the built-in phantom's
/// PhantomMaterial, or the labels a scenario or a CT's thresholds give).
struct LabelledVolume {
  Volume volume;
  std::vector<std::uint8_t> material;  ///< a label per voxel, same layout as volume.data
};

}  // namespace lancet::volume
