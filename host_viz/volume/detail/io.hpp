#pragma once
// Helpers shared by the volume file loaders (metaimage.cpp, nrrd.cpp): error and progress
// reporting, header text parsing, file size, and conversion of stored elements to float.
// Internal to host_viz/volume; not a public API.

#include <algorithm>
#include <bit>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <new>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "volume/in_two_halves.hpp"
#include "volume/volume.hpp"

namespace lancet::volume::detail {

inline constexpr int kProgressSteps = 32;             ///< progress reports per long phase
inline constexpr std::size_t kMinChunk = 1 << 20;     ///< elements or bytes handled between reports

enum class Elem : std::uint8_t { kU8, kI8, kI16, kU16, kI32, kU32, kF32, kF64 };

struct ElemInfo {
  const char* name;
  Elem elem;
  std::size_t bytes;
  VoxelType nearest;
};

inline Error invalid(std::string message) { return Error{ErrorCode::kInvalid, std::move(message)}; }

inline void report(const Progress& progress, double fraction) {
  if (progress) progress(std::clamp(fraction, 0.0, 1.0));
}

inline std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t' || s.front() == '\r')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) s.remove_suffix(1);
  return s;
}

inline std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>((c >= 'A' && c <= 'Z') ? c - 'A' + 'a' : c);
  return out;
}

// Shortens a found value for an error message (a fuzzed line may be huge or binary).
inline std::string shown(std::string_view s) {
  std::string out;
  for (char c : s.substr(0, 80)) out += (c >= 32 && c < 127) ? c : '?';
  if (s.size() > 80) out += "...";
  return "'" + out + "'";
}

inline std::vector<std::string_view> split_words(std::string_view s) {
  std::vector<std::string_view> words;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && (s[i] == ' ' || s[i] == '\t')) ++i;
    const std::size_t start = i;
    while (i < s.size() && s[i] != ' ' && s[i] != '\t') ++i;
    if (i > start) words.push_back(s.substr(start, i - start));
  }
  return words;
}

inline std::optional<double> parse_double(std::string_view w) {
  double v = 0;
  if (!w.empty() && w.front() == '+') w.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(w.data(), w.data() + w.size(), v);
  if (ec != std::errc{} || ptr != w.data() + w.size()) return std::nullopt;
  return v;
}

inline std::optional<std::int64_t> parse_int(std::string_view w) {
  std::int64_t v = 0;
  if (!w.empty() && w.front() == '+') w.remove_prefix(1);
  const auto [ptr, ec] = std::from_chars(w.data(), w.data() + w.size(), v);
  if (ec != std::errc{} || ptr != w.data() + w.size()) return std::nullopt;
  return v;
}

inline Result<std::uint64_t> file_size(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (ec || !std::filesystem::exists(status)) {
    return Error{ErrorCode::kNotFound, path + ": cannot open: file not found"};
  }
  if (!std::filesystem::is_regular_file(status)) {
    return invalid(path + ": cannot read: not a regular file");
  }
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) return Error{ErrorCode::kSystem, path + ": cannot read its size: " + ec.message()};
  return static_cast<std::uint64_t>(size);
}

template <class T>
inline T load_elem(const unsigned char* p, bool swap) {
  unsigned char b[sizeof(T)];
  std::memcpy(b, p, sizeof(T));
  if (swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

template <class T>
inline void convert_range(const unsigned char* src, float* dst, std::size_t n, bool swap) {
  for (std::size_t i = 0; i < n; ++i) dst[i] = static_cast<float>(load_elem<T>(src + i * sizeof(T), swap));
}

// Converts the file's elements to floats in chunks, reporting progress from p0 to p1 (on the
// caller's thread). Each value is written once (VoxelArray does not zero it first), each chunk in
// two halves on two threads for a large volume: the first touch of the new pages, most of the
// cost, is shared by the two cores.
inline VoxelArray convert(const std::vector<unsigned char>& bytes, const ElemInfo& elem, bool big_endian, std::size_t count,
                          const Progress& progress, double p0, double p1) {
  constexpr bool kHostLittle = std::endian::native == std::endian::little;
  const bool swap = big_endian == kHostLittle && elem.bytes > 1;
  VoxelArray out(count);
  const bool two = worth_two_threads(count);
  const std::size_t chunk = std::max<std::size_t>(kMinChunk, count / kProgressSteps + 1);
  for (std::size_t start = 0; start < count; start += chunk) {
    const std::size_t n = std::min(chunk, count - start);
    in_two_halves(n, two, [&](std::size_t begin, std::size_t end, int) {
      const unsigned char* s = bytes.data() + (start + begin) * elem.bytes;
      float* d = out.data() + start + begin;
      const std::size_t m = end - begin;
      switch (elem.elem) {
        case Elem::kU8: convert_range<std::uint8_t>(s, d, m, swap); break;
        case Elem::kI8: convert_range<std::int8_t>(s, d, m, swap); break;
        case Elem::kI16: convert_range<std::int16_t>(s, d, m, swap); break;
        case Elem::kU16: convert_range<std::uint16_t>(s, d, m, swap); break;
        case Elem::kI32: convert_range<std::int32_t>(s, d, m, swap); break;
        case Elem::kU32: convert_range<std::uint32_t>(s, d, m, swap); break;
        case Elem::kF32: convert_range<float>(s, d, m, swap); break;
        case Elem::kF64: convert_range<double>(s, d, m, swap); break;
      }
    });
    report(progress, p0 + (p1 - p0) * static_cast<double>(start + n) / static_cast<double>(count));
  }
  return out;
}

/// The first min(size, max_bytes) bytes of the file at path: a header to parse. kNotFound when it
/// cannot be opened.
inline Result<std::string> read_header_text(const std::string& path, std::uint64_t size, std::size_t max_bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{ErrorCode::kNotFound, path + ": cannot open for reading"};
  std::string text(static_cast<std::size_t>(std::min<std::uint64_t>(size, max_bytes)), '\0');
  in.read(text.data(), static_cast<std::streamsize>(text.size()));
  text.resize(static_cast<std::size_t>(std::max<std::streamsize>(0, in.gcount())));
  return text;
}

/// Runs a loader, turning an exception from deep inside it (allocation, filesystem) into an Error
/// that names the file: loaders return errors, they never throw at their callers.
template <class Load>
auto load_catching(const std::string& path, Load&& load) -> decltype(load()) {
  try {
    return load();
  } catch (const std::bad_alloc&) {
    return Error{ErrorCode::kSystem, path + ": out of memory while loading the volume"};
  } catch (const std::exception& e) {
    return Error{ErrorCode::kSystem, path + ": " + e.what()};
  }
}

}  // namespace lancet::volume::detail
