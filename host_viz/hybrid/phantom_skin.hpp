#pragma once
// The built-in CT phantom as lancet-viz places it: its skin (marching cubes at −300 HU, padded so
// it closes) turned so that the limb lies along x with its upper side facing +z and lowered so
// that its top is at z = 0, where the stylus scripts work; the same placement puts the phantom's
// volume under it for the drill's brick. Allocating; configure time only.

#include "hybrid/volume_brick.hpp"
#include "surface/placeholder_mesh.hpp"
#include "volume/phantom.hpp"

namespace lancet::hybrid {

/// The skin in the world frame (empty when the extraction fails), and the placement of `phantom`'s
/// volume that puts it there.
surface::TriangleMesh phantom_skin(const volume::Phantom& phantom, VolumePlacement& placement);

}  // namespace lancet::hybrid
