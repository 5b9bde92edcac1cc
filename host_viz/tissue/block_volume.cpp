#include "tissue/block_volume.hpp"

#include <algorithm>
#include <cmath>

namespace lancet::tissue {

volume::LabelledVolume make_block_volume(const surface::TissueBlockParams& block, const BlockLayers& L) {
  using volume::PhantomMaterial;
  volume::LabelledVolume ph;
  volume::Volume& v = ph.volume;
  const double s = L.spacing, a = std::abs(block.wave_amplitude);
  const double z_top = a + 2 * s, z_bottom = -a - L.depth;
  const int nxy = static_cast<int>(std::ceil(2 * block.half_extent / s)) + 1;
  const int nz = static_cast<int>(std::ceil((z_top - z_bottom) / s)) + 1;
  v.dims = {nxy, nxy, nz};
  v.spacing = {s, s, s};
  v.origin = {-block.half_extent, -block.half_extent, z_bottom};
  v.source_type = volume::VoxelType::kF32;
  v.value_unit = "HU";
  v.modality = "CT";  // a simulated CT
  v.data.resize(v.voxel_count());
  ph.material.resize(v.voxel_count());
  const double skin_end = L.skin, fat_end = skin_end + L.fat, muscle_end = fat_end + L.muscle, cortex_end = muscle_end + L.cortex;
  const auto hu = [](PhantomMaterial m) { return static_cast<double>(volume::phantom_hu(m)); };
  const auto inside = [s](double d) { return volume::partial_volume_fraction(d, s); };  // the phantom's blending
  const auto lerp = [](double x, double y, double t) { return x + (y - x) * t; };
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < nxy; ++j)
      for (int i = 0; i < nxy; ++i) {
        const Vec3 w = v.position(i, j, k);
        const double d = surface::tissue_block_height(block, w.x, w.y) - w.z;  // depth under the surface
        PhantomMaterial m = volume::kAir;
        if (d >= 0) {
          m = d < skin_end     ? volume::kSkin
              : d < fat_end    ? volume::kFat
              : d < muscle_end ? volume::kMuscle
              : d < cortex_end ? volume::kCorticalBone
                               : volume::kMarrow;
        }
        const double bone = lerp(hu(volume::kCorticalBone), hu(volume::kMarrow), inside(d - cortex_end));
        const double muscle = lerp(hu(volume::kMuscle), bone, inside(d - muscle_end));
        const double fat = lerp(hu(volume::kFat), muscle, inside(d - fat_end));
        const double skin = lerp(hu(volume::kSkin), fat, inside(d - skin_end));
        const std::size_t idx = v.index(i, j, k);
        v.data[idx] = static_cast<float>(lerp(hu(volume::kAir), skin, inside(d)));
        ph.material[idx] = m;
      }
  return ph;
}

}  // namespace lancet::tissue
