// DICOM series loader: scan_dicom checks each file's bytes, GDCM parses the headers of the files
// that pass, and this file takes their pixels, picks the series, checks it is one consistent,
// untilted stack with no gaps, sorts it along the slice normal and builds the Volume.
//
// Why this shape. GDCM asserts (SIGABRT: the whole program dies) on a file cut inside its header,
// and its image reader runs the pixel codecs (RLE, JPEG, JPEG-LS, JPEG 2000) even to read a
// compressed file; the DICOM fuzzer found its RLE decoder reading out of bounds after a one-bit
// change of a valid file. So:
//  1. scan_dicom walks every element of the file's bytes first (truncation, lengths, VRs, nesting,
//     pixel format, pixel data size) and names the byte and field of the first problem;
//  2. GDCM parses only the header of a file that passed, from those same bytes in memory (a file
//     changed on disk in between cannot slip past), and only up to PixelData: no codec runs here;
//  3. the pixels are taken here: native ones straight from the bytes, RLE by decode_rle_frame; only
//     JPEG-family data goes through GDCM's codecs, and that in a child process (run_isolated).
// Why not every parse in a forked child: the loader runs inside lancet-viz, whose render and
// haptics threads are running, and after fork() a multi-threaded process may only call
// async-signal-safe functions; GDCM allocates, locks and uses iostreams, so a child can deadlock
// (we then lose its time limit) and is kept for the rare compressed slice. A child would also hide
// the parse from the fuzzer's coverage, and its death could only say "signal 6" where the scan
// names the byte and the element. The DICOM fuzz target (tests/fuzz/dicom_fuzz.cpp) runs the scan
// and GDCM's header parse in its own process, where an assertion is a reported crash.

#include "volume/dicom.hpp"

#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmStringFilter.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <optional>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "volume/detail/io.hpp"
#include "volume/dicom_pixels.hpp"
#include "volume/dicom_scan.hpp"
#include "volume/metaimage.hpp"

namespace lancet::volume {
namespace {

namespace fs = std::filesystem;
using detail::invalid;

/// Files named one by one in Volume::warnings; the rest are counted in one more line.
constexpr std::size_t kMaxNamedSkips = 20;
/// RLE Lossless: decoded by decode_rle_frame, not by GDCM.
constexpr std::string_view kRleSyntax = "1.2.840.10008.1.2.5";
/// Longest a child process may take to decode one compressed slice.
constexpr std::chrono::milliseconds kDecodeLimit{20000};

struct Field {
  std::uint16_t group, element;
  const char* name;
};

constexpr Field kPosition{0x0020, 0x0032, "ImagePositionPatient"};
constexpr Field kOrientation{0x0020, 0x0037, "ImageOrientationPatient"};
constexpr Field kPixelSpacing{0x0028, 0x0030, "PixelSpacing"};
constexpr Field kIntercept{0x0028, 0x1052, "RescaleIntercept"};
constexpr Field kSlope{0x0028, 0x1053, "RescaleSlope"};
constexpr Field kThickness{0x0018, 0x0050, "SliceThickness"};

std::string tag_name(const Field& f) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "(%04X,%04X)", static_cast<unsigned>(f.group), static_cast<unsigned>(f.element));
  return std::string(f.name) + " " + buf;
}

std::string mm(double millimetres) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(2);
  s << millimetres << " mm";
  return s.str();
}

// ---- files and their scans ------------------------------------------------------------------

struct Entry {
  fs::path path;
  std::string name;  // file name only, for messages
  DicomScan scan;
};

// The whole file, or (when it lacks the DICOM marker) only its first 132 bytes: a large file of
// something else is not read. kSystem when it cannot be read.
Result<std::vector<std::uint8_t>> read_for_scan(const fs::path& file, std::uint64_t max_bytes) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return Error{ErrorCode::kSystem, "cannot open for reading: " + std::string(std::strerror(errno))};
  std::vector<std::uint8_t> bytes(132);
  in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  bytes.resize(static_cast<std::size_t>(in.gcount()));
  if (!has_dicom_marker(bytes)) return bytes;
  std::error_code ec;
  const auto size = fs::file_size(file, ec);
  if (ec) return Error{ErrorCode::kSystem, "cannot read its size: " + ec.message()};
  if (size > max_bytes) {
    return Error{ErrorCode::kInvalid, "too large for one slice: " + std::to_string(size) + " bytes, at most " + std::to_string(max_bytes)};
  }
  bytes.resize(static_cast<std::size_t>(size));
  in.read(reinterpret_cast<char*>(bytes.data()) + 132, static_cast<std::streamsize>(size - 132));
  bytes.resize(132 + static_cast<std::size_t>(in.gcount()));
  return bytes;
}

Entry scan_file(const fs::path& file, std::vector<std::uint8_t>* keep) {
  Entry e{file, file.filename().string(), {}};
  auto bytes = read_for_scan(file, kMaxDicomFileBytes);
  if (!bytes) {
    e.scan.status = DicomScanStatus::kBroken;
    e.scan.problem = bytes.error().message;
    return e;
  }
  e.scan = scan_dicom(bytes.value());
  if (keep != nullptr) *keep = std::move(bytes).value();
  return e;
}

// The regular files of the directory, sorted; subfolders and special files (FIFOs, devices: never
// opened, reading one could block) are counted for the messages.
struct Listing {
  std::vector<fs::path> files;
  std::vector<std::string> folders;
  std::vector<std::string> special;
};

Result<Listing> list_directory(const std::string& directory) {
  std::error_code ec;
  const auto st = fs::status(directory, ec);
  if (ec || !fs::exists(st)) return Error{ErrorCode::kNotFound, directory + ": not found (expected a folder of DICOM files)"};
  if (!fs::is_directory(st)) return invalid(directory + ": not a folder (a DICOM series is read from the folder holding its files)");
  Listing l;
  fs::directory_iterator it(directory, ec);
  if (ec) return Error{ErrorCode::kSystem, directory + ": cannot list the folder: " + ec.message()};
  for (const auto& entry : it) {
    std::error_code e2;
    if (entry.is_regular_file(e2)) l.files.push_back(entry.path());
    else if (entry.is_directory(e2)) l.folders.push_back(entry.path().filename().string());
    else l.special.push_back(entry.path().filename().string());
  }
  std::sort(l.files.begin(), l.files.end());
  std::sort(l.folders.begin(), l.folders.end());
  return l;
}

std::string some_names(const std::vector<std::string>& names) {
  std::string out;
  for (std::size_t i = 0; i < names.size() && i < 5; ++i) out += (i ? ", " : "") + names[i];
  if (names.size() > 5) out += ", ...";
  return out;
}

// ---- which files are the series ---------------------------------------------------------------

struct Selection {
  std::string series_uid;
  std::vector<const Entry*> slices;  // kImage files of the series
  std::vector<std::string> warnings;
  std::vector<std::string> suspects;  // "name (reason)" of skipped files that could be a missing slice
};

std::string skip_reason(const Entry& e, const std::string& chosen) {
  const DicomScan& s = e.scan;
  switch (s.status) {
    case DicomScanStatus::kNotDicom: return s.problem;
    case DicomScanStatus::kNotImage:
      return (s.series_uid == chosen ? "DICOM of this series without an image (cut short?): " : "DICOM without an image: ") + s.problem;
    case DicomScanStatus::kImage:
      return "another series (SeriesInstanceUID " + detail::shown(s.series_uid) + ", Modality " + detail::shown(s.modality) + ")";
    case DicomScanStatus::kBroken:
    case DicomScanStatus::kUnsupported:
      if (!s.series_uid.empty() && s.series_uid != chosen) {
        return "another series (SeriesInstanceUID " + detail::shown(s.series_uid) + "), unreadable: " + s.problem;
      }
      return "unreadable before its SeriesInstanceUID (0020,000E): " + s.problem;
  }
  return s.problem;
}

Result<Selection> select_series(const std::string& directory, const Listing& listing, const std::vector<Entry>& entries) {
  // The series with the most readable images.
  std::map<std::string, std::size_t> count;
  for (const Entry& e : entries) {
    if (e.scan.status == DicomScanStatus::kImage) ++count[e.scan.series_uid];
  }
  if (count.empty()) {
    std::string why;
    std::size_t n = 0;
    for (const Entry& e : entries) {
      if (n++ < 5) why += (why.empty() ? "" : "; ") + e.name + ": " + e.scan.problem;
    }
    if (entries.size() > 5) why += "; ...";
    std::string folders;
    if (!listing.folders.empty()) {
      folders = "; it has subfolders (" + some_names(listing.folders) + "): give the folder that holds the series' files";
    }
    if (entries.empty()) return invalid(directory + ": no DICOM files: the folder contains no files" + folders);
    return invalid(directory + ": no DICOM image files that can be read among its " + std::to_string(entries.size()) + " file(s): " + why + folders);
  }
  auto best = count.begin();
  for (auto it = count.begin(); it != count.end(); ++it) {
    if (it->second > best->second) best = it;
  }
  for (auto it = count.begin(); it != count.end(); ++it) {
    if (it != best && it->second == best->second) {
      return invalid(directory + ": two series with " + std::to_string(best->second) + " image file(s) each (SeriesInstanceUID (0020,000E) " +
                     detail::shown(best->first) + " and " + detail::shown(it->first) + "): put each series in its own folder");
    }
  }

  Selection sel;
  sel.series_uid = best->first;
  std::vector<std::string> member_errors;
  std::vector<std::string> skipped;
  for (const Entry& e : entries) {
    const DicomScan& s = e.scan;
    const bool member = !s.series_uid.empty() && s.series_uid == sel.series_uid;
    if (s.status == DicomScanStatus::kImage && s.series_uid == sel.series_uid) {
      sel.slices.push_back(&e);
    } else if (member && (s.status == DicomScanStatus::kBroken || s.status == DicomScanStatus::kUnsupported)) {
      member_errors.push_back(e.path.string() + ": " + s.problem);
    } else {
      skipped.push_back(e.path.string() + ": skipped, not part of the series: " + skip_reason(e, sel.series_uid));
      if (s.series_uid.empty() || s.series_uid == sel.series_uid) sel.suspects.push_back(e.name + " (" + skip_reason(e, sel.series_uid) + ")");
    }
  }
  if (!member_errors.empty()) {
    std::string more;
    if (member_errors.size() > 1) more = " (and " + std::to_string(member_errors.size() - 1) + " more file(s) of the series)";
    return invalid(member_errors.front() + more);
  }
  for (std::size_t i = 0; i < skipped.size() && i < kMaxNamedSkips; ++i) sel.warnings.push_back(skipped[i]);
  if (skipped.size() > kMaxNamedSkips) {
    sel.warnings.push_back(directory + ": " + std::to_string(skipped.size() - kMaxNamedSkips) + " more file(s) skipped, not part of the series");
  }
  if (!listing.folders.empty()) {
    sel.warnings.push_back(directory + ": subfolders not searched: " + some_names(listing.folders));
  }
  if (!listing.special.empty()) {
    sel.warnings.push_back(directory + ": special files (not regular files) not read: " + some_names(listing.special));
  }
  return sel;
}

// ---- one slice through GDCM -----------------------------------------------------------------------

struct Slice {
  std::string path;
  std::string name;  // file name only, for messages
  int columns = 0, rows = 0;
  int bits_allocated = 16;
  bool is_signed = true;
  std::array<double, 6> orientation{};
  std::array<double, 2> pixel_spacing{};  // mm: row spacing, column spacing
  Vec3 position{};                        // mm
  double slope = 1, intercept = 0;
  double thickness = 0;                   // mm, SliceThickness; 0 when absent
  std::string modality;
  std::vector<float> values;              // rescaled, x fastest
  double along_normal = 0;                // position · normal (mm)
};

std::string field_string(gdcm::StringFilter& sf, const gdcm::DataSet& ds, const Field& f) {
  const gdcm::Tag tag(f.group, f.element);
  if (!ds.FindDataElement(tag)) return {};
  return std::string(detail::trim(sf.ToString(tag)));
}

// Parses a backslash-separated decimal string into exactly n numbers.
template <std::size_t N>
Result<std::array<double, N>> numbers(const std::string& path, const std::string& text, const Field& f, bool required,
                                      std::array<double, N> fallback) {
  if (text.empty()) {
    if (!required) return fallback;
    return invalid(path + ": " + tag_name(f) + ": expected " + std::to_string(N) + " numbers, found the field missing or empty");
  }
  std::array<double, N> out{};
  std::size_t count = 0;
  std::string_view rest(text);
  while (true) {
    const auto cut = rest.find('\\');
    const std::string_view word = detail::trim(rest.substr(0, cut));
    const auto v = detail::parse_double(word);
    if (!v || !std::isfinite(*v) || count >= N) {
      return invalid(path + ": " + tag_name(f) + ": expected " + std::to_string(N) + " numbers separated by '\\', found " +
                     detail::shown(text));
    }
    out[count++] = *v;
    if (cut == std::string_view::npos) break;
    rest.remove_prefix(cut + 1);
  }
  if (count != N) {
    return invalid(path + ": " + tag_name(f) + ": expected " + std::to_string(N) + " numbers, found " + std::to_string(count) +
                   " in " + detail::shown(text));
  }
  return out;
}

// One stored sample as the value it stands for: the BitsStored bits ending at HighBit, sign-extended
// when PixelRepresentation is 1 (PS3.5 8.1.1); anything in the other bits (overlays) is dropped.
std::int32_t sample_value(std::uint32_t raw, const DicomScan& scan) {
  const int shift = scan.high_bit + 1 - scan.bits_stored;
  const std::uint32_t mask = scan.bits_stored >= 32 ? 0xFFFFFFFFu : (1u << scan.bits_stored) - 1;
  const std::uint32_t v = (raw >> shift) & mask;
  if (scan.pixel_representation == 1 && (v >> (scan.bits_stored - 1)) != 0) {
    return static_cast<std::int32_t>(v) - static_cast<std::int32_t>(std::uint32_t{1} << scan.bits_stored);
  }
  return static_cast<std::int32_t>(v);
}

// The frame's stored samples as bytes in the order `big_endian` says, rows x columns x bytes_per.
// Native pixel data is the file's own bytes; RLE is decoded here; JPEG, JPEG-LS and JPEG 2000 by
// GDCM in a child process (dicom_pixels.hpp says why).
Result<std::vector<std::uint8_t>> stored_samples(const std::string& p, const std::vector<std::uint8_t>& bytes, const DicomScan& scan,
                                              bool& big_endian) {
  const std::size_t need = static_cast<std::size_t>(scan.frame_bytes());
  big_endian = scan.big_endian;
  if (!scan.encapsulated) {
    const auto* f = bytes.data() + scan.pixel_offset;
    return std::vector<std::uint8_t>(f, f + need);  // the scan checked PixelData holds them
  }
  const std::string ts = " (TransferSyntaxUID (0002,0010) " + detail::shown(scan.transfer_syntax) + ")";
  big_endian = false;
  if (scan.transfer_syntax == kRleSyntax) {
    if (scan.fragments != 1) {
      return invalid(p + ": PixelData (7FE0,0010): RLE needs one fragment per frame (PS3.5 Annex G), found " + std::to_string(scan.fragments));
    }
    auto d = decode_rle_frame(std::span(bytes).subspan(scan.first_fragment_offset, scan.first_fragment_length), scan.rows, scan.columns,
                              scan.bits_allocated / 8);
    if (!d) return invalid(p + ": PixelData (7FE0,0010): " + d.error().message + ts);
    return std::move(d).value();
  }
  // The child reads the whole file with GDCM's image reader (which runs the codec even to read the
  // header) and sends back the decoded frame, host byte order.
  auto d = run_isolated(
      [&](std::span<char> out) {
        std::istringstream in(std::string(bytes.begin(), bytes.end()), std::ios::binary);
        gdcm::ImageReader reader;
        reader.SetStream(in);
        if (!reader.Read()) return false;
        const gdcm::Image& image = reader.GetImage();
        if (image.GetDimension(0) != static_cast<unsigned>(scan.columns) || image.GetDimension(1) != static_cast<unsigned>(scan.rows) ||
            image.GetPixelFormat().GetBitsAllocated() != scan.bits_allocated || image.GetPixelFormat().GetSamplesPerPixel() != 1 ||
            image.GetBufferLength() != out.size()) {
          return false;
        }
        return image.GetBuffer(out.data());
      },
      need, kDecodeLimit);
  if (!d) return invalid(p + ": PixelData (7FE0,0010): " + d.error().message + ts);
  return std::vector<std::uint8_t>(d.value().begin(), d.value().end());
}

// Reads one file of the series again and scans those bytes again (the file may have changed since
// the first pass). GDCM parses its header from memory, the bytes before PixelData; the pixels are
// taken by stored_samples.
Result<Slice> read_slice(const Entry& entry, const std::string& series_uid) {
  const std::string p = entry.path.string();
  std::vector<std::uint8_t> bytes;
  const Entry again = scan_file(entry.path, &bytes);
  if (again.scan.status != DicomScanStatus::kImage || again.scan.series_uid != series_uid) {
    return invalid(p + ": changed while the series was read: " + (again.scan.problem.empty() ? "now another series" : again.scan.problem));
  }
  const DicomScan& scan = again.scan;

  // The header alone: the bytes before PixelData's tag (the pixels never reach GDCM here).
  std::istringstream stream(std::string(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(scan.pixel_element_offset)),
                            std::ios::binary);
  gdcm::Reader reader;
  reader.SetStream(stream);
  if (!reader.Read()) {
    return invalid(p + ": GDCM could not read the header, although every element is complete (TransferSyntaxUID (0002,0010) " +
                   detail::shown(scan.transfer_syntax) + ")");
  }
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  gdcm::StringFilter sf;
  sf.SetFile(reader.GetFile());

  Slice s;
  s.path = p;
  s.name = entry.name;
  s.modality = scan.modality;
  s.columns = scan.columns;
  s.rows = scan.rows;
  s.bits_allocated = scan.bits_allocated;
  s.is_signed = scan.pixel_representation == 1;

  auto orientation = numbers<6>(p, field_string(sf, ds, kOrientation), kOrientation, true, {});
  if (!orientation) return orientation.error();
  s.orientation = orientation.value();
  auto position = numbers<3>(p, field_string(sf, ds, kPosition), kPosition, true, {});
  if (!position) return position.error();
  s.position = {position.value()[0], position.value()[1], position.value()[2]};
  auto spacing = numbers<2>(p, field_string(sf, ds, kPixelSpacing), kPixelSpacing, true, {});
  if (!spacing) return spacing.error();
  s.pixel_spacing = spacing.value();
  if (!(s.pixel_spacing[0] > 0 && s.pixel_spacing[1] > 0)) {
    return invalid(p + ": " + tag_name(kPixelSpacing) + ": expected two positive numbers, found " +
                   detail::shown(field_string(sf, ds, kPixelSpacing)));
  }
  auto slope = numbers<1>(p, field_string(sf, ds, kSlope), kSlope, false, {1.0});
  if (!slope) return slope.error();
  auto intercept = numbers<1>(p, field_string(sf, ds, kIntercept), kIntercept, false, {0.0});
  if (!intercept) return intercept.error();
  s.slope = slope.value()[0];
  s.intercept = intercept.value()[0];
  // SliceThickness only guides gap detection: a malformed one is ignored, not fatal.
  if (auto thickness = numbers<1>(p, field_string(sf, ds, kThickness), kThickness, false, {0.0}); thickness && thickness.value()[0] > 0) {
    s.thickness = thickness.value()[0];
  }

  bool big = false;
  auto frame = stored_samples(p, bytes, scan, big);
  if (!frame) return frame.error();
  const std::vector<std::uint8_t>& src = frame.value();
  const std::size_t count = static_cast<std::size_t>(s.columns) * static_cast<std::size_t>(s.rows);
  const bool wide = scan.bits_allocated == 16;
  if (src.size() < count * (wide ? 2 : 1)) {
    return invalid(p + ": PixelData (7FE0,0010): expected " + std::to_string(count * (wide ? 2 : 1)) + " bytes of decoded pixels, found " +
                   std::to_string(src.size()));
  }
  s.values.resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    const std::uint32_t raw = wide ? (big ? (std::uint32_t{src[2 * i]} << 8 | src[2 * i + 1]) : (std::uint32_t{src[2 * i + 1]} << 8 | src[2 * i]))
                                   : std::uint32_t{src[i]};
    s.values[i] = static_cast<float>(sample_value(raw, scan) * s.slope + s.intercept);
  }
  return s;
}

std::string join6(const std::array<double, 6>& a) {
  std::ostringstream s;
  for (std::size_t i = 0; i < a.size(); ++i) s << (i ? "\\" : "") << a[i];
  return s.str();
}

// Everything that shapes the stack must agree with the first slice.
Result<bool> check_one_stack(const std::vector<Slice>& slices) {
  const Slice& first = slices.front();
  for (const Slice& s : slices) {
    if (s.rows != first.rows || s.columns != first.columns) {
      return invalid(first.path + " and " + s.name + " are not one stack: Rows (0028,0010) x Columns (0028,0011) differ: " +
                     std::to_string(first.rows) + " x " + std::to_string(first.columns) + " vs " + std::to_string(s.rows) + " x " +
                     std::to_string(s.columns));
    }
    for (std::size_t k = 0; k < 6; ++k) {
      if (std::abs(s.orientation[k] - first.orientation[k]) > 1e-4) {
        return invalid(first.path + " and " + s.name + " are not one stack: " + tag_name(kOrientation) + " differs: " +
                       join6(first.orientation) + " vs " + join6(s.orientation));
      }
    }
    for (std::size_t k = 0; k < 2; ++k) {
      if (std::abs(s.pixel_spacing[k] - first.pixel_spacing[k]) > 1e-6 * first.pixel_spacing[k] + 1e-9) {
        return invalid(first.path + " and " + s.name + " are not one stack: " + tag_name(kPixelSpacing) + " differs");
      }
    }
    if (s.bits_allocated != first.bits_allocated || s.is_signed != first.is_signed) {
      return invalid(first.path + " and " + s.name +
                     " are not one stack: the pixel type (BitsAllocated (0028,0100) / PixelRepresentation (0028,0103)) differs");
    }
  }
  return true;
}

// ---- gaps ---------------------------------------------------------------------------------------

// The spacing expected at step i (mm): the median of up to two steps on either side; capped by the
// thicker of the two slices' SliceThickness when known (contiguous slices are as far apart as
// they are thick). 0 when nothing says (a two-slice series without SliceThickness).
struct Expected {
  double spacing = 0;           // mm; 0 when nothing says
  bool from_thickness = false;  // SliceThickness set it (it was below the neighbours' median, or there are none)
};

Expected expected_spacing(const std::vector<double>& steps, const std::vector<Slice>& slices, std::size_t i) {
  std::vector<double> around;
  for (std::size_t j = (i >= 2 ? i - 2 : 0); j <= i + 2 && j < steps.size(); ++j) {
    if (j != i) around.push_back(steps[j]);
  }
  Expected e;
  if (!around.empty()) {
    std::sort(around.begin(), around.end());
    const std::size_t m = around.size() / 2;
    e.spacing = around.size() % 2 == 1 ? around[m] : 0.5 * (around[m - 1] + around[m]);
  }
  const double thick = std::max(slices[i].thickness, slices[i + 1].thickness);
  if (thick > 0 && (e.spacing == 0 || thick < e.spacing * (1 - 1e-3))) e = {thick, true};
  return e;
}

struct Gap {
  std::size_t step;     // between slices[step] and slices[step + 1]
  double length;        // mm along the normal
  Expected expected;
};

std::vector<Gap> find_gaps(const std::vector<double>& steps, const std::vector<Slice>& slices) {
  std::vector<Gap> gaps;
  for (std::size_t i = 0; i < steps.size(); ++i) {
    const Expected e = expected_spacing(steps, slices, i);
    if (e.spacing > 0 && steps[i] > kDicomGapRatio * e.spacing) gaps.push_back({i, steps[i], e});
  }
  return gaps;
}

std::string describe(const std::string& directory, const Gap& g, const std::vector<Slice>& slices) {
  std::ostringstream r;
  r.setf(std::ios::fixed);
  r.precision(1);
  r << g.length / g.expected.spacing;
  const std::string expected = g.expected.from_thickness
                                   ? "for slices " + mm(g.expected.spacing) + " thick (" + tag_name(kThickness) + ")"
                                   : "where the slices around it are " + mm(g.expected.spacing) + " apart";
  return directory + ": gap of " + mm(g.length) + " along the slice normal between " + slices[g.step].name + " and " +
         slices[g.step + 1].name + ", " + expected + " (" + r.str() + "x; a missing slice?)";
}

// ---- the volume -----------------------------------------------------------------------------------

// The steps (mm) along the slice normal between consecutive slices, sorted along it; a duplicate
// slice, or (unless kept sheared) a step not along the normal, is an error naming both slices.
Result<std::vector<double>> normal_steps(const std::string& directory, const std::vector<Slice>& slices,
                                         const DicomOptions& options) {
  const Slice& first = slices.front();
  const double tol = options.spacing_tolerance;
  std::vector<double> steps;  // mm along the normal between consecutive slices
  for (std::size_t i = 1; i < slices.size(); ++i) {
    const Vec3 step = slices[i].position - slices[i - 1].position;
    const double along = slices[i].along_normal - slices[i - 1].along_normal;
    if (along <= 1e-3) {
      return invalid(directory + ": " + slices[i - 1].name + " and " + slices[i].name + " have the same " + tag_name(kPosition) +
                     " along the slice normal: duplicate slices are not supported");
    }
    const double length = norm(step);
    const double sine = std::sqrt(std::max(0.0, 1.0 - (along / length) * (along / length)));
    if (sine > tol && !options.shear_tilted) {
      const double degrees = std::asin(std::min(1.0, sine)) * 180.0 / std::numbers::pi;
      std::ostringstream msg;
      msg.setf(std::ios::fixed);
      msg.precision(1);
      msg << directory << ": gantry tilt of " << degrees << " degrees: the step in " << tag_name(kPosition) << " from "
          << slices[i - 1].name << " to " << slices[i].name << " is not parallel to the slice normal (row x column of "
          << tag_name(kOrientation) << " = " << join6(first.orientation) << "); use " << options.names.shear_tilted
          << " to keep the tilt as a sheared slice axis";
      return invalid(msg.str());
    }
    steps.push_back(along);
  }
  return steps;
}

// Resamples the slices along the normal to the smallest step, linearly between the two nearest,
// into v (whose dims and spacing follow).
Result<bool> resample_to_smallest_step(const std::string& directory, const std::vector<Slice>& slices,
                                       const std::vector<double>& steps, double stretch, Volume& v) {
  const std::size_t plane = slices.front().values.size();
  const double step = *std::min_element(steps.begin(), steps.end());
  const double total = slices.back().along_normal - slices.front().along_normal;
  const double nz_real = std::floor(total / step + 1e-6) + 1;
  if (!(nz_real * static_cast<double>(plane) <= static_cast<double>(kMaxVoxels))) {
    return invalid(directory + ": too large after resampling to " + mm(step) + ": " + std::to_string(static_cast<std::uint64_t>(nz_real)) +
                   " slices of " + std::to_string(plane) + " voxels, at most " + std::to_string(kMaxVoxels) + " voxels");
  }
  const auto nz = static_cast<std::size_t>(nz_real);
  v.dims[2] = static_cast<int>(nz);
  v.spacing.z = step * stretch * 1e-3;
  v.data.resize(plane * nz);
  std::size_t seg = 0;
  for (std::size_t k = 0; k < nz; ++k) {
    const double t = slices.front().along_normal + static_cast<double>(k) * step;
    while (seg + 2 < slices.size() && slices[seg + 1].along_normal < t) ++seg;
    const Slice& a = slices[seg];
    const Slice& b = slices[seg + 1];
    const double w = std::clamp((t - a.along_normal) / (b.along_normal - a.along_normal), 0.0, 1.0);
    float* out = v.data.data() + k * plane;
    const auto wf = static_cast<float>(w);
    for (std::size_t i = 0; i < plane; ++i) out[i] = a.values[i] + wf * (b.values[i] - a.values[i]);
  }
  return true;
}


Result<Volume> load(const std::string& directory, const DicomOptions& options, const Progress& progress) {
  auto listing = list_directory(directory);
  if (!listing) return listing.error();

  gdcm::Trace::WarningOff();
  gdcm::Trace::ErrorOff();
  gdcm::Trace::DebugOff();
  // First pass: scan every file (GDCM sees none of them yet).
  const auto& files = listing.value().files;
  std::vector<Entry> entries;
  entries.reserve(files.size());
  for (std::size_t i = 0; i < files.size(); ++i) {
    entries.push_back(scan_file(files[i], nullptr));
    detail::report(progress, 0.3 * static_cast<double>(i + 1) / static_cast<double>(files.size()));
  }
  auto selection = select_series(directory, listing.value(), entries);
  if (!selection) return selection.error();
  Selection& sel = selection.value();

  // Second pass: the series' files through GDCM.
  std::vector<Slice> slices;
  slices.reserve(sel.slices.size());
  for (std::size_t i = 0; i < sel.slices.size(); ++i) {
    auto s = read_slice(*sel.slices[i], sel.series_uid);
    if (!s) return s.error();
    slices.push_back(std::move(s).value());
    detail::report(progress, 0.3 + 0.6 * static_cast<double>(i + 1) / static_cast<double>(sel.slices.size()));
  }
  if (auto one = check_one_stack(slices); !one) return one.error();

  const Slice& first = slices.front();
  const Vec3 row{first.orientation[0], first.orientation[1], first.orientation[2]};
  const Vec3 col{first.orientation[3], first.orientation[4], first.orientation[5]};
  if (std::abs(norm(row) - 1) > 0.01 || std::abs(norm(col) - 1) > 0.01 || std::abs(dot(row, col)) > 0.01) {
    return invalid(first.path + ": " + tag_name(kOrientation) + ": expected two orthogonal unit vectors, found " +
                   join6(first.orientation));
  }
  const Vec3 nr = normalized(row), nc = normalized(col);
  const Vec3 normal = normalized(cross(nr, nc));
  for (Slice& s : slices) s.along_normal = dot(s.position, normal);
  std::stable_sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.along_normal < b.along_normal; });

  const double tol = options.spacing_tolerance;
  auto steps_r = normal_steps(directory, slices, options);
  if (!steps_r) return steps_r.error();
  const std::vector<double>& steps = steps_r.value();

  // The slice axis: the normal, or for a tilted series kept sheared, the direction the slices
  // step along (every slice must lie on that one line through the first; spacings along it are
  // the normal steps / cos tilt).
  Vec3 axis = normal;
  double stretch = 1;  // slice-axis length per mm along the normal
  if (options.shear_tilted && slices.size() >= 2) {
    const Vec3 span = slices.back().position - slices.front().position;
    axis = normalized(span);
    const double cosine = dot(axis, normal);
    if (cosine < 0.5)
      return invalid(directory + ": gantry tilt of more than 60 degrees between " + slices.front().name + " and " + slices.back().name +
                     ": not a tilted stack");
    stretch = 1 / cosine;
    for (const Slice& sl : slices) {
      const Vec3 expected = slices.front().position + axis * ((sl.along_normal - slices.front().along_normal) * stretch);
      const double off = norm(sl.position - expected);
      if (off > 0.1)
        return invalid(directory + ": " + sl.name + " lies " + mm(off) + " off the tilted stack through " + slices.front().name +
                       " and " + slices.back().name + " (" + tag_name(kPosition) + "): the slices do not form one sheared grid");
    }
  }
  Volume v;
  v.dims = {first.columns, first.rows, static_cast<int>(slices.size())};
  v.spacing = {first.pixel_spacing[1] * 1e-3, first.pixel_spacing[0] * 1e-3, steps.empty() ? 1e-3 : steps.front() * stretch * 1e-3};
  v.origin = slices.front().position * 1e-3;
  v.direction = {nr.x, nc.x, axis.x, nr.y, nc.y, axis.y, nr.z, nc.z, axis.z};
  v.source_type = first.bits_allocated == 8 ? (first.is_signed ? VoxelType::kI16 : VoxelType::kU8)
                                             : (first.is_signed ? VoxelType::kI16 : VoxelType::kU16);
  v.modality = first.modality;
  v.value_unit = first.modality == "CT" ? "HU" : "raw";
  v.warnings = std::move(sel.warnings);
  const std::size_t plane = slices.front().values.size();

  // Uneven spacing; a gap (a missing slice) is named as one.
  const std::vector<Gap> gaps = find_gaps(steps, slices);
  std::optional<std::size_t> uneven_at;
  for (std::size_t i = 1; i < steps.size() && !uneven_at; ++i) {
    if (std::abs(steps[i] - steps[0]) > tol * steps[0]) uneven_at = i;
  }
  std::string more_gaps = gaps.size() > 1 ? " (and " + std::to_string(gaps.size() - 1) + " more gap(s))" : "";
  if (!sel.suspects.empty()) {
    // The missing slice may be a file that was skipped: name it where the gap is reported.
    more_gaps += "; skipped file(s) in the folder, perhaps the missing slice: ";
    for (std::size_t i = 0; i < sel.suspects.size() && i < 3; ++i) more_gaps += (i ? "; " : "") + sel.suspects[i];
    if (sel.suspects.size() > 3) more_gaps += "; ...";
  }
  if (uneven_at && !options.resample_uneven) {
    if (!gaps.empty()) {
      return invalid(describe(directory, gaps.front(), slices) + more_gaps + ": slice spacing is uneven; use " +
                     options.names.resample_uneven + " with " + options.names.allow_gaps + " to interpolate across it");
    }
    const std::size_t i = *uneven_at;
    return invalid(directory + ": uneven slice spacing along the normal of " + tag_name(kOrientation) + " (from " + tag_name(kPosition) +
                   "): slice spacing changes from " + mm(steps[0]) + " to " + mm(steps[i]) + " between " + slices[i].name + " and " +
                   slices[i + 1].name + " (use " + options.names.resample_uneven + " to resample to the smallest spacing)");
  }
  if (!gaps.empty() && !options.allow_gaps) {
    if (uneven_at) {
      return invalid(describe(directory, gaps.front(), slices) + more_gaps + ": refusing to interpolate across it (use " +
                     options.names.allow_gaps + " to allow)");
    }
    return invalid(describe(directory, gaps.front(), slices) + more_gaps + " (use " + options.names.allow_gaps +
                   " to load it with that slice spacing)");
  }
  for (const Gap& g : gaps) {
    v.warnings.push_back(describe(directory, g, slices) + (uneven_at ? ": interpolated across" : ": kept as the slice spacing"));
  }

  if (!uneven_at) {
    if (static_cast<std::uint64_t>(plane) * slices.size() > kMaxVoxels) {
      return invalid(directory + ": too large: " + std::to_string(plane * slices.size()) + " voxels, at most " +
                     std::to_string(kMaxVoxels));
    }
    v.data.reserve(plane * slices.size());
    for (const Slice& s : slices) v.data.insert(v.data.end(), s.values.begin(), s.values.end());
    detail::report(progress, 1.0);
    return v;
  }

  if (auto r = resample_to_smallest_step(directory, slices, steps, stretch, v); !r) return r.error();
  detail::report(progress, 1.0);
  return v;
}

}  // namespace

Result<Volume> load_dicom_series(const std::string& directory, const DicomOptions& options, const Progress& progress) {
  return detail::load_catching(directory, [&] { return load(directory, options, progress); });
}

}  // namespace lancet::volume
