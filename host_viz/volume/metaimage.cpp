#include "volume/metaimage.hpp"
#include "volume/detail/header_fields.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

namespace lancet::volume {
namespace {

using namespace detail;  // the helpers shared by the loaders

// The header is text and small; anything longer is not a MetaImage header.
constexpr std::size_t kMaxHeaderBytes = 1 << 20;
// Progress is reported once per chunk, so a large volume gives a few dozen calls.

constexpr ElemInfo kElems[] = {
    {"MET_UCHAR", Elem::kU8, 1, VoxelType::kU8},    {"MET_CHAR", Elem::kI8, 1, VoxelType::kI16},
    {"MET_SHORT", Elem::kI16, 2, VoxelType::kI16},  {"MET_USHORT", Elem::kU16, 2, VoxelType::kU16},
    {"MET_INT", Elem::kI32, 4, VoxelType::kF32},    {"MET_UINT", Elem::kU32, 4, VoxelType::kF32},
    {"MET_FLOAT", Elem::kF32, 4, VoxelType::kF32},  {"MET_DOUBLE", Elem::kF64, 8, VoxelType::kF32},
};

// Where and how the voxels are stored, once the header is understood.
struct Layout {
  std::array<int, 3> dims{};
  ElemInfo elem = kElems[0];
  bool big_endian = false;
  bool compressed = false;
  std::optional<std::uint64_t> compressed_size;
  std::int64_t header_size = 0;  // bytes to skip before the data; -1: data at the end
  std::string data_path;
  std::uint64_t data_start = 0;  // offset in data_path where the data (or the HeaderSize skip) begins
  bool attached = false;         // data_path is the header file itself (LOCAL)
  bool headerless = false;       // load_raw: no header, so messages speak of dims, not DimSize
};

std::uint64_t voxel_count(const std::array<int, 3>& d) {
  return static_cast<std::uint64_t>(d[0]) * static_cast<std::uint64_t>(d[1]) * static_cast<std::uint64_t>(d[2]);
}

// Reads `count` bytes at `offset` of `path`, reporting progress from p0 to p1.
Result<std::vector<unsigned char>> read_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count,
                                              const Progress& progress, double p0, double p1) {
  std::vector<unsigned char> out;
  auto r = append_file_bytes(path, offset, count, out, progress, p0, p1);
  if (!r) return r.error();
  return out;
}

// Reads the voxel bytes described by `layout` (raw or compressed), checking every size against
// the real file before allocating.
Result<std::vector<unsigned char>> read_voxel_bytes(const std::string& header_path, const Layout& layout,
                                                    const Progress& progress) {
  const std::uint64_t expected = voxel_count(layout.dims) * layout.elem.bytes;
  auto size_r = file_size(layout.data_path);
  if (!size_r) {
    Error e = size_r.error();
    if (layout.data_path != header_path) e.message = header_path + ": ElementDataFile: " + e.message;
    return e;
  }
  const std::uint64_t size = size_r.value();
  if (layout.data_start > size) return invalid(layout.data_path + ": data offset beyond the end of the file");
  const std::uint64_t after_header = size - layout.data_start;
  const std::string where = layout.attached ? header_path + " (data after the header)" : layout.data_path;

  if (!layout.compressed) {
    std::uint64_t offset = 0;
    if (layout.header_size == -1) {
      if (after_header < expected) {
        return invalid(where + ": truncated data: expected " + std::to_string(expected) +
                       " bytes (DimSize × element size) at the end of the file, found " + std::to_string(after_header));
      }
      offset = size - expected;
    } else {
      const auto skip = static_cast<std::uint64_t>(layout.header_size);
      if (skip > after_header) {
        return invalid(where + ": HeaderSize: expected at most " + std::to_string(after_header) + " bytes to skip, found " +
                       std::to_string(skip));
      }
      const std::uint64_t found = after_header - skip;
      if (found != expected) {
        const std::string dims = std::to_string(layout.dims[0]) + "×" + std::to_string(layout.dims[1]) + "×" + std::to_string(layout.dims[2]);
        return invalid(where + ": data size mismatch: expected " + std::to_string(expected) + " bytes (" +
                       (layout.headerless ? dims + " voxels × " + std::to_string(layout.elem.bytes) + " byte(s) each"
                                          : "DimSize " + dims + " × " + std::to_string(layout.elem.bytes) + " bytes of " + layout.elem.name) +
                       "), found " + std::to_string(found));
      }
      offset = layout.data_start + skip;
    }
    return read_bytes(layout.data_path, offset, expected, progress, 0.0, 0.5);
  }

  // Compressed: HeaderSize bytes (if any) come before the stream; -1 makes no sense here.
  if (layout.header_size == -1) {
    return invalid(header_path + ": HeaderSize: expected >= 0 with CompressedData = True, found -1");
  }
  const auto skip = static_cast<std::uint64_t>(layout.header_size);
  if (skip > after_header) {
    return invalid(where + ": HeaderSize: expected at most " + std::to_string(after_header) + " bytes to skip, found " +
                   std::to_string(skip));
  }
  const std::uint64_t available = after_header - skip;
  std::uint64_t csize = available;
  if (layout.compressed_size) {
    if (*layout.compressed_size > available) {
      return invalid(where + ": CompressedDataSize: expected at most the " + std::to_string(available) +
                     " bytes left in the file, found " + std::to_string(*layout.compressed_size));
    }
    csize = *layout.compressed_size;
  }
  if (csize == 0) return invalid(where + ": CompressedData: no compressed data in the file");
  auto compressed = read_bytes(layout.data_path, layout.data_start + skip, csize, progress, 0.0, 0.1);
  if (!compressed) return compressed.error();
  std::vector<unsigned char> out;
  constexpr StreamWords kWords{"CompressedData", "zlib", "DimSize × element size"};
  auto z = inflate_exact(where, kWords, compressed.value(), expected, out, progress, 0.1, 0.5);
  if (!z) return z.error();
  return out;
}

Result<Layout> parse_header(HeaderFields& header, const std::string& text, std::size_t& data_start, bool& found_data_line) {
  const std::string& path = header.path();
  std::size_t pos = 0;
  int line_no = 0;
  found_data_line = false;
  while (pos < text.size()) {
    std::size_t end = text.find('\n', pos);
    const bool last = end == std::string::npos;
    if (last) end = text.size();
    const std::string_view line(text.data() + pos, end - pos);
    ++line_no;
    pos = last ? end : end + 1;
    const std::string_view t = trim(line);
    if (t.empty()) continue;
    const std::size_t eq = t.find('=');
    if (eq == std::string_view::npos) {
      return invalid(path + ":" + std::to_string(line_no) + ": expected a header line 'Key = value' (a header ends with 'ElementDataFile = ...'), found " +
                     shown(t));
    }
    const std::string_view key = trim(t.substr(0, eq));
    const std::string_view value = trim(t.substr(eq + 1));
    if (key.empty()) {
      return invalid(path + ":" + std::to_string(line_no) + ": expected a field name before '=', found " + shown(t));
    }
    header.set(HeaderField{std::string(key), std::string(value), line_no});
    if (lower(key) == "elementdatafile") {
      found_data_line = true;
      data_start = pos;
      break;
    }
  }
  return Layout{};
}

Result<std::array<int, 3>> check_dims(const std::string& what, std::array<int, 3> dims) {
  for (int d : dims) {
    if (d <= 0) {
      return invalid(what + ": expected 3 positive sizes, found " + std::to_string(dims[0]) + " " +
                     std::to_string(dims[1]) + " " + std::to_string(dims[2]));
    }
  }
  if (voxel_count(dims) > kMaxVoxels) {
    return invalid(what + ": expected at most " + std::to_string(kMaxVoxels) + " voxels, found " +
                   std::to_string(voxel_count(dims)));
  }
  return dims;
}

// The element layout: dimensions, element type, byte order, compression, header size.
Result<Layout> read_layout(const HeaderFields& h, std::uint64_t size) {
  Layout layout;
  if (const auto* f = h.find({"ObjectType"}); f && lower(trim(f->value)) != "image") {
    return h.error(*f, "Image");
  }
  const auto* ndims_f = h.find({"NDims"});
  if (!ndims_f) return h.missing("NDims", "NDims = 3");
  {
    auto n = h.integer(*ndims_f, 1, 1000);
    if (!n) return n.error();
    if (n.value() != 3) {
      return h.error(*ndims_f, "3 (only 3-D volumes are supported" +
                                         std::string(n.value() == 2 ? "; a 2-D image is not a volume)" : ")"));
    }
  }
  if (const auto* f = h.find({"ElementNumberOfChannels"})) {
    auto n = h.integer(*f, 1, std::numeric_limits<int>::max());
    if (!n) return n.error();
    if (n.value() != 1) return h.error(*f, "1 (only single-channel scalar volumes are supported)");
  }
  if (const auto* f = h.find({"BinaryData"})) {
    auto b = h.boolean(*f);
    if (!b) return b.error();
    if (!b.value()) return h.error(*f, "True (ASCII voxel data is not supported)");
  }

  const auto* dim_f = h.find({"DimSize"});
  if (!dim_f) return h.missing("DimSize", "DimSize = nx ny nz");
  {
    auto dims = h.sizes(*dim_f, kMaxVoxels);
    if (!dims) return dims.error();
    layout.dims = dims.value();
  }

  const auto* type_f = h.find({"ElementType"});
  if (!type_f) return h.missing("ElementType", "ElementType = MET_...");
  {
    const std::string_view name = trim(type_f->value);
    bool known = false;
    for (const ElemInfo& e : kElems) {
      if (name == e.name) {
        layout.elem = e;
        known = true;
      }
    }
    if (!known) {
      return h.error(*type_f, "one of MET_UCHAR, MET_CHAR, MET_SHORT, MET_USHORT, MET_INT, MET_UINT, MET_FLOAT, MET_DOUBLE");
    }
  }

  // Byte order: either field may say big-endian; if both are present they must agree.
  std::optional<bool> msb;
  for (const char* key : {"ElementByteOrderMSB", "BinaryDataByteOrderMSB"}) {
    if (const auto* f = h.find({key})) {
      auto b = h.boolean(*f);
      if (!b) return b.error();
      if (msb && *msb != b.value()) {
        return h.error(*f, std::string(*msb ? "True" : "False") + " (the other byte-order field says so)");
      }
      msb = b.value();
    }
  }
  layout.big_endian = msb.value_or(false);

  if (const auto* f = h.find({"CompressedData"})) {
    auto b = h.boolean(*f);
    if (!b) return b.error();
    layout.compressed = b.value();
  }
  if (const auto* f = h.find({"CompressedDataSize"})) {
    auto n = h.integer(*f, 1, std::numeric_limits<std::int64_t>::max());
    if (!n) return n.error();
    if (static_cast<std::uint64_t>(n.value()) > size) {
      return h.error(*f, "at most the file size (" + std::to_string(size) + " bytes)");
    }
    layout.compressed_size = static_cast<std::uint64_t>(n.value());
  }
  if (const auto* f = h.find({"HeaderSize"})) {
    auto n = h.integer(*f, -1, std::numeric_limits<std::int64_t>::max());
    if (!n) return n.error();
    layout.header_size = n.value();
  }

  return layout;
}

// Spacing, origin, directions, orientation and modality (mm in the file, metres in the Volume).
Result<bool> read_geometry(const HeaderFields& h, MetaImage& out) {
  Volume& v = out.volume;
  constexpr double kMm = 1e-3;
  if (const auto* f = h.find({"ElementSpacing", "ElementSize"})) {
    auto s = h.numbers(*f, 3, true);
    if (!s) return s.error();
    v.spacing = Vec3{s.value()[0] * kMm, s.value()[1] * kMm, s.value()[2] * kMm};
  } else {
    v.spacing = Vec3{kMm, kMm, kMm};
  }
  if (const auto* f = h.find({"Offset", "Position", "Origin"})) {
    auto o = h.numbers(*f, 3, false);
    if (!o) return o.error();
    v.origin = Vec3{o.value()[0] * kMm, o.value()[1] * kMm, o.value()[2] * kMm};
  }
  if (const auto* f = h.find({"TransformMatrix", "Orientation", "Rotation"})) {
    auto m = h.numbers(*f, 9, false);
    if (!m) return m.error();
    const auto& t = m.value();
    // File group k (numbers 3k..3k+2) is axis k's world direction = column k of Volume::direction.
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) v.direction[static_cast<std::size_t>(r * 3 + c)] = t[static_cast<std::size_t>(c * 3 + r)];
    }
    if (!(std::abs(determinant3(v.direction)) > 1e-6)) return h.error(*f, "an invertible 3×3 direction matrix");
  }
  if (const auto* f = h.find({"AnatomicalOrientation"})) out.anatomical_orientation = std::string(trim(f->value));
  if (const auto* f = h.find({"Modality"})) {
    static constexpr std::pair<std::string_view, std::string_view> kModalities[] = {
        {"MET_MOD_CT", "CT"}, {"MET_MOD_MR", "MR"}, {"MET_MOD_NM", "NM"}, {"MET_MOD_US", "US"}, {"MET_MOD_OTHER", ""}, {"MET_MOD_UNKNOWN", ""}};
    const std::string_view m = trim(f->value);
    const auto* it = std::find_if(std::begin(kModalities), std::end(kModalities), [&](const auto& e) { return e.first == m; });
    if (it == std::end(kModalities)) {
      return h.error(*f, "one of MET_MOD_CT, MET_MOD_MR, MET_MOD_NM, MET_MOD_US, MET_MOD_OTHER, MET_MOD_UNKNOWN");
    }
    v.modality = std::string(it->second);
    if (v.modality == "CT") v.value_unit = "HU";
  }

  return true;
}

Result<MetaImage> load(const std::string& path, const Progress& progress) {
  auto size_r = file_size(path);
  if (!size_r) return size_r.error();
  const std::uint64_t size = size_r.value();

  auto header = read_header_text(path, size, kMaxHeaderBytes);
  if (!header) return header.error();
  std::string text = std::move(header).value();
  HeaderFields h(path);
  std::size_t data_start = 0;
  bool found_data_line = false;
  {
    auto r = parse_header(h, text, data_start, found_data_line);
    if (!r) return r.error();
  }
  if (!found_data_line) {
    return invalid(path + ": ElementDataFile: expected a line 'ElementDataFile = LOCAL' or '= <file>' within the first " +
                   std::to_string(kMaxHeaderBytes) + " bytes, found none");
  }

  auto layout_r = read_layout(h, size);
  if (!layout_r) return layout_r.error();
  Layout layout = std::move(layout_r).value();

  MetaImage out;
  Volume& v = out.volume;
  v.dims = layout.dims;
  v.source_type = layout.elem.nearest;
  v.value_unit = "raw";
  if (auto g = read_geometry(h, out); !g) return g.error();

  // Where the data is.
  const auto* file_f = h.find({"ElementDataFile"});
  const std::string data_file(trim(file_f->value));
  if (data_file == "LOCAL" || data_file == "local") {
    layout.data_path = path;
    layout.data_start = data_start;
    layout.attached = true;
  } else if (data_file.empty()) {
    return h.error(*file_f, "LOCAL or a file name");
  } else if (lower(data_file).rfind("list", 0) == 0 || data_file.find('%') != std::string::npos) {
    return h.error(*file_f, "LOCAL or a single data file (file lists and patterns are not supported)");
  } else {
    std::filesystem::path p(data_file);
    if (p.is_relative()) p = std::filesystem::path(header_dir(path)) / p;
    layout.data_path = p.string();
    layout.data_start = 0;
  }

  auto bytes = read_voxel_bytes(path, layout, progress);
  if (!bytes) return bytes.error();
  v.data = convert(bytes.value(), layout.elem, layout.big_endian, v.voxel_count(), progress, 0.5, 1.0);
  return out;
}

}  // namespace

Result<MetaImage> load_metaimage_with_info(const std::string& path, const Progress& progress) {
  return detail::load_catching(path, [&] { return load(path, progress); });
}

Result<Volume> load_metaimage(const std::string& path, const Progress& progress) {
  auto r = load_metaimage_with_info(path, progress);
  if (!r) return r.error();
  return std::move(r.value().volume);
}

Result<Volume> load_raw(const std::string& path, std::array<int, 3> dims, VoxelType type, Vec3 spacing_m,
                        bool big_endian, const Progress& progress) {
  try {
    auto d = check_dims(path + ": dims", dims);
    if (!d) return d.error();
    if (!(spacing_m.x > 0 && spacing_m.y > 0 && spacing_m.z > 0) || !is_finite(spacing_m)) {
      return invalid(path + ": spacing: expected 3 positive finite lengths (m), found " + std::to_string(spacing_m.x) +
                     " " + std::to_string(spacing_m.y) + " " + std::to_string(spacing_m.z));
    }
    Layout layout;
    layout.dims = dims;
    switch (type) {
      case VoxelType::kU8: layout.elem = kElems[0]; break;
      case VoxelType::kI16: layout.elem = kElems[2]; break;
      case VoxelType::kU16: layout.elem = kElems[3]; break;
      case VoxelType::kF32: layout.elem = kElems[6]; break;
    }
    layout.big_endian = big_endian;
    layout.data_path = path;
    layout.headerless = true;
    auto bytes = read_voxel_bytes(path, layout, progress);
    if (!bytes) return bytes.error();
    Volume v;
    v.dims = dims;
    v.spacing = spacing_m;
    v.source_type = type;
    v.value_unit = "raw";
    v.data = convert(bytes.value(), layout.elem, big_endian, v.voxel_count(), progress, 0.5, 1.0);
    return v;
  } catch (const std::bad_alloc&) {
    return Error{ErrorCode::kSystem, path + ": out of memory while loading the volume"};
  }
}

}  // namespace lancet::volume
