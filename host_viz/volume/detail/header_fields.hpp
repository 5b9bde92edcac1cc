#pragma once
// What the two text-header volume formats (MetaImage "Key = value", NRRD "field: value") share
// once a header's lines are split: the fields by case-insensitive name, each with the line it
// came from, typed readers whose errors name the file, line and field with what was expected and
// what was found; and the data-reading steps after the header (a byte range of a file, a gzip or
// zlib stream inflated to an exact size). Internal to host_viz/volume; not a public API.

#include <array>
#include <cstdint>
#include <initializer_list>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "volume/detail/io.hpp"

namespace lancet::volume::detail {

/// One header line's field: its name as written, its value (trimmed) and its line number.
struct HeaderField {
  std::string name;
  std::string value;
  int line = 0;
};

class HeaderFields {
 public:
  explicit HeaderFields(std::string path) : path_(std::move(path)) {}

  const std::string& path() const { return path_; }

  /// Stores a field under its lower-case name, replacing one of the same name.
  void set(HeaderField f) {
    std::string key = lower(f.name);
    fields_[std::move(key)] = std::move(f);
  }

  /// The first of several synonyms present (e.g. Offset / Position / Origin), or nullptr.
  const HeaderField* find(std::initializer_list<std::string_view> names) const;

  /// "path:line: name: expected <expected>, found <value>".
  Error error(const HeaderField& f, const std::string& expected) const;
  /// "path: name: expected a line '<example>', found none".
  Error missing(std::string_view name, std::string_view example) const;

  /// One integer in [lo, hi].
  Result<std::int64_t> integer(const HeaderField& f, std::int64_t lo, std::int64_t hi) const;
  /// Exactly n finite numbers, each > 0 when `positive`.
  Result<std::vector<double>> numbers(const HeaderField& f, std::size_t n, bool positive) const;
  /// True/False (also 1/0, yes/no), as MetaImage writes booleans.
  Result<bool> boolean(const HeaderField& f) const;
  /// Three sizes in 1..INT_MAX whose product is at most `max_voxels`.
  Result<std::array<int, 3>> sizes(const HeaderField& f, std::uint64_t max_voxels) const;

 private:
  std::string path_;
  std::map<std::string, HeaderField> fields_;  // lower-case name → field
};

/// The determinant of a row-major 3×3 matrix (a volume's direction cosines).
double determinant3(const std::array<double, 9>& m);

/// The folder of a header file ("." when it names none); relative data files are taken from it.
std::string header_dir(const std::string& path);

/// Appends `count` bytes at `offset` of `path` to `out`, reporting progress from p0 to p1. The
/// caller has checked that the file holds them, so the allocation is bounded by its real size.
Result<bool> append_file_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count,
                               std::vector<unsigned char>& out, const Progress& progress, double p0, double p1);

/// How a format names its compressed stream in messages: the header field it belongs to, the kind
/// of stream, and what the expected size is made of.
struct StreamWords {
  std::string_view field;        ///< e.g. "CompressedData" or "encoding"
  std::string_view kind;         ///< "zlib" or "gzip"
  std::string_view expected_is;  ///< e.g. "DimSize × element size"
};

/// Inflates a zlib or gzip stream into exactly `expected` bytes appended to `out`; a stream that
/// holds more or less, or is corrupt, is an error naming `where`. The output grows only as data
/// really comes out, so a tiny file that claims a huge image allocates nothing big.
Result<bool> inflate_exact(const std::string& where, const StreamWords& words, const std::vector<unsigned char>& in,
                           std::uint64_t expected, std::vector<unsigned char>& out, const Progress& progress,
                           double p0, double p1);

}  // namespace lancet::volume::detail
