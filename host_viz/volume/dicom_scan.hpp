#pragma once
// DicomScan: a check of one DICOM Part 10 file's data elements, run on the file's bytes before any
// DICOM library parses them. GDCM's reader asserts (SIGABRT: the whole program dies) on a file cut
// inside its header, and silently zero-fills pixel data cut short; this walk finds both, and every
// other element whose length does not fit, and says where: byte offset, tag, name, expected vs found.
//
// It walks every element of the file meta group and the data set, sequences and items included
// (at most kMaxDicomDepth deep), in the transfer syntax's encoding (implicit VR little endian,
// explicit VR little or big endian, and encapsulated pixel data for RLE, JPEG, JPEG-LS and
// JPEG 2000), checks every value representation and every length against the bytes that hold it,
// reads the fields that shape an image (Rows, Columns, pixel format, frames, Modality,
// SeriesInstanceUID) and checks the pixel format is one the loader supports and that native
// PixelData holds Rows × Columns × bytes per pixel.
//
// Reads nothing but `bytes`; allocates only the returned strings. Never throws. Not for the
// real-time path.

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace lancet::volume {

/// Deepest nesting of sequences the scan follows; deeper files are kBroken (a guard against a
/// crafted file exhausting the stack of whoever parses it next).
inline constexpr int kMaxDicomDepth = 16;
/// Largest file the DICOM loader reads as one slice (bytes).
inline constexpr std::uint64_t kMaxDicomFileBytes = std::uint64_t{1} << 30;

enum class DicomScanStatus : std::uint8_t {
  kImage,        ///< one frame of pixel data in a form the loader reads
  kNotImage,     ///< a valid DICOM file without PixelData (7FE0,0010): DICOMDIR, a report, ...
  kNotDicom,     ///< no 'DICM' marker at byte 128: not a DICOM Part 10 file
  kBroken,       ///< DICOM, but truncated or malformed (problem says where)
  kUnsupported,  ///< a DICOM image in a form the loader refuses (problem says which field)
};

struct DicomScan {
  DicomScanStatus status = DicomScanStatus::kNotDicom;
  /// Why the status is not kImage, without the file name: byte offset, tag and name, expected vs
  /// found. Empty for kImage.
  std::string problem;
  std::string transfer_syntax;  ///< TransferSyntaxUID (0002,0010)
  bool explicit_vr = true;
  bool big_endian = false;
  bool encapsulated = false;    ///< compressed pixel data in fragments
  // The fields below are filled as they are met, so a kBroken file still has those that came
  // before its problem (the loader uses series_uid to tell a broken slice of its series from junk).
  std::string modality;         ///< Modality (0008,0060), e.g. "CT", "MR"; empty when absent
  std::string series_uid;       ///< SeriesInstanceUID (0020,000E); empty when absent
  int rows = 0;                 ///< Rows (0028,0010)
  int columns = 0;              ///< Columns (0028,0011)
  int samples_per_pixel = 1;    ///< SamplesPerPixel (0028,0002)
  int bits_allocated = 0;       ///< BitsAllocated (0028,0100)
  int bits_stored = 0;          ///< BitsStored (0028,0101); 0 when absent
  int high_bit = -1;            ///< HighBit (0028,0102); -1 when absent
  int pixel_representation = 0; ///< PixelRepresentation (0028,0103): 0 unsigned, 1 signed
  int frames = 1;               ///< NumberOfFrames (0028,0008)
  std::string photometric;      ///< PhotometricInterpretation (0028,0004)
  bool has_pixel_data = false;
  std::uint64_t pixel_element_offset = 0;  ///< bytes from the file's start to PixelData's tag: the header ends there
  std::uint64_t pixel_offset = 0;  ///< bytes from the file's start to PixelData's value
  std::uint64_t pixel_length = 0;  ///< bytes of PixelData's value (native), or of all fragments
  std::uint64_t fragments = 0;     ///< compressed: fragments after the basic offset table
  std::uint64_t first_fragment_offset = 0;  ///< compressed: bytes from the file's start to the first fragment's data
  std::uint64_t first_fragment_length = 0;  ///< compressed: bytes of the first fragment

  /// Bytes of native pixel data one frame needs: Rows × Columns × BitsAllocated / 8.
  [[nodiscard]] std::uint64_t frame_bytes() const noexcept {
    return static_cast<std::uint64_t>(rows) * static_cast<std::uint64_t>(columns) * static_cast<std::uint64_t>(bits_allocated / 8);
  }
};

/// Scans one file's bytes (the whole file). Never fails: the status says what the file is.
[[nodiscard]] DicomScan scan_dicom(std::span<const std::uint8_t> bytes);

/// True when the first bytes carry the DICOM Part 10 marker ('DICM' at byte 128); lets a caller
/// skip reading a large file that is not DICOM.
[[nodiscard]] bool has_dicom_marker(std::span<const std::uint8_t> first_bytes) noexcept;

}  // namespace lancet::volume
