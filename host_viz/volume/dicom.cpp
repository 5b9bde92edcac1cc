// DICOM series loader: GDCM reads and decodes each file; this file checks the series is one
// consistent, untilted stack, sorts it along the slice normal and builds the Volume.

#include "volume/dicom.hpp"

#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmPixelFormat.h>
#include <gdcmStringFilter.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>
#include <gdcmTransferSyntax.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "volume/detail/io.hpp"
#include "volume/metaimage.hpp"

namespace lancet::volume {
namespace {

namespace fs = std::filesystem;
using detail::invalid;

struct Field {
  std::uint16_t group, element;
  const char* name;
};

constexpr Field kSeriesUid{0x0020, 0x000E, "SeriesInstanceUID"};
constexpr Field kPosition{0x0020, 0x0032, "ImagePositionPatient"};
constexpr Field kOrientation{0x0020, 0x0037, "ImageOrientationPatient"};
constexpr Field kPixelSpacing{0x0028, 0x0030, "PixelSpacing"};
constexpr Field kIntercept{0x0028, 0x1052, "RescaleIntercept"};
constexpr Field kSlope{0x0028, 0x1053, "RescaleSlope"};

std::string tag_name(const Field& f) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "(%04X,%04X)", static_cast<unsigned>(f.group), static_cast<unsigned>(f.element));
  return std::string(f.name) + " " + buf;
}

std::string mm(double metres) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(2);
  s << metres * 1000.0 << " mm";
  return s.str();
}

struct Slice {
  std::string path;
  std::string name;  // file name only, for messages
  std::string series_uid;
  int columns = 0, rows = 0;
  gdcm::PixelFormat::ScalarType scalar = gdcm::PixelFormat::UNKNOWN;
  std::array<double, 6> orientation{};
  std::array<double, 2> pixel_spacing{};  // mm: row spacing, column spacing
  Vec3 position{};                        // mm
  double slope = 1, intercept = 0;
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

// Reads one file. nullopt = not a DICOM image (skipped); an Error = a DICOM image we cannot use.
Result<std::optional<Slice>> read_slice(const fs::path& file) {
  gdcm::ImageReader reader;
  reader.SetFileName(file.string().c_str());
  if (!reader.Read()) return std::optional<Slice>{};
  const gdcm::Image& image = reader.GetImage();
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  gdcm::StringFilter sf;
  sf.SetFile(reader.GetFile());

  Slice s;
  s.path = file.string();
  s.name = file.filename().string();
  const std::string& p = s.path;
  if (image.GetNumberOfDimensions() == 3 && image.GetDimension(2) > 1) {
    return invalid(p + ": NumberOfFrames (0028,0008): expected 1 (one slice per file), found " +
                   std::to_string(image.GetDimension(2)) + ": multi-frame files are not supported");
  }
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  if (pf.GetSamplesPerPixel() != 1) {
    return invalid(p + ": SamplesPerPixel (0028,0002): expected 1, found " + std::to_string(pf.GetSamplesPerPixel()));
  }
  s.scalar = pf.GetScalarType();
  std::size_t bytes = 0;
  switch (s.scalar) {
    case gdcm::PixelFormat::UINT8:
    case gdcm::PixelFormat::INT8: bytes = 1; break;
    case gdcm::PixelFormat::UINT16:
    case gdcm::PixelFormat::INT16: bytes = 2; break;
    default:
      return invalid(p + ": BitsAllocated (0028,0100) / PixelRepresentation (0028,0103): expected 8- or 16-bit integers, found " +
                     std::string(pf.GetScalarTypeAsString()));
  }
  s.columns = static_cast<int>(image.GetDimension(0));
  s.rows = static_cast<int>(image.GetDimension(1));
  if (s.columns <= 0 || s.rows <= 0) {
    return invalid(p + ": Rows (0028,0010) / Columns (0028,0011): expected positive, found " + std::to_string(s.rows) + " x " +
                   std::to_string(s.columns));
  }
  s.series_uid = field_string(sf, ds, kSeriesUid);

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

  const std::size_t count = static_cast<std::size_t>(s.columns) * static_cast<std::size_t>(s.rows);
  std::vector<char> buffer(image.GetBufferLength());
  if (buffer.size() < count * bytes) {
    return invalid(p + ": PixelData (7FE0,0010): expected at least " + std::to_string(count * bytes) + " bytes, found " +
                   std::to_string(buffer.size()));
  }
  if (!image.GetBuffer(buffer.data())) {
    return invalid(p + ": PixelData (7FE0,0010): GDCM could not decode the pixel data (transfer syntax " +
                   std::string(gdcm::TransferSyntax::GetTSString(image.GetTransferSyntax())) + ")");
  }
  s.values.resize(count);
  const auto* src = reinterpret_cast<const unsigned char*>(buffer.data());
  for (std::size_t i = 0; i < count; ++i) {
    double v = 0;
    switch (s.scalar) {
      case gdcm::PixelFormat::UINT8: v = src[i]; break;
      case gdcm::PixelFormat::INT8: v = detail::load_elem<std::int8_t>(src + i, false); break;
      case gdcm::PixelFormat::UINT16: v = detail::load_elem<std::uint16_t>(src + 2 * i, false); break;
      default: v = detail::load_elem<std::int16_t>(src + 2 * i, false); break;
    }
    s.values[i] = static_cast<float>(v * s.slope + s.intercept);
  }
  return std::optional<Slice>{std::move(s)};
}

std::string mismatch(const Slice& a, const Slice& b, const Field& f, const std::string& va, const std::string& vb) {
  return invalid(a.path + " and " + b.name + " are not one series: " + tag_name(f) + " differs: " + detail::shown(va) +
                 " vs " + detail::shown(vb) + " (put each series in its own directory)")
      .message;
}

std::string join6(const std::array<double, 6>& a) {
  std::ostringstream s;
  for (std::size_t i = 0; i < a.size(); ++i) s << (i ? "\\" : "") << a[i];
  return s.str();
}

Result<Volume> load(const std::string& directory, const DicomOptions& options, const Progress& progress) {
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) {
    return Error{ErrorCode::kNotFound, directory + ": cannot open the DICOM series: not a directory"};
  }
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(directory)) {
    if (entry.is_regular_file()) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) return invalid(directory + ": no DICOM files: the directory contains no files");

  gdcm::Trace::WarningOff();
  gdcm::Trace::ErrorOff();
  std::vector<Slice> slices;
  std::vector<std::string> skipped;
  for (std::size_t i = 0; i < files.size(); ++i) {
    auto r = read_slice(files[i]);
    if (!r) return r.error();
    if (r.value()) {
      slices.push_back(std::move(*r.value()));
    } else {
      skipped.push_back(files[i].filename().string());
    }
    detail::report(progress, 0.9 * static_cast<double>(i + 1) / static_cast<double>(files.size()));
  }
  if (slices.empty()) {
    std::string names;
    for (std::size_t i = 0; i < skipped.size() && i < 5; ++i) names += (i ? ", " : "") + skipped[i];
    if (skipped.size() > 5) names += ", ...";
    return invalid(directory + ": no DICOM image files: " + std::to_string(skipped.size()) +
                   " file(s) are not DICOM images with pixel data (" + names + ")");
  }

  // One series: everything that shapes the stack must agree with the first slice.
  const Slice& first = slices.front();
  for (const Slice& s : slices) {
    if (s.series_uid != first.series_uid) return invalid(mismatch(first, s, kSeriesUid, first.series_uid, s.series_uid));
    if (s.rows != first.rows || s.columns != first.columns) {
      return invalid(first.path + " and " + s.name + " are not one series: Rows (0028,0010) x Columns (0028,0011) differ: " +
                     std::to_string(first.rows) + " x " + std::to_string(first.columns) + " vs " + std::to_string(s.rows) +
                     " x " + std::to_string(s.columns));
    }
    for (std::size_t k = 0; k < 6; ++k) {
      if (std::abs(s.orientation[k] - first.orientation[k]) > 1e-4) {
        return invalid(mismatch(first, s, kOrientation, join6(first.orientation), join6(s.orientation)));
      }
    }
    for (std::size_t k = 0; k < 2; ++k) {
      if (std::abs(s.pixel_spacing[k] - first.pixel_spacing[k]) > 1e-6 * first.pixel_spacing[k] + 1e-9) {
        return invalid(first.path + " and " + s.name + " are not one series: " + tag_name(kPixelSpacing) + " differs");
      }
    }
    if (s.scalar != first.scalar) {
      return invalid(first.path + " and " + s.name +
                     " are not one series: the pixel type (BitsAllocated (0028,0100) / PixelRepresentation (0028,0103)) differs");
    }
  }

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
  std::vector<double> gaps;  // mm along the normal between consecutive slices
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
          << tag_name(kOrientation) << " = " << join6(first.orientation)
          << "); set DicomOptions::shear_tilted to keep the tilt as a sheared slice axis";
      return invalid(msg.str());
    }
    gaps.push_back(along);
  }

  // The slice axis: the normal, or for a tilted series kept sheared, the direction the slices
  // step along (every slice must lie on that one line through the first; spacings along it are
  // the normal gaps / cos tilt).
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
        return invalid(directory + ": " + sl.name + " lies " + mm(off * 1e-3) + " off the tilted stack through " + slices.front().name +
                       " and " + slices.back().name + " (" + tag_name(kPosition) + "): the slices do not form one sheared grid");
    }
  }
  Volume v;
  v.dims = {first.columns, first.rows, static_cast<int>(slices.size())};
  v.spacing = {first.pixel_spacing[1] * 1e-3, first.pixel_spacing[0] * 1e-3, gaps.empty() ? 1e-3 : gaps.front() * stretch * 1e-3};
  v.origin = slices.front().position * 1e-3;
  v.direction = {nr.x, nc.x, axis.x, nr.y, nc.y, axis.y, nr.z, nc.z, axis.z};
  switch (first.scalar) {
    case gdcm::PixelFormat::UINT8: v.source_type = VoxelType::kU8; break;
    case gdcm::PixelFormat::UINT16: v.source_type = VoxelType::kU16; break;
    default: v.source_type = VoxelType::kI16; break;
  }
  v.value_unit = "HU";
  const std::size_t plane = slices.front().values.size();

  bool uneven = false;
  for (std::size_t i = 1; i < gaps.size(); ++i) {
    if (std::abs(gaps[i] - gaps[0]) > tol * gaps[0]) {
      if (!options.resample_uneven) {
        return invalid(directory + ": uneven slice spacing along the normal of " + tag_name(kOrientation) + " (from " +
                       tag_name(kPosition) + "): slice spacing changes from " + mm(gaps[0] * 1e-3) + " to " +
                       mm(gaps[i] * 1e-3) + " between " + slices[i].name + " and " + slices[i + 1].name +
                       " (set DicomOptions::resample_uneven to resample to the smallest spacing)");
      }
      uneven = true;
    }
  }

  if (!uneven) {
    if (static_cast<std::uint64_t>(plane) * slices.size() > kMaxVoxels) {
      return invalid(directory + ": too large: " + std::to_string(plane * slices.size()) + " voxels, at most " +
                     std::to_string(kMaxVoxels));
    }
    v.data.reserve(plane * slices.size());
    for (const Slice& s : slices) v.data.insert(v.data.end(), s.values.begin(), s.values.end());
    detail::report(progress, 1.0);
    return v;
  }

  // Resample along the normal to the smallest spacing, linear between the two nearest slices.
  const double step = *std::min_element(gaps.begin(), gaps.end());
  const double total = slices.back().along_normal - slices.front().along_normal;
  const auto nz = static_cast<std::size_t>(std::floor(total / step + 1e-6)) + 1;
  if (static_cast<std::uint64_t>(plane) * nz > kMaxVoxels) {
    return invalid(directory + ": too large after resampling: " + std::to_string(plane * nz) + " voxels, at most " +
                   std::to_string(kMaxVoxels));
  }
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
  detail::report(progress, 1.0);
  return v;
}

}  // namespace

Result<Volume> load_dicom_series(const std::string& directory, const DicomOptions& options, const Progress& progress) {
  return detail::load_catching(directory, [&] { return load(directory, options, progress); });
}

}  // namespace lancet::volume
