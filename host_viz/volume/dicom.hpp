#pragma once
// DICOM series loader (GDCM): one directory holding the slices of one CT series.
// Allocating file I/O at load time; not for the real-time path. Errors never throw: every
// failure comes back as an Error naming the directory or file, the field (tag and name) and
// expected vs found.

#include <string>

#include "lancet/shared_model/result.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

struct DicomOptions {
  /// Uneven slice spacing: false = refuse; true = resample along the slice axis to the smallest
  /// spacing with linear interpolation.
  bool resample_uneven = false;
  /// Relative tolerance for "equal" slice spacings and for "step parallel to the slice normal"
  /// (sine of the angle between the position step and the normal).
  double spacing_tolerance = 0.01;
  /// Gantry tilt (slice positions stepping off the normal): false = refuse, naming the angle;
  /// true = keep the stack as acquired, on a sheared grid: direction's third column is then the
  /// step direction (tilted from the normal by the gantry angle), spacing.z the step along it,
  /// and every voxel sits exactly where the scanner put it (no resampling in-plane). Every slice
  /// must lie on one line through the first and last.
  bool shear_tilted = false;
};

/// Loads every file in `directory` (not recursive) that parses as a DICOM image with pixel data;
/// other files are skipped. All slices must share SeriesInstanceUID (0020,000E), Rows (0028,0010),
/// Columns (0028,0011), ImageOrientationPatient (0020,0037), PixelSpacing (0028,0030) and pixel
/// type; otherwise the error names the two disagreeing files. Slices are sorted by the projection
/// of ImagePositionPatient (0020,0032) onto the slice normal (row cosine × column cosine), not by
/// file name. Values = stored value · RescaleSlope + RescaleIntercept (defaults 1 and 0),
/// value_unit "HU"; 8-bit and 16-bit (signed or unsigned) single-sample pixels. Geometry in
/// metres: spacing x = PixelSpacing[1] (column spacing), y = PixelSpacing[0], z = distance between
/// slices along the normal; origin = first slice's ImagePositionPatient; direction columns = row
/// cosine, column cosine, slice normal (the tilted step direction with options.shear_tilted).
/// Refuses multi-frame files; gantry tilt (position steps not parallel to the normal; the message
/// gives the angle in degrees) unless options.shear_tilted; and uneven slice spacing unless
/// options.resample_uneven (the message names both spacings and the files where it changes).
/// `progress` (may be empty) is called with 0..1 while reading.
[[nodiscard]] Result<Volume> load_dicom_series(const std::string& directory, const DicomOptions& options = {},
                                               const Progress& progress = {});

}  // namespace lancet::volume
