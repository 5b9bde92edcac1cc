#pragma once
// Values as error messages show them: quoted strings (escaped, cut at 48 characters), numbers,
// integer ranges, and the nearest known name to a misspelt one ("did you mean ...?"). Free of
// toml++; describe(const toml::node&) is in config/schema.hpp.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

namespace lancet::config {

/// `s` in double quotes: `"` and `\` escaped, control and non-ASCII bytes as \xNN, at most 48
/// characters shown (then "...").
[[nodiscard]] std::string quote(std::string_view s);
/// %g.
[[nodiscard]] std::string num(double v);
/// Decimal, or 0x%04X when `hex` and v >= 0.
[[nodiscard]] std::string num(std::int64_t v, bool hex = false);
/// "the integer N" or "an integer in lo..hi" (hex: bounds as 0x%04X).
[[nodiscard]] std::string int_range_text(std::int64_t lo, std::int64_t hi, bool hex = false);
/// `path[i]`.
[[nodiscard]] std::string indexed(const std::string& path, std::size_t i);

/// Optimal string alignment distance: insertions, deletions, substitutions and swaps of two
/// neighbouring characters ("nmae" is one edit from "name").
[[nodiscard]] std::size_t edit_distance(std::string_view a, std::string_view b);

/// The candidate closest to `word` when it is a plausible typo of it (fewer than 3 edits and
/// fewer than half the candidate's length); empty otherwise. `Names`: a range of things that
/// convert to std::string_view.
template <class Names>
[[nodiscard]] std::string_view nearest(std::string_view word, const Names& candidates) {
  std::string_view best;
  std::size_t best_d = 3;
  for (const auto& c : candidates) {
    const std::string_view cv(c);
    const std::size_t d = edit_distance(word, cv);
    if (d < best_d && d < std::max<std::size_t>(cv.size() / 2, 1)) {
      best_d = d;
      best = cv;
    }
  }
  return best;
}

}  // namespace lancet::config
