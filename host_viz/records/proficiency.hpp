#pragma once
// The progression rule of a curriculum step, as MScore-style protocols state it: a trainee is
// proficient at a scenario after `required` proficient attempts, of which at least `consecutive`
// in a row (consecutive == required: all in a row; consecutive == 1: any `required` of them).
// Proficiency once reached stays: later attempts, passed or not, do not take it away.
//
// A pure function of the attempts' results in the order they were made; no allocation.

#include <cstddef>
#include <span>

namespace lancet::records {

struct ProficiencyRule {
  std::size_t required = 1;     ///< proficient attempts needed, >= 1
  std::size_t consecutive = 1;  ///< of them in a row, 1..required
};

/// Where a trainee stands on one scenario.
struct Standing {
  std::size_t attempts = 0;     ///< attempts made
  std::size_t passes = 0;       ///< of them proficient
  std::size_t longest_run = 0;  ///< most proficient attempts in a row
  std::size_t current_run = 0;  ///< proficient attempts in a row at the end
  bool proficient = false;      ///< the rule is met
  /// When proficient: the 1-based attempt at which the rule was first met (0 otherwise).
  std::size_t proficient_at = 0;
};

/// True when 1 <= consecutive <= required.
[[nodiscard]] constexpr bool valid(const ProficiencyRule& r) noexcept {
  return r.required >= 1 && r.consecutive >= 1 && r.consecutive <= r.required;
}

/// Applies `rule` (which must be valid) to the attempts' results in order (true: proficient attempt).
[[nodiscard]] Standing evaluate(const ProficiencyRule& rule, std::span<const bool> passed) noexcept;

}  // namespace lancet::records
