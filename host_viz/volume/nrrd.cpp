#include "volume/nrrd.hpp"
#include "volume/detail/io.hpp"

#include <zlib.h>

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "volume/metaimage.hpp"  // kMaxVoxels

namespace lancet::volume {
namespace {

using namespace detail;  // the helpers shared by the loaders

// Text, file and conversion helpers are shared with metaimage.cpp (volume/detail/io.hpp). NRRD's
// inflation appends to a buffer (several gzip files make one volume), unlike MetaImage's.

constexpr std::size_t kMaxHeaderBytes = 1 << 20;
constexpr double kMm = 1e-3;

struct TypeName {
  const char* spelling;
  ElemInfo info;
};

constexpr ElemInfo kU8{"uchar", Elem::kU8, 1, VoxelType::kU8};
constexpr ElemInfo kI8{"signed char", Elem::kI8, 1, VoxelType::kI16};
constexpr ElemInfo kI16{"short", Elem::kI16, 2, VoxelType::kI16};
constexpr ElemInfo kU16{"ushort", Elem::kU16, 2, VoxelType::kU16};
constexpr ElemInfo kI32{"int", Elem::kI32, 4, VoxelType::kF32};
constexpr ElemInfo kU32{"uint", Elem::kU32, 4, VoxelType::kF32};
constexpr ElemInfo kF32{"float", Elem::kF32, 4, VoxelType::kF32};
constexpr ElemInfo kF64{"double", Elem::kF64, 8, VoxelType::kF32};

constexpr TypeName kTypes[] = {
    {"uchar", kU8},          {"unsigned char", kU8},      {"uint8", kU8},
    {"uint8_t", kU8},        {"signed char", kI8},        {"int8", kI8},
    {"int8_t", kI8},         {"short", kI16},             {"short int", kI16},
    {"signed short", kI16},  {"signed short int", kI16},  {"int16", kI16},
    {"int16_t", kI16},       {"ushort", kU16},            {"unsigned short", kU16},
    {"unsigned short int", kU16}, {"uint16", kU16},       {"uint16_t", kU16},
    {"int", kI32},           {"signed int", kI32},        {"int32", kI32},
    {"int32_t", kI32},       {"uint", kU32},              {"unsigned int", kU32},
    {"uint32", kU32},        {"uint32_t", kU32},          {"float", kF32},
    {"double", kF64},
};

// Fields that describe the data but do not change how it is read; accepted and ignored.
constexpr std::string_view kIgnored[] = {
    "content",   "kinds",     "centers",      "centerings",   "labels",     "units",     "min",
    "max",       "old min",   "oldmin",       "old max",      "oldmax",     "thicknesses", "axis mins",
    "axismins",  "axis maxs", "axismaxs",     "sample units", "sampleunits", "measurement frame",
    "number",    "space units", "spaceunits", "dimension",    "type",       "sizes",     "encoding",
    "endian",    "spacings",  "space directions", "space origin", "space", "space dimension",
    "byte skip", "byteskip",  "line skip",    "lineskip",     "data file",  "datafile",  "block size",
    "blocksize",
};

// Appends `count` bytes at `offset` of `path` to `out`; the caller has checked the file holds them.
Result<bool> append_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count,
                          std::vector<unsigned char>& out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{ErrorCode::kNotFound, path + ": cannot open for reading"};
  in.seekg(static_cast<std::streamoff>(offset));
  if (!in) return invalid(path + ": cannot seek to byte " + std::to_string(offset));
  const std::size_t at = out.size();
  out.resize(at + static_cast<std::size_t>(count));
  in.read(reinterpret_cast<char*>(out.data() + at), static_cast<std::streamsize>(count));
  if (static_cast<std::uint64_t>(in.gcount()) != count) {
    return invalid(path + ": truncated data: expected " + std::to_string(count) + " bytes from byte " +
                   std::to_string(offset) + ", found " + std::to_string(in.gcount()));
  }
  return true;
}

// Offset just after the first `lines` newline characters of the file, or nullopt if it has fewer.
std::optional<std::uint64_t> after_lines(const std::string& path, std::uint64_t start, std::int64_t lines) {
  if (lines == 0) return start;
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  in.seekg(static_cast<std::streamoff>(start));
  std::uint64_t pos = start;
  std::int64_t seen = 0;
  char buf[65536];
  while (in) {
    in.read(buf, sizeof buf);
    const auto n = static_cast<std::size_t>(in.gcount());
    for (std::size_t i = 0; i < n; ++i) {
      if (buf[i] == '\n' && ++seen == lines) return pos + i + 1;
    }
    pos += n;
    if (n == 0) break;
  }
  return std::nullopt;
}

// Inflates a gzip (or zlib) stream into exactly `expected` bytes appended to `out`. The output
// grows only as data really comes out, so a tiny file that claims a huge image allocates nothing big.
Result<bool> inflate_exact(const std::string& where, const std::vector<unsigned char>& in, std::uint64_t expected,
                           std::vector<unsigned char>& out) {
  z_stream zs{};
  if (inflateInit2(&zs, 15 + 32) != Z_OK) return Error{ErrorCode::kSystem, where + ": zlib inflateInit failed"};
  constexpr std::size_t kMaxStep = 1u << 30;
  const std::size_t base = out.size();
  std::size_t in_pos = 0;
  std::uint64_t produced = 0;
  int rc = Z_OK;
  auto feed = [&] {
    if (zs.avail_in == 0 && in_pos < in.size()) {
      const std::size_t n = std::min(kMaxStep, in.size() - in_pos);
      zs.next_in = const_cast<Bytef*>(in.data() + in_pos);  // zlib's API is not const; it only reads
      zs.avail_in = static_cast<uInt>(n);
      in_pos += n;
    }
  };
  while (produced < expected) {
    if (base + produced == out.size()) {
      const std::uint64_t grow = std::min<std::uint64_t>(expected - produced, std::max<std::uint64_t>(produced, kMinChunk));
      out.resize(out.size() + static_cast<std::size_t>(grow));
    }
    feed();
    const std::size_t room = std::min<std::size_t>(kMaxStep, out.size() - base - static_cast<std::size_t>(produced));
    zs.next_out = out.data() + base + produced;
    zs.avail_out = static_cast<uInt>(room);
    rc = inflate(&zs, Z_NO_FLUSH);
    produced += room - zs.avail_out;
    if (rc == Z_STREAM_END) break;
    if (rc == Z_BUF_ERROR && zs.avail_in == 0 && in_pos >= in.size()) break;
    if (rc != Z_OK && rc != Z_BUF_ERROR) break;
  }
  bool more = false;
  if (produced == expected && rc != Z_STREAM_END && rc != Z_DATA_ERROR) {
    unsigned char extra = 0;
    zs.next_out = &extra;
    zs.avail_out = 1;
    feed();
    rc = inflate(&zs, Z_NO_FLUSH);
    more = zs.avail_out == 0;
  }
  const std::string msg = zs.msg != nullptr ? zs.msg : "";
  inflateEnd(&zs);
  out.resize(base + static_cast<std::size_t>(produced));
  if (rc == Z_DATA_ERROR || rc == Z_NEED_DICT || rc == Z_MEM_ERROR || rc == Z_STREAM_ERROR) {
    return invalid(where + ": encoding: corrupt gzip stream after " + std::to_string(produced) + " of " +
                   std::to_string(expected) + " expected bytes" + (msg.empty() ? "" : " (" + msg + ")"));
  }
  if (more) {
    return invalid(where + ": encoding: the gzip stream holds more than the expected " + std::to_string(expected) +
                   " bytes (sizes × element size + byte skip)");
  }
  if (produced != expected) {
    return invalid(where + ": encoding: truncated gzip stream: expected " + std::to_string(expected) +
                   " bytes (sizes × element size + byte skip), found " + std::to_string(produced));
  }
  return true;
}

// ---- header ---------------------------------------------------------------------------------

struct Field {
  std::string name;  // as written
  std::string value;
  int line = 0;
};

class Header {
 public:
  explicit Header(std::string path) : path_(std::move(path)) {}
  const std::string& path() const { return path_; }
  std::map<std::string, Field>& fields() { return fields_; }

  const Field* find(std::initializer_list<std::string_view> keys) const {
    for (std::string_view k : keys) {
      const auto it = fields_.find(std::string(k));
      if (it != fields_.end()) return &it->second;
    }
    return nullptr;
  }
  Error error(const Field& f, const std::string& expected) const {
    return invalid(path_ + ":" + std::to_string(f.line) + ": " + f.name + ": expected " + expected + ", found " +
                   shown(f.value));
  }
  Error missing(const std::string& name, const std::string& example) const {
    return invalid(path_ + ": " + name + ": expected a line '" + example + "', found none");
  }
  Result<std::int64_t> integer(const Field& f, std::int64_t lo, std::int64_t hi) const {
    const auto words = split_words(f.value);
    const std::string expected = "an integer in " + std::to_string(lo) + ".." + std::to_string(hi);
    if (words.size() != 1) return error(f, expected);
    const auto v = parse_int(words[0]);
    if (!v || *v < lo || *v > hi) return error(f, expected);
    return *v;
  }

 private:
  std::string path_;
  std::map<std::string, Field> fields_;  // lower-case name → field
};

// Parses "(a,b,c) (d,e,f) ..." into `n` 3-vectors; nullopt on any deviation.
std::optional<std::vector<std::array<double, 3>>> parse_vectors(std::string_view s, std::size_t n) {
  std::vector<std::array<double, 3>> out;
  std::size_t i = 0;
  while (true) {
    while (i < s.size() && (s[i] == ' ' || s[i] == '\t')) ++i;
    if (i == s.size()) break;
    if (s[i] != '(') return std::nullopt;
    const std::size_t close = s.find(')', i);
    if (close == std::string_view::npos) return std::nullopt;
    std::string_view inner = s.substr(i + 1, close - i - 1);
    std::array<double, 3> v{};
    for (std::size_t c = 0; c < 3; ++c) {
      const std::size_t comma = c < 2 ? inner.find(',') : inner.size();
      if (comma == std::string_view::npos) return std::nullopt;
      const auto d = parse_double(trim(inner.substr(0, comma)));
      if (!d || !std::isfinite(*d)) return std::nullopt;
      v[c] = *d;
      inner = c < 2 ? inner.substr(comma + 1) : std::string_view{};
    }
    out.push_back(v);
    if (out.size() > n) return std::nullopt;
    i = close + 1;
  }
  if (out.size() != n) return std::nullopt;
  return out;
}

// A printf pattern with exactly one integer conversion (%d, %i, %u with optional 0 flag and width).
struct Pattern {
  std::string prefix, suffix;
  bool zero = false;
  int width = 0;
  std::string format(std::int64_t v) const {
    std::string digits = std::to_string(v < 0 ? -v : v);
    const std::size_t body = digits.size() + (v < 0 ? 1 : 0);
    const std::size_t pad = static_cast<std::size_t>(width) > body ? static_cast<std::size_t>(width) - body : 0;
    std::string num = zero ? (v < 0 ? "-" : "") + std::string(pad, '0') + digits
                           : std::string(pad, ' ') + (v < 0 ? "-" : "") + digits;
    return prefix + num + suffix;
  }
};

std::optional<Pattern> parse_pattern(std::string_view s) {
  Pattern p;
  bool found = false;
  std::string* part = &p.prefix;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '%') {
      *part += s[i];
      continue;
    }
    if (i + 1 < s.size() && s[i + 1] == '%') {
      *part += '%';
      ++i;
      continue;
    }
    if (found) return std::nullopt;
    found = true;
    ++i;
    if (i < s.size() && s[i] == '0') {
      p.zero = true;
      ++i;
    }
    while (i < s.size() && s[i] >= '0' && s[i] <= '9') {
      p.width = p.width * 10 + (s[i] - '0');
      if (p.width > 32) return std::nullopt;
      ++i;
    }
    if (i >= s.size() || (s[i] != 'd' && s[i] != 'i' && s[i] != 'u')) return std::nullopt;
    part = &p.suffix;
  }
  if (!found) return std::nullopt;
  return p;
}

std::string header_dir(const std::string& path) {
  const std::filesystem::path p(path);
  return p.has_parent_path() ? p.parent_path().string() : std::string(".");
}

std::string resolve(const std::string& header, std::string_view name) {
  std::filesystem::path p{std::string(name)};
  if (p.is_relative()) p = std::filesystem::path(header_dir(header)) / p;
  return p.string();
}

// The data files (or the attached data) and how many elements each holds.
struct Source {
  std::string path;
  std::uint64_t start = 0;  // offset where the line/byte skip begins
  int line = 0;             // header line naming it (0: attached)
};

Result<Volume> load(const std::string& path, const Progress& progress) {
  auto size_r = file_size(path);
  if (!size_r) return size_r.error();
  const std::uint64_t size = size_r.value();
  auto header = read_header_text(path, size, kMaxHeaderBytes);
  if (!header) return header.error();
  std::string text = std::move(header).value();

  // Magic.
  const std::size_t first_nl = text.find('\n');
  const std::string_view magic = trim(std::string_view(text).substr(0, std::min(first_nl, text.size())));
  if (magic.size() != 8 || magic.substr(0, 7) != "NRRD000" || magic[7] < '1' || magic[7] > '5') {
    return invalid(path + ":1: expected the magic line 'NRRD0001'..'NRRD0005', found " + shown(magic));
  }

  // Lines up to the first blank line (attached data follows it) or the end of the file.
  Header h(path);
  std::size_t pos = first_nl == std::string::npos ? text.size() : first_nl + 1;
  int line_no = 1;
  bool blank = false;
  std::size_t data_start = text.size();
  std::vector<std::pair<std::string, int>> list_files;  // after `data file: LIST`
  bool in_list = false;
  while (pos < text.size()) {
    std::size_t end = text.find('\n', pos);
    const bool last = end == std::string::npos;
    if (last) {
      if (size > text.size()) {
        return invalid(path + ":" + std::to_string(line_no + 1) + ": expected the header to end with a blank line within the first " +
                       std::to_string(kMaxHeaderBytes) + " bytes, found none");
      }
      end = text.size();
    }
    const std::string_view t = trim(std::string_view(text).substr(pos, end - pos));
    ++line_no;
    pos = last ? end : end + 1;
    if (t.empty()) {
      blank = true;
      data_start = pos;
      break;
    }
    if (in_list) {
      list_files.emplace_back(std::string(t), line_no);
      continue;
    }
    if (t.front() == '#') continue;
    const std::size_t colon = t.find(':');
    if (colon == std::string_view::npos || colon == 0) {
      return invalid(path + ":" + std::to_string(line_no) + ": expected a header line 'field: value' or 'key:=value', found " + shown(t));
    }
    if (colon + 1 < t.size() && t[colon + 1] == '=') continue;  // key/value pair: ignored
    const std::string_view name = trim(t.substr(0, colon));
    const std::string key = lower(name);
    Field f{std::string(name), std::string(trim(t.substr(colon + 1))), line_no};
    if (std::find(std::begin(kIgnored), std::end(kIgnored), key) == std::end(kIgnored)) {
      return invalid(path + ":" + std::to_string(line_no) + ": " + f.name +
                     ": expected a known NRRD field (dimension, type, sizes, encoding, endian, spacings, space directions, ...), found " +
                     shown(t));
    }
    if (const auto it = h.fields().find(key); it != h.fields().end()) {
      return invalid(path + ":" + std::to_string(line_no) + ": " + f.name + ": expected each field once (first on line " +
                     std::to_string(it->second.line) + "), found " + shown(f.value));
    }
    if (key == "data file" || key == "datafile") {
      const auto words = split_words(f.value);
      in_list = !words.empty() && words[0] == "LIST";
    }
    h.fields()[key] = std::move(f);
  }

  // dimension, type, sizes, encoding, endian.
  const Field* dim_f = h.find({"dimension"});
  if (!dim_f) return h.missing("dimension", "dimension: 3");
  {
    auto n = h.integer(*dim_f, 1, 16);
    if (!n) return n.error();
    if (n.value() != 3) return h.error(*dim_f, "3 (only 3-D scalar volumes are supported)");
  }
  const Field* type_f = h.find({"type"});
  if (!type_f) return h.missing("type", "type: short");
  ElemInfo elem = kU8;
  {
    const auto words = split_words(type_f->value);
    std::string joined;
    for (auto w : words) joined += (joined.empty() ? "" : " ") + lower(w);
    bool known = false;
    for (const TypeName& tn : kTypes) {
      if (joined == tn.spelling) {
        elem = tn.info;
        known = true;
      }
    }
    if (!known) {
      return h.error(*type_f, "one of uchar, signed char, short, ushort, int, uint, float, double (or a synonym such as int16)");
    }
  }
  if (const Field* f = h.find({"block size", "blocksize"})) return h.error(*f, "no block size (type block is not supported)");
  const Field* sizes_f = h.find({"sizes"});
  if (!sizes_f) return h.missing("sizes", "sizes: nx ny nz");
  std::array<int, 3> dims{};
  {
    const auto words = split_words(sizes_f->value);
    const std::string expected = "3 integers in 1.." + std::to_string(std::numeric_limits<int>::max()) +
                                 " with a product of at most " + std::to_string(kMaxVoxels);
    if (words.size() != 3) return h.error(*sizes_f, expected);
    for (std::size_t a = 0; a < 3; ++a) {
      const auto v = parse_int(words[a]);
      if (!v || *v < 1 || *v > std::numeric_limits<int>::max()) return h.error(*sizes_f, expected);
      dims[a] = static_cast<int>(*v);
    }
    const std::uint64_t count = static_cast<std::uint64_t>(dims[0]) * static_cast<std::uint64_t>(dims[1]) *
                                static_cast<std::uint64_t>(dims[2]);
    if (count > kMaxVoxels) return h.error(*sizes_f, expected);
  }
  const Field* enc_f = h.find({"encoding"});
  if (!enc_f) return h.missing("encoding", "encoding: raw");
  bool gzip = false;
  {
    const std::string e = lower(trim(enc_f->value));
    if (e == "gzip" || e == "gz") gzip = true;
    else if (e != "raw") return h.error(*enc_f, "raw, gzip or gz (ascii, hex and bzip2 are not supported)");
  }
  bool big_endian = false;
  if (const Field* f = h.find({"endian"})) {
    const std::string e = lower(trim(f->value));
    if (e == "big") big_endian = true;
    else if (e != "little") return h.error(*f, "little or big");
  } else if (elem.bytes > 1) {
    return h.missing("endian", "endian: little");
  }

  Volume v;
  v.dims = dims;
  v.source_type = elem.nearest;
  v.value_unit = "raw";
  v.spacing = Vec3{kMm, kMm, kMm};

  // Geometry.
  const Field* space_f = h.find({"space"});
  const Field* sdim_f = h.find({"space dimension"});
  if (space_f && sdim_f) return h.error(*sdim_f, "no 'space dimension' when 'space' is given");
  if (space_f) {
    static constexpr std::string_view kSpaces3[] = {
        "right-anterior-superior", "ras", "left-anterior-superior", "las", "left-posterior-superior", "lps",
        "scanner-xyz", "3d-right-handed", "3d-left-handed"};
    const std::string s = lower(trim(space_f->value));
    if (std::find(std::begin(kSpaces3), std::end(kSpaces3), s) == std::end(kSpaces3)) {
      return h.error(*space_f, "a 3-D space (left-posterior-superior, right-anterior-superior, left-anterior-superior, "
                               "scanner-xyz, 3D-right-handed, 3D-left-handed)");
    }
  }
  if (sdim_f) {
    auto n = h.integer(*sdim_f, 1, 16);
    if (!n) return n.error();
    if (n.value() != 3) return h.error(*sdim_f, "3");
  }
  const bool has_space = space_f || sdim_f;
  if (const Field* f = h.find({"space units", "spaceunits"})) {
    std::string u(f->value);
    std::replace(u.begin(), u.end(), '"', ' ');
    const auto words = split_words(u);
    if (words.size() != 3 || std::any_of(words.begin(), words.end(), [](std::string_view w) { return w != "mm"; })) {
      return h.error(*f, "\"mm\" \"mm\" \"mm\" (other units are not supported)");
    }
  }
  const Field* spacings_f = h.find({"spacings"});
  const Field* dirs_f = h.find({"space directions"});
  if (spacings_f && dirs_f) return h.error(*spacings_f, "either spacings or space directions, not both");
  if (spacings_f) {
    const auto words = split_words(spacings_f->value);
    std::array<double, 3> s{};
    if (words.size() != 3) return h.error(*spacings_f, "3 positive finite numbers");
    for (std::size_t a = 0; a < 3; ++a) {
      const auto d = parse_double(words[a]);
      if (!d || !std::isfinite(*d) || !(*d > 0)) return h.error(*spacings_f, "3 positive finite numbers");
      s[a] = *d;
    }
    v.spacing = Vec3{s[0] * kMm, s[1] * kMm, s[2] * kMm};
  }
  // pynrrd writes space directions (and origin) without a space or space dimension line; teem
  // refuses such a file, we take the space dimension from the vectors (3 numbers each) and say so.
  const Field* inferred_from = nullptr;
  if (dirs_f) {
    const auto vecs = parse_vectors(dirs_f->value, 3);
    if (!vecs) return h.error(*dirs_f, "3 vectors '(x,y,z)' of finite numbers");
    if (!has_space) inferred_from = dirs_f;
    std::array<double, 3> len{};
    for (std::size_t a = 0; a < 3; ++a) {
      const auto& d = (*vecs)[a];
      len[a] = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      if (!(len[a] > 0) || !std::isfinite(len[a])) return h.error(*dirs_f, "3 non-zero vectors '(x,y,z)'");
      for (std::size_t r = 0; r < 3; ++r) v.direction[r * 3 + a] = d[r] / len[a];
    }
    const auto& d = v.direction;
    const double det = d[0] * (d[4] * d[8] - d[5] * d[7]) - d[1] * (d[3] * d[8] - d[5] * d[6]) +
                       d[2] * (d[3] * d[7] - d[4] * d[6]);
    if (!(std::abs(det) > 1e-6)) return h.error(*dirs_f, "3 linearly independent vectors");
    v.spacing = Vec3{len[0] * kMm, len[1] * kMm, len[2] * kMm};
  }
  if (const Field* f = h.find({"space origin"})) {
    const auto o = parse_vectors(f->value, 1);
    if (!o) return h.error(*f, "one vector '(x,y,z)' of finite numbers");
    if (!has_space && inferred_from == nullptr) inferred_from = f;
    v.origin = Vec3{(*o)[0][0] * kMm, (*o)[0][1] * kMm, (*o)[0][2] * kMm};
  }
  if (inferred_from != nullptr) {
    v.warnings.push_back(path + ":" + std::to_string(inferred_from->line) + ": " + inferred_from->name +
                         ": no 'space:' or 'space dimension:' line (as pynrrd writes it; teem refuses such a file): "
                         "took 'space dimension: 3' from its vectors of 3 numbers");
  }

  // Skips.
  std::int64_t byte_skip = 0, line_skip = 0;
  if (const Field* f = h.find({"byte skip", "byteskip"})) {
    auto n = h.integer(*f, -1, std::numeric_limits<std::int64_t>::max() / 4);
    if (!n) return n.error();
    if (n.value() == -1 && gzip) return h.error(*f, ">= 0 with gzip encoding (-1 is only for raw)");
    byte_skip = n.value();
  }
  if (const Field* f = h.find({"line skip", "lineskip"})) {
    auto n = h.integer(*f, 0, std::numeric_limits<std::int64_t>::max() / 4);
    if (!n) return n.error();
    line_skip = n.value();
  }

  // Data files.
  const std::uint64_t total = v.voxel_count();
  std::vector<Source> sources;
  std::optional<Pattern> pattern;
  std::int64_t pat_min = 0, pat_step = 1;
  std::uint64_t file_count = 1;
  std::int64_t subdim = 2;  // axes 0..subdim-1 are inside each file
  const Field* file_f = h.find({"data file", "datafile"});
  if (!file_f) {
    if (!blank) {
      return invalid(path + ": data file: expected a line 'data file: <name>' or a blank line followed by the data, found neither");
    }
    sources.push_back(Source{path, static_cast<std::uint64_t>(data_start), 0});
  } else {
    const auto words = split_words(file_f->value);
    const std::string expected_df = "a file name, 'LIST [subdim]' or '<printf pattern> min max step [subdim]'";
    if (words.empty()) return h.error(*file_f, expected_df);
    auto read_subdim = [&](std::string_view w) -> Result<bool> {
      const auto n = parse_int(w);
      if (!n || *n < 1 || *n > 3) return h.error(*file_f, "a subdim in 1..3");
      subdim = *n;
      return true;
    };
    if (words[0] == "LIST") {
      if (words.size() > 2) return h.error(*file_f, expected_df);
      if (words.size() == 2) {
        if (auto r = read_subdim(words[1]); !r) return r.error();
      } else {
        subdim = 2;
      }
      if (list_files.empty()) return h.error(*file_f, "one file name per line after 'data file: LIST', found none");
      for (const auto& [name, line] : list_files) sources.push_back(Source{resolve(path, name), 0, line});
      file_count = sources.size();
    } else if (words.size() >= 4 && words[0].find('%') != std::string_view::npos) {
      if (words.size() > 5) return h.error(*file_f, expected_df);
      pattern = parse_pattern(words[0]);
      if (!pattern) return h.error(*file_f, "a printf pattern with exactly one %d, %i or %u (e.g. slice.%03d)");
      const auto mn = parse_int(words[1]), mx = parse_int(words[2]), st = parse_int(words[3]);
      constexpr std::int64_t kLim = std::int64_t{1} << 40;
      if (!mn || !mx || !st || *st == 0 || std::abs(*mn) > kLim || std::abs(*mx) > kLim || std::abs(*st) > kLim ||
          (*mx - *mn) / *st < 0) {
        return h.error(*file_f, "integers min max step with step != 0 leading from min to max");
      }
      if (words.size() == 5) {
        if (auto r = read_subdim(words[4]); !r) return r.error();
      }
      pat_min = *mn;
      pat_step = *st;
      file_count = static_cast<std::uint64_t>((*mx - *mn) / *st) + 1;
    } else if (words.size() == 1) {
      sources.push_back(Source{resolve(path, words[0]), 0, file_f->line});
    } else {
      return h.error(*file_f, expected_df);
    }
  }
  // Files hold axes 0..subdim-1; their count must be the product of the other sizes.
  std::uint64_t per_file_elems = 1, outer = 1;
  for (std::int64_t a = 0; a < 3; ++a) {
    (a < subdim ? per_file_elems : outer) *= static_cast<std::uint64_t>(dims[static_cast<std::size_t>(a)]);
  }
  const bool many = pattern.has_value() || (file_f && split_words(file_f->value)[0] == "LIST");
  if (many && file_count != outer) {
    return h.error(*file_f, std::to_string(outer) + " data files (the product of the sizes beyond subdim " +
                                std::to_string(subdim) + "), not " + std::to_string(file_count));
  }
  if (!many) per_file_elems = total;
  const std::uint64_t per_file = per_file_elems * elem.bytes;
  const auto source_at = [&](std::uint64_t i) -> Source {
    if (pattern) {
      return Source{resolve(path, pattern->format(pat_min + static_cast<std::int64_t>(i) * pat_step)), 0, file_f->line};
    }
    return sources[static_cast<std::size_t>(i)];
  };

  // Check every file against its real size before reading anything (raw), then read.
  struct Span {
    std::uint64_t offset, count;
  };
  std::vector<unsigned char> bytes;
  const auto n_files = pattern ? file_count : static_cast<std::uint64_t>(sources.size());
  std::vector<Span> spans;
  for (std::uint64_t i = 0; i < n_files; ++i) {
    const Source s = source_at(i);
    const std::string where = s.line == 0 ? path + " (data after the header)" : s.path;
    auto fs = file_size(s.path);
    if (!fs) {
      Error e = fs.error();
      if (s.line != 0) e.message = path + ":" + std::to_string(s.line) + ": data file: " + e.message;
      return e;
    }
    std::uint64_t start = s.start;
    if (line_skip > 0) {
      const auto after = after_lines(s.path, start, line_skip);
      if (!after) {
        return invalid(where + ": line skip: expected at least " + std::to_string(line_skip) +
                       " lines before the data, found fewer");
      }
      start = *after;
    }
    const std::uint64_t left = fs.value() > start ? fs.value() - start : 0;
    if (gzip) {
      if (left == 0) return invalid(where + ": encoding: expected gzip data, found none");
      spans.push_back(Span{start, left});
      continue;
    }
    if (byte_skip == -1) {
      if (left < per_file) {
        return invalid(where + ": truncated data: expected " + std::to_string(per_file) +
                       " bytes (sizes × element size) at the end of the file, found " + std::to_string(left));
      }
      spans.push_back(Span{fs.value() - per_file, per_file});
      continue;
    }
    const auto skip = static_cast<std::uint64_t>(byte_skip);
    if (skip > left) {
      return invalid(where + ": byte skip: expected at most " + std::to_string(left) + " bytes to skip, found " +
                     std::to_string(skip));
    }
    if (left - skip != per_file) {
      return invalid(where + ": data size mismatch: expected " + std::to_string(per_file) + " bytes (sizes " +
                     std::to_string(dims[0]) + "×" + std::to_string(dims[1]) + "×" + std::to_string(dims[2]) +
                     (n_files > 1 ? " / " + std::to_string(n_files) + " files" : std::string()) + " × " +
                     std::to_string(elem.bytes) + " bytes of " + elem.name + "), found " + std::to_string(left - skip));
    }
    spans.push_back(Span{start + skip, per_file});
  }
  if (!gzip) bytes.reserve(static_cast<std::size_t>(total * elem.bytes));  // every file's size is checked
  for (std::uint64_t i = 0; i < n_files; ++i) {
    const Source s = source_at(i);
    const std::string where = s.line == 0 ? path + " (data after the header)" : s.path;
    const Span& sp = spans[static_cast<std::size_t>(i)];
    if (!gzip) {
      auto r = append_bytes(s.path, sp.offset, sp.count, bytes);
      if (!r) return r.error();
    } else {
      std::vector<unsigned char> packed;
      auto r = append_bytes(s.path, sp.offset, sp.count, packed);
      if (!r) return r.error();
      const std::size_t before = bytes.size();
      const auto skip = static_cast<std::uint64_t>(byte_skip);
      auto z = inflate_exact(where, packed, skip + per_file, bytes);
      if (!z) return z.error();
      bytes.erase(bytes.begin() + static_cast<std::ptrdiff_t>(before),
                  bytes.begin() + static_cast<std::ptrdiff_t>(before + skip));
    }
    report(progress, 0.5 * static_cast<double>(i + 1) / static_cast<double>(n_files));
  }
  v.data = convert(bytes, elem, big_endian, v.voxel_count(), progress, 0.5, 1.0);
  return v;
}

}  // namespace

Result<Volume> load_nrrd(const std::string& path, const Progress& progress) {
  return detail::load_catching(path, [&] { return load(path, progress); });
}

}  // namespace lancet::volume
