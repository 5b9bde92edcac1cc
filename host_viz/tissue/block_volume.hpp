#pragma once
// The volume under the procedural tissue block (surface/triangle_mesh), so that the block has
// a voxel brick too and the drill works on it: layers parallel to the block's surface, in
// Hounsfield units with the phantom's partial-volume blending and labels. Allocating; configure
// time only.

#include "surface/triangle_mesh.hpp"
#include "volume/phantom.hpp"

namespace lancet::tissue {

struct BlockLayers {
  double skin = 0.002;    ///< m thick
  double fat = 0.006;     ///< m thick
  double muscle = 0.012;  ///< m thick: the bone plate's top lies skin + fat + muscle deep
  double cortex = 0.004;  ///< m thick, over marrow to the bottom
  double depth = 0.04;    ///< m of tissue under the surface's lowest point
  double spacing = 0.001; ///< m, isotropic
};

/// Voxels over the block's square (world frame: the volume needs no placement), from just above
/// its highest point to `depth` below its lowest. Material labels as the phantom's
/// (PhantomMaterial); noise-free.
volume::LabelledVolume make_block_volume(const surface::TissueBlockParams& block, const BlockLayers& layers = {});

}  // namespace lancet::tissue
