#include "volume/nrrd.hpp"
#include "volume/detail/header_fields.hpp"

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "volume/metaimage.hpp"  // kMaxVoxels

namespace lancet::volume {
namespace {

using namespace detail;  // the helpers shared by the loaders

// Text, header-field, file and inflation helpers are shared with metaimage.cpp (volume/detail/).

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

// The header's lines up to the blank line that ends it (attached data follows) or the file's end.
struct HeaderText {
  explicit HeaderText(const std::string& path) : fields(path) {}
  HeaderFields fields;
  std::vector<std::pair<std::string, int>> list_files;  // the lines after `data file: LIST`
  bool blank = false;                                    // a blank line ended it
  std::size_t data_start = 0;                            // the byte after that blank line
};

Result<bool> check_magic(const std::string& path, std::string_view first_line) {
  const std::string_view magic = trim(first_line);
  if (magic.size() != 8 || magic.substr(0, 7) != "NRRD000" || magic[7] < '1' || magic[7] > '5') {
    return invalid(path + ":1: expected the magic line 'NRRD0001'..'NRRD0005', found " + shown(magic));
  }
  return true;
}

// Takes one "field: value" line into `h`; `in_list` turns on after `data file: LIST`.
Result<bool> take_field_line(HeaderText& h, std::string_view t, int line_no, bool& in_list) {
  const std::string& path = h.fields.path();
  const std::size_t colon = t.find(':');
  if (colon == std::string_view::npos || colon == 0) {
    return invalid(path + ":" + std::to_string(line_no) + ": expected a header line 'field: value' or 'key:=value', found " + shown(t));
  }
  if (colon + 1 < t.size() && t[colon + 1] == '=') return true;  // key/value pair: ignored
  const std::string_view name = trim(t.substr(0, colon));
  const std::string key = lower(name);
  HeaderField f{std::string(name), std::string(trim(t.substr(colon + 1))), line_no};
  if (std::find(std::begin(kIgnored), std::end(kIgnored), key) == std::end(kIgnored)) {
    return invalid(path + ":" + std::to_string(line_no) + ": " + f.name +
                   ": expected a known NRRD field (dimension, type, sizes, encoding, endian, spacings, space directions, ...), found " +
                   shown(t));
  }
  if (const HeaderField* before = h.fields.find({key})) {
    return invalid(path + ":" + std::to_string(line_no) + ": " + f.name + ": expected each field once (first on line " +
                   std::to_string(before->line) + "), found " + shown(f.value));
  }
  if (key == "data file" || key == "datafile") {
    const auto words = split_words(f.value);
    in_list = !words.empty() && words[0] == "LIST";
  }
  h.fields.set(std::move(f));
  return true;
}

Result<HeaderText> read_header(const std::string& path, std::uint64_t size) {
  auto header = read_header_text(path, size, kMaxHeaderBytes);
  if (!header) return header.error();
  const std::string text = std::move(header).value();
  const std::size_t first_nl = text.find('\n');
  if (auto m = check_magic(path, std::string_view(text).substr(0, std::min(first_nl, text.size()))); !m) return m.error();

  HeaderText h(path);
  h.data_start = text.size();
  std::size_t pos = first_nl == std::string::npos ? text.size() : first_nl + 1;
  int line_no = 1;
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
      h.blank = true;
      h.data_start = pos;
      break;
    }
    if (in_list) {
      h.list_files.emplace_back(std::string(t), line_no);
    } else if (t.front() != '#') {
      if (auto r = take_field_line(h, t, line_no, in_list); !r) return r.error();
    }
  }
  return h;
}

// How the elements are stored: dimension, type, sizes, encoding, endian.
struct Format {
  std::array<int, 3> dims{};
  ElemInfo elem = kU8;
  bool gzip = false;
  bool big_endian = false;
};

Result<ElemInfo> read_type(const HeaderFields& h, const HeaderField& f) {
  std::string joined;
  for (auto w : split_words(f.value)) joined += (joined.empty() ? "" : " ") + lower(w);
  for (const TypeName& tn : kTypes) {
    if (joined == tn.spelling) return tn.info;
  }
  return h.error(f, "one of uchar, signed char, short, ushort, int, uint, float, double (or a synonym such as int16)");
}

Result<Format> read_format(const HeaderFields& h) {
  Format out;
  const HeaderField* dim_f = h.find({"dimension"});
  if (!dim_f) return h.missing("dimension", "dimension: 3");
  auto n = h.integer(*dim_f, 1, 16);
  if (!n) return n.error();
  if (n.value() != 3) return h.error(*dim_f, "3 (only 3-D scalar volumes are supported)");
  const HeaderField* type_f = h.find({"type"});
  if (!type_f) return h.missing("type", "type: short");
  auto elem = read_type(h, *type_f);
  if (!elem) return elem.error();
  out.elem = elem.value();
  if (const HeaderField* f = h.find({"block size", "blocksize"})) return h.error(*f, "no block size (type block is not supported)");
  const HeaderField* sizes_f = h.find({"sizes"});
  if (!sizes_f) return h.missing("sizes", "sizes: nx ny nz");
  auto dims = h.sizes(*sizes_f, kMaxVoxels);
  if (!dims) return dims.error();
  out.dims = dims.value();
  const HeaderField* enc_f = h.find({"encoding"});
  if (!enc_f) return h.missing("encoding", "encoding: raw");
  const std::string e = lower(trim(enc_f->value));
  if (e == "gzip" || e == "gz") out.gzip = true;
  else if (e != "raw") return h.error(*enc_f, "raw, gzip or gz (ascii, hex and bzip2 are not supported)");
  if (const HeaderField* f = h.find({"endian"})) {
    const std::string end = lower(trim(f->value));
    if (end == "big") out.big_endian = true;
    else if (end != "little") return h.error(*f, "little or big");
  } else if (out.elem.bytes > 1) {
    return h.missing("endian", "endian: little");
  }
  return out;
}

// `space` and `space dimension`: a 3-D space when either is given. Returns whether one is.
Result<bool> read_space(const HeaderFields& h) {
  const HeaderField* space_f = h.find({"space"});
  const HeaderField* sdim_f = h.find({"space dimension"});
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
  if (const HeaderField* f = h.find({"space units", "spaceunits"})) {
    std::string u(f->value);
    std::replace(u.begin(), u.end(), '"', ' ');
    const auto words = split_words(u);
    if (words.size() != 3 || std::any_of(words.begin(), words.end(), [](std::string_view w) { return w != "mm"; })) {
      return h.error(*f, "\"mm\" \"mm\" \"mm\" (other units are not supported)");
    }
  }
  return space_f != nullptr || sdim_f != nullptr;
}

// `space directions`: the axes' directions (into v.direction) and lengths (into v.spacing).
Result<bool> read_directions(const HeaderFields& h, const HeaderField& f, Volume& v) {
  const auto vecs = parse_vectors(f.value, 3);
  if (!vecs) return h.error(f, "3 vectors '(x,y,z)' of finite numbers");
  std::array<double, 3> len{};
  for (std::size_t a = 0; a < 3; ++a) {
    const auto& d = (*vecs)[a];
    len[a] = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(len[a] > 0) || !std::isfinite(len[a])) return h.error(f, "3 non-zero vectors '(x,y,z)'");
    for (std::size_t r = 0; r < 3; ++r) v.direction[r * 3 + a] = d[r] / len[a];
  }
  if (!(std::abs(determinant3(v.direction)) > 1e-6)) return h.error(f, "3 linearly independent vectors");
  v.spacing = Vec3{len[0] * kMm, len[1] * kMm, len[2] * kMm};
  return true;
}

// The volume's spacing, directions and origin (mm in the file, metres in the Volume).
Result<bool> read_geometry(const HeaderFields& h, Volume& v) {
  auto has_space = read_space(h);
  if (!has_space) return has_space.error();
  const HeaderField* spacings_f = h.find({"spacings"});
  const HeaderField* dirs_f = h.find({"space directions"});
  if (spacings_f && dirs_f) return h.error(*spacings_f, "either spacings or space directions, not both");
  if (spacings_f) {
    auto s = h.numbers(*spacings_f, 3, true);
    if (!s) return s.error();
    v.spacing = Vec3{s.value()[0] * kMm, s.value()[1] * kMm, s.value()[2] * kMm};
  }
  // pynrrd writes space directions (and origin) without a space or space dimension line; teem
  // refuses such a file, we take the space dimension from the vectors (3 numbers each) and say so.
  const HeaderField* inferred_from = nullptr;
  if (dirs_f) {
    if (auto r = read_directions(h, *dirs_f, v); !r) return r.error();
    if (!has_space.value()) inferred_from = dirs_f;
  }
  if (const HeaderField* f = h.find({"space origin"})) {
    const auto o = parse_vectors(f->value, 1);
    if (!o) return h.error(*f, "one vector '(x,y,z)' of finite numbers");
    if (!has_space.value() && inferred_from == nullptr) inferred_from = f;
    v.origin = Vec3{(*o)[0][0] * kMm, (*o)[0][1] * kMm, (*o)[0][2] * kMm};
  }
  if (inferred_from != nullptr) {
    v.warnings.push_back(h.path() + ":" + std::to_string(inferred_from->line) + ": " + inferred_from->name +
                         ": no 'space:' or 'space dimension:' line (as pynrrd writes it; teem refuses such a file): "
                         "took 'space dimension: 3' from its vectors of 3 numbers");
  }
  return true;
}

// `byte skip` (-1: the data is at the end of each file) and `line skip`.
struct Skips {
  std::int64_t bytes = 0;
  std::int64_t lines = 0;
};

Result<Skips> read_skips(const HeaderFields& h, bool gzip) {
  Skips out;
  if (const HeaderField* f = h.find({"byte skip", "byteskip"})) {
    auto n = h.integer(*f, -1, std::numeric_limits<std::int64_t>::max() / 4);
    if (!n) return n.error();
    if (n.value() == -1 && gzip) return h.error(*f, ">= 0 with gzip encoding (-1 is only for raw)");
    out.bytes = n.value();
  }
  if (const HeaderField* f = h.find({"line skip", "lineskip"})) {
    auto n = h.integer(*f, 0, std::numeric_limits<std::int64_t>::max() / 4);
    if (!n) return n.error();
    out.lines = n.value();
  }
  return out;
}

// The data files in order (one, a LIST, or a printf pattern), and how many elements each holds.
struct DataFiles {
  std::string header;             // the header's path; pattern names are resolved against it
  std::vector<Source> listed;     // the attached data, one file or a LIST
  std::optional<Pattern> pattern;
  std::int64_t pattern_min = 0, pattern_step = 1;
  int pattern_line = 0;
  std::uint64_t count = 1;
  std::uint64_t elems_each = 0;

  Source at(std::uint64_t i) const {
    if (pattern) {
      return Source{resolve(header, pattern->format(pattern_min + static_cast<std::int64_t>(i) * pattern_step)), 0,
                    pattern_line};
    }
    return listed[static_cast<std::size_t>(i)];
  }
};

// `data file: <printf pattern> min max step [subdim]` into `out`.
Result<bool> read_pattern(const HeaderFields& h, const HeaderField& f, const std::vector<std::string_view>& words,
                          DataFiles& out) {
  out.pattern = parse_pattern(words[0]);
  if (!out.pattern) return h.error(f, "a printf pattern with exactly one %d, %i or %u (e.g. slice.%03d)");
  const auto mn = parse_int(words[1]), mx = parse_int(words[2]), st = parse_int(words[3]);
  constexpr std::int64_t kLim = std::int64_t{1} << 40;
  if (!mn || !mx || !st || *st == 0 || std::abs(*mn) > kLim || std::abs(*mx) > kLim || std::abs(*st) > kLim ||
      (*mx - *mn) / *st < 0) {
    return h.error(f, "integers min max step with step != 0 leading from min to max");
  }
  out.pattern_min = *mn;
  out.pattern_step = *st;
  out.pattern_line = f.line;
  out.count = static_cast<std::uint64_t>((*mx - *mn) / *st) + 1;
  return true;
}

Result<DataFiles> read_data_files(const HeaderText& t, const Format& format) {
  const HeaderFields& h = t.fields;
  const std::string& path = h.path();
  DataFiles out;
  out.header = path;
  std::int64_t subdim = 2;  // axes 0..subdim-1 are inside each file
  bool many = false;
  const HeaderField* file_f = h.find({"data file", "datafile"});
  if (!file_f) {
    if (!t.blank) {
      return invalid(path + ": data file: expected a line 'data file: <name>' or a blank line followed by the data, found neither");
    }
    out.listed.push_back(Source{path, static_cast<std::uint64_t>(t.data_start), 0});
  } else {
    const auto words = split_words(file_f->value);
    const std::string expected_df = "a file name, 'LIST [subdim]' or '<printf pattern> min max step [subdim]'";
    const auto read_subdim = [&](std::string_view w) -> Result<bool> {
      const auto n = parse_int(w);
      if (!n || *n < 1 || *n > 3) return h.error(*file_f, "a subdim in 1..3");
      subdim = *n;
      return true;
    };
    if (words.empty()) return h.error(*file_f, expected_df);
    if (words[0] == "LIST") {
      if (words.size() > 2) return h.error(*file_f, expected_df);
      if (words.size() == 2) {
        if (auto r = read_subdim(words[1]); !r) return r.error();
      }
      if (t.list_files.empty()) return h.error(*file_f, "one file name per line after 'data file: LIST', found none");
      for (const auto& [name, line] : t.list_files) out.listed.push_back(Source{resolve(path, name), 0, line});
      out.count = out.listed.size();
      many = true;
    } else if (words.size() >= 4 && words[0].find('%') != std::string_view::npos) {
      if (words.size() > 5) return h.error(*file_f, expected_df);
      if (auto r = read_pattern(h, *file_f, words, out); !r) return r.error();
      if (words.size() == 5) {
        if (auto r = read_subdim(words[4]); !r) return r.error();
      }
      many = true;
    } else if (words.size() == 1) {
      out.listed.push_back(Source{resolve(path, words[0]), 0, file_f->line});
    } else {
      return h.error(*file_f, expected_df);
    }
  }
  // Files hold axes 0..subdim-1; their count must be the product of the other sizes.
  std::uint64_t per_file = 1, outer = 1;
  for (std::int64_t a = 0; a < 3; ++a) {
    (a < subdim ? per_file : outer) *= static_cast<std::uint64_t>(format.dims[static_cast<std::size_t>(a)]);
  }
  if (many && out.count != outer) {
    return h.error(*file_f, std::to_string(outer) + " data files (the product of the sizes beyond subdim " +
                                std::to_string(subdim) + "), not " + std::to_string(out.count));
  }
  out.elems_each = many ? per_file : per_file * outer;
  return out;
}

// Where each file's data lies: checked against every file's real size before anything is read.
struct Span {
  std::uint64_t offset, count;
};

std::string where_of(const std::string& path, const Source& s) {
  return s.line == 0 ? path + " (data after the header)" : s.path;
}

Result<Span> data_span(const std::string& path, const Source& s, const Format& format, const Skips& skips,
                       std::uint64_t per_file, std::uint64_t n_files) {
  const std::string where = where_of(path, s);
  auto fs = file_size(s.path);
  if (!fs) {
    Error e = fs.error();
    if (s.line != 0) e.message = path + ":" + std::to_string(s.line) + ": data file: " + e.message;
    return e;
  }
  std::uint64_t start = s.start;
  if (skips.lines > 0) {
    const auto after = after_lines(s.path, start, skips.lines);
    if (!after) {
      return invalid(where + ": line skip: expected at least " + std::to_string(skips.lines) + " lines before the data, found fewer");
    }
    start = *after;
  }
  const std::uint64_t left = fs.value() > start ? fs.value() - start : 0;
  if (format.gzip) {
    if (left == 0) return invalid(where + ": encoding: expected gzip data, found none");
    return Span{start, left};
  }
  if (skips.bytes == -1) {
    if (left < per_file) {
      return invalid(where + ": truncated data: expected " + std::to_string(per_file) +
                     " bytes (sizes × element size) at the end of the file, found " + std::to_string(left));
    }
    return Span{fs.value() - per_file, per_file};
  }
  const auto skip = static_cast<std::uint64_t>(skips.bytes);
  if (skip > left) {
    return invalid(where + ": byte skip: expected at most " + std::to_string(left) + " bytes to skip, found " + std::to_string(skip));
  }
  if (left - skip != per_file) {
    const auto& d = format.dims;
    return invalid(where + ": data size mismatch: expected " + std::to_string(per_file) + " bytes (sizes " +
                   std::to_string(d[0]) + "×" + std::to_string(d[1]) + "×" + std::to_string(d[2]) +
                   (n_files > 1 ? " / " + std::to_string(n_files) + " files" : std::string()) + " × " +
                   std::to_string(format.elem.bytes) + " bytes of " + format.elem.name + "), found " +
                   std::to_string(left - skip));
  }
  return Span{start + skip, per_file};
}

// Every file's elements, in order, raw or inflated.
Result<std::vector<unsigned char>> read_data(const std::string& path, const DataFiles& files, const Format& format,
                                             const Skips& skips, std::uint64_t total, const Progress& progress) {
  const std::uint64_t per_file = files.elems_each * format.elem.bytes;
  std::vector<Span> spans;
  for (std::uint64_t i = 0; i < files.count; ++i) {
    auto sp = data_span(path, files.at(i), format, skips, per_file, files.count);
    if (!sp) return sp.error();
    spans.push_back(sp.value());
  }
  std::vector<unsigned char> bytes;
  if (!format.gzip) bytes.reserve(static_cast<std::size_t>(total * format.elem.bytes));  // every file's size is checked
  constexpr StreamWords kWords{"encoding", "gzip", "sizes × element size + byte skip"};
  for (std::uint64_t i = 0; i < files.count; ++i) {
    const Source s = files.at(i);
    const Span& sp = spans[static_cast<std::size_t>(i)];
    if (!format.gzip) {
      if (auto r = append_file_bytes(s.path, sp.offset, sp.count, bytes, {}, 0.0, 0.0); !r) return r.error();
    } else {
      std::vector<unsigned char> packed;
      if (auto r = append_file_bytes(s.path, sp.offset, sp.count, packed, {}, 0.0, 0.0); !r) return r.error();
      const std::size_t before = bytes.size();
      const auto skip = static_cast<std::uint64_t>(skips.bytes);
      auto z = inflate_exact(where_of(path, s), kWords, packed, skip + per_file, bytes, {}, 0.0, 0.0);
      if (!z) return z.error();
      bytes.erase(bytes.begin() + static_cast<std::ptrdiff_t>(before),
                  bytes.begin() + static_cast<std::ptrdiff_t>(before + skip));
    }
    report(progress, 0.5 * static_cast<double>(i + 1) / static_cast<double>(files.count));
  }
  return bytes;
}

Result<Volume> load(const std::string& path, const Progress& progress) {
  auto size = file_size(path);
  if (!size) return size.error();
  auto header = read_header(path, size.value());
  if (!header) return header.error();
  const HeaderFields& h = header.value().fields;
  auto format = read_format(h);
  if (!format) return format.error();
  Volume v;
  v.dims = format.value().dims;
  v.source_type = format.value().elem.nearest;
  v.value_unit = "raw";
  v.spacing = Vec3{kMm, kMm, kMm};
  if (auto g = read_geometry(h, v); !g) return g.error();
  auto skips = read_skips(h, format.value().gzip);
  if (!skips) return skips.error();
  auto files = read_data_files(header.value(), format.value());
  if (!files) return files.error();
  auto bytes = read_data(path, files.value(), format.value(), skips.value(), v.voxel_count(), progress);
  if (!bytes) return bytes.error();
  v.data = convert(bytes.value(), format.value().elem, format.value().big_endian, v.voxel_count(), progress, 0.5, 1.0);
  return v;
}

}  // namespace

Result<Volume> load_nrrd(const std::string& path, const Progress& progress) {
  return detail::load_catching(path, [&] { return load(path, progress); });
}

}  // namespace lancet::volume
