#include "text/text.hpp"

#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <system_error>

namespace lancet::text {
namespace {

// The length of the well-formed UTF-8 sequence of two or more bytes at s[i], and its code point;
// 0 when there is none there (a stray or missing continuation byte, an overlong form, a
// surrogate, or anything above U+10FFFF).
std::size_t utf8_sequence(std::string_view s, std::size_t i, std::uint32_t& cp) {
  const auto c = static_cast<unsigned char>(s[i]);
  std::size_t len = 0;
  if (c >= 0xc2 && c <= 0xdf) len = 2, cp = c & 0x1fu;
  else if (c >= 0xe0 && c <= 0xef) len = 3, cp = c & 0x0fu;
  else if (c >= 0xf0 && c <= 0xf4) len = 4, cp = c & 0x07u;
  if (len == 0 || i + len > s.size()) return 0;
  for (std::size_t k = 1; k < len; ++k) {
    const auto cc = static_cast<unsigned char>(s[i + k]);
    if ((cc & 0xc0u) != 0x80u) return 0;
    cp = (cp << 6) | (cc & 0x3fu);
  }
  const bool overlong = (len == 3 && cp < 0x800) || (len == 4 && cp < 0x10000);
  if (overlong || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff)) return 0;
  return len;
}

}  // namespace

std::string json_string(std::string_view s) {
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
      std::uint32_t cp = 0;
      const std::size_t n = utf8_sequence(s, i, cp);
      if (n != 0) {
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

std::string json_number(double v, int decimals) {
  if (!std::isfinite(v)) return "null";
  return format("%.*f", decimals, v);
}

std::string json_number(double v) { return std::isfinite(v) ? format("%.12g", v) : "null"; }

std::string xml_escape(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  std::size_t i = 0;
  while (i < s.size()) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c < 0x80) {
      switch (c) {
        case '&': out += "&amp;"; break;
        case '<': out += "&lt;"; break;
        case '>': out += "&gt;"; break;
        case '"': out += "&quot;"; break;
        case '\'': out += "&apos;"; break;
        default: out += (c < 0x20 || c == 0x7f) ? '?' : static_cast<char>(c);
      }
      ++i;
      continue;
    }
    // U+FFFE/U+FFFF and the C1 controls are not XML characters, even well-formed.
    std::uint32_t cp = 0;
    const std::size_t len = utf8_sequence(s, i, cp);
    const bool valid = len != 0 && cp != 0xfffe && cp != 0xffff && !(cp >= 0x80 && cp <= 0x9f);
    if (valid) {
      out.append(s.substr(i, len));
      i += len;
    } else {
      out += '?';
      ++i;
    }
  }
  return out;
}

std::string fixed(double v, int decimals) {
  std::array<char, 64> buf{};
  const auto [p, ec] = std::to_chars(buf.data(), buf.data() + buf.size(), v, std::chars_format::fixed, decimals);
  if (ec != std::errc{}) return format("%.*f", decimals, v);
  std::string s(buf.data(), p);
  if (s.size() > 1 && s[0] == '-' && s.find_first_not_of("-0.") == std::string::npos) s.erase(0, 1);
  return s;
}

}  // namespace lancet::text
