#pragma once
// NRRD (NRRD0001..NRRD0005) volume loader: .nrrd with an attached header (data after the first
// blank line) and .nhdr detached headers (`data file:` one file, a printf pattern list
// `name.%d min max step [subdim]`, or `LIST [subdim]` followed by one file name per line).
// Allocating file I/O at load time; not for the real-time path. Errors never throw: every failure
// comes back as an Error naming the file, the header line and field (when the problem is about a
// field) and expected vs found, e.g. `head.nhdr:3: sizes: expected 3 integers …, found '64 64'`.

#include <string>

#include "lancet/shared_model/result.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// Loads a 3-D scalar NRRD. Supports `encoding:` raw and gzip (gz), `type:` every 8/16/32-bit
/// integer spelling and float/double (values become floats; source_type is the nearest VoxelType:
/// u8, i16 for int8/int16, u16, f32 for the rest), `endian:` little/big (required for multi-byte
/// types), `dimension: 3`, `sizes:`, `spacings:` or `space directions:` (vector length = spacing,
/// unit vector = column of Volume::direction) with `space origin:` (without a `space:` or
/// `space dimension:` line, as pynrrd writes them, the space dimension is taken from the vectors
/// and Volume::warnings says so), `byte skip:` (-1 = data at the
/// end of each raw file; for gzip the skip applies to the inflated stream), `line skip:`.
/// Lengths are taken as mm (`space units:` other than mm are refused) and stored in metres. The
/// `space:` name (e.g. left-posterior-superior) is checked to be 3-D but not kept: direction and
/// origin are stored as the file gives them, in that space. Comments (#) and `key:=value` lines are
/// ignored, as are purely descriptive fields (kinds, centers, labels, units, content, min/max, ...).
/// Refuses other dimensions, block/int64 types, ascii/hex/bzip2 encodings, unknown or repeated
/// fields, and more than kMaxVoxels voxels (checked before anything is allocated; every size is
/// checked against the real data files). Relative data file names are relative to the header's
/// folder. value_unit is "raw". `progress` (may be empty) gets a few dozen calls with 0..1.
[[nodiscard]] Result<Volume> load_nrrd(const std::string& path, const Progress& progress = {});

}  // namespace lancet::volume
