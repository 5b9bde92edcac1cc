#pragma once
// MetaImage (.mhd detached header, .mha attached header) and headerless raw volume loaders.
// Allocating file I/O at load time; not for the real-time path. Errors never throw: every
// failure comes back as an Error naming the file, the header line and field (when the problem is
// about a field) and expected vs found.

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>

#include "lancet/shared_model/result.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// Largest voxel count a loader accepts (2^31). Checked before anything is allocated.
inline constexpr std::uint64_t kMaxVoxels = std::uint64_t{1} << 31;

/// A loaded MetaImage plus the header fields that do not fit in Volume.
struct MetaImage {
  Volume volume;
  std::string anatomical_orientation;  ///< e.g. "RPS" from AnatomicalOrientation; empty if absent
};

/// Loads a 3-D MetaImage: a .mhd whose ElementDataFile names a raw file beside it (relative to
/// the header's folder) or is LOCAL, or a .mha whose data follows the line
/// `ElementDataFile = LOCAL`. Supports raw or zlib-compressed data (CompressedData = True; gzip is
/// also accepted), ElementType MET_UCHAR/CHAR/SHORT/USHORT/INT/UINT/FLOAT/DOUBLE (values become
/// floats; source_type is the nearest VoxelType: u8, i16 for CHAR/SHORT, u16, f32 for the rest),
/// big-endian data (ElementByteOrderMSB / BinaryDataByteOrderMSB = True), HeaderSize (bytes to
/// skip; -1 = data at the end of the file), ElementSpacing (else ElementSize, else 1 mm),
/// Offset/Position/Origin and TransformMatrix/Orientation/Rotation. Lengths in the file are mm;
/// the Volume holds metres. TransformMatrix is read as MetaIO/ITK write it: the k-th group of three
/// numbers is the world direction of index axis k, so Volume::position() maps index → world.
/// Modality (MET_MOD_CT, MET_MOD_MR, ...) sets Volume::modality; value_unit is "HU" for
/// MET_MOD_CT, else "raw". Refuses NDims ≠ 3, ElementNumberOfChannels ≠ 1, ASCII data, file lists
/// and more than kMaxVoxels voxels. Unknown fields are ignored.
/// `progress` (may be empty) is called a few dozen times with 0..1 while reading/converting.
[[nodiscard]] Result<MetaImage> load_metaimage_with_info(const std::string& path, const Progress& progress = {});

/// load_metaimage_with_info without the extra header fields.
[[nodiscard]] Result<Volume> load_metaimage(const std::string& path, const Progress& progress = {});

/// Loads a headerless raw file of dims[0]·dims[1]·dims[2] voxels of `type`, x fastest. The file
/// size must equal the voxel count × element size. spacing_m: metres between voxel centres;
/// origin 0, identity direction, value_unit "raw".
[[nodiscard]] Result<Volume> load_raw(const std::string& path, std::array<int, 3> dims, VoxelType type,
                                      Vec3 spacing_m, bool big_endian = false, const Progress& progress = {});

}  // namespace lancet::volume
