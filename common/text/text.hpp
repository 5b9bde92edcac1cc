#pragma once
// Text for machines and for people, written the same way by every tool: JSON strings and
// numbers, XML/HTML-escaped text, printf-style and fixed-point numbers that never depend on the
// locale.

#include <cstdio>
#include <string>
#include <string_view>

namespace lancet::text {

/// `s` as a JSON string literal (quotes included): quotes, backslashes and control bytes escaped;
/// bytes that are not well-formed UTF-8 (a path may hold any) become U+FFFD.
[[nodiscard]] std::string json_string(std::string_view s);

/// A JSON number with `decimals` digits after the point, or null for what JSON cannot hold.
[[nodiscard]] std::string json_number(double v, int decimals);
/// A JSON number with up to 12 significant digits, or null for what JSON cannot hold.
[[nodiscard]] std::string json_number(double v);

/// Text content or an attribute value for XML or HTML: & < > " ' escaped; control characters and
/// bytes that are not valid UTF-8 (neither is allowed in XML 1.0, even as references) become '?'.
[[nodiscard]] std::string xml_escape(std::string_view s);

/// `v` with `decimals` digits after the point, '.' whatever the locale, and no "-0".
[[nodiscard]] std::string fixed(double v, int decimals);

/// printf into a std::string, whatever its length.
template <class... Args>
[[nodiscard]] std::string format(const char* fmt, Args... args) {
  const int n = std::snprintf(nullptr, 0, fmt, args...);
  if (n <= 0) return {};
  std::string out(static_cast<std::size_t>(n) + 1, '\0');
  std::snprintf(out.data(), out.size(), fmt, args...);
  out.resize(static_cast<std::size_t>(n));
  return out;
}

}  // namespace lancet::text
