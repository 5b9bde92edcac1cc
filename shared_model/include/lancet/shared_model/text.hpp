#pragma once
// Small text helpers every tool needs the same way: a JSON string literal, and a 64-bit hash that
// mixes words in (for state hashes that must agree bit for bit between two runs).

#include <bit>
#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>

#include "lancet/shared_model/geometry.hpp"

namespace lancet {

/// `s` as a JSON string literal (quotes included): quotes, backslashes and control bytes escaped;
/// bytes that are not well-formed UTF-8 (a path may hold any) become U+FFFD.
inline std::string json_string(std::string_view s) {
  std::string out = "\"";
  for (std::size_t i = 0; i < s.size();) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += static_cast<char>(c);
      ++i;
    } else if (c < 0x20 || c == 0x7F) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(c));
      out += buf;
      ++i;
    } else if (c < 0x80) {
      out += static_cast<char>(c);
      ++i;
    } else {
      // A well-formed UTF-8 sequence is copied; anything else is replaced.
      const std::size_t n = c >= 0xF0 && c <= 0xF4 ? 4 : c >= 0xE0 && c <= 0xEF ? 3 : c >= 0xC2 && c <= 0xDF ? 2 : 0;
      bool ok = n != 0 && i + n <= s.size();
      for (std::size_t k = 1; ok && k < n; ++k) ok = (static_cast<unsigned char>(s[i + k]) & 0xC0) == 0x80;
      if (ok) {
        out.append(s.substr(i, n));
        i += n;
      } else {
        out += "\\ufffd";
        ++i;
      }
    }
  }
  return out + "\"";
}

/// A 64-bit hash built word by word (a multiply-xorshift mix, as in splitmix64). Doubles and
/// floats go in by their bits, so equal hashes mean bit-identical values. Real-time safe.
class WordHasher {
 public:
  explicit constexpr WordHasher(std::uint64_t seed = 0x9e3779b97f4a7c15ull) noexcept : h_(seed) {}
  constexpr void word(std::uint64_t w) noexcept {
    h_ ^= w + 0x9e3779b97f4a7c15ull + (h_ << 6) + (h_ >> 2);
    h_ ^= h_ >> 31;
    h_ *= 0xbf58476d1ce4e5b9ull;
  }
  void f(double x) noexcept { word(std::bit_cast<std::uint64_t>(x)); }
  void f(float x) noexcept { word(std::bit_cast<std::uint32_t>(x)); }
  void v(Vec3 p) noexcept { f(p.x), f(p.y), f(p.z); }
  constexpr void b(bool x) noexcept { word(x ? 1 : 0); }
  /// The hash, never 0 (0 means "no hash" where hashes are stored).
  [[nodiscard]] constexpr std::uint64_t value() const noexcept { return h_ != 0 ? h_ : 1; }

 private:
  std::uint64_t h_;
};

}  // namespace lancet
