// The progression rule (records/proficiency.hpp).

#include "records/proficiency.hpp"

#include <algorithm>
#include <cassert>

namespace lancet::records {

Standing evaluate(const ProficiencyRule& rule, std::span<const bool> passed) noexcept {
  assert(valid(rule) && "records::evaluate: the rule needs 1 <= consecutive <= required");
  Standing s;
  for (const bool p : passed) {
    ++s.attempts;
    s.current_run = p ? s.current_run + 1 : 0;
    if (p) ++s.passes;
    s.longest_run = std::max(s.longest_run, s.current_run);
    if (!s.proficient && s.passes >= rule.required && s.longest_run >= rule.consecutive) {
      s.proficient = true;
      s.proficient_at = s.attempts;
    }
  }
  return s;
}

}  // namespace lancet::records
