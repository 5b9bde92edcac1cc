#pragma once
// DICOM series loader (GDCM): one directory holding the slices of one CT series.
// Allocating file I/O at load time; not for the real-time path. Errors never throw (and no input
// file can make GDCM abort the program: see dicom_scan.hpp): every failure comes back as an Error
// naming the directory or file, the field (tag and name) and expected vs found; what was skipped
// comes back in Volume::warnings.

#include <string>

#include "lancet/shared_model/result.hpp"
#include "volume/volume.hpp"

namespace lancet::volume {

/// Largest step between neighbouring slices, as a multiple of the spacing around it, that is not a
/// gap (a missing slice leaves twice the spacing).
inline constexpr double kDicomGapRatio = 1.5;

/// How error messages name the DicomOptions fields: a program passes its own flags (lancet-volume
/// passes "--resample-uneven", "--shear-tilted", "--allow-gaps").
struct DicomOptionNames {
  const char* resample_uneven = "DicomOptions::resample_uneven";
  const char* shear_tilted = "DicomOptions::shear_tilted";
  const char* allow_gaps = "DicomOptions::allow_gaps";
};

struct DicomOptions {
  /// Uneven slice spacing: false = refuse; true = resample along the slice axis to the smallest
  /// spacing with linear interpolation (gaps only with allow_gaps).
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
  /// With resample_uneven: interpolate across gaps too (steps over kDicomGapRatio × the spacing
  /// around them, typically a missing slice), each named in Volume::warnings. false = refuse them.
  bool allow_gaps = false;
  /// How error messages name the options above.
  DicomOptionNames names{};
};

/// Loads the one CT (or other greyscale) series in `directory` (not recursive).
///
/// Every regular file is first checked by scan_dicom (dicom_scan.hpp) on its bytes; only files
/// that pass are parsed by GDCM, from those same bytes. The series is the SeriesInstanceUID
/// (0020,000E) with the most readable image files (a tie is an error). Files that are not part of
/// it (not DICOM, not an image, another series, or unreadable before their SeriesInstanceUID) are
/// skipped and each is named in Volume::warnings with the reason. A file of the series that is
/// broken (cut short: PixelData shorter than Rows × Columns × bytes per pixel; malformed) or in a
/// form the loader refuses is an error naming the file, the byte, the field and expected vs found.
///
/// All slices must share Rows (0028,0010), Columns (0028,0011), ImageOrientationPatient
/// (0020,0037), PixelSpacing (0028,0030) and pixel type; otherwise the error names the two
/// disagreeing files. Slices are sorted by the projection of ImagePositionPatient (0020,0032) onto
/// the slice normal (row cosine × column cosine), not by file name. Values = stored value ·
/// RescaleSlope + RescaleIntercept (defaults 1 and 0); value_unit "HU" only when Modality
/// (0008,0060) is CT, else "raw"; Volume::modality = Modality. 8-bit and 16-bit (signed or
/// unsigned) single-sample pixels, uncompressed or RLE/JPEG/JPEG-LS/JPEG 2000. Geometry in metres:
/// spacing x = PixelSpacing[1] (column spacing), y = PixelSpacing[0], z = distance between slices
/// along the normal; origin = first slice's ImagePositionPatient; direction columns = row cosine,
/// column cosine, slice normal (the tilted step direction with options.shear_tilted).
///
/// Refuses multi-frame files; gantry tilt (position steps not parallel to the normal; the message
/// gives the angle in degrees) unless options.shear_tilted; uneven slice spacing unless
/// options.resample_uneven (the message names both spacings and the files where it changes); and
/// a gap, a step over kDicomGapRatio × the spacing around it (the median of up to two steps either
/// side, at most the thicker slice's SliceThickness (0018,0050)), unless options.allow_gaps too:
/// the message names the files either side of the gap, its length and the spacing expected there.
/// Options are named in messages as options.names says. A missing directory is kNotFound.
/// `progress` (may be empty) is called with 0..1 while reading.
[[nodiscard]] Result<Volume> load_dicom_series(const std::string& directory, const DicomOptions& options = {},
                                               const Progress& progress = {});

}  // namespace lancet::volume
