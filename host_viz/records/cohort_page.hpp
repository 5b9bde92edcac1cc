#pragma once
// A cohort at a glance, for its instructor: each trainee's current curriculum step, attempts and
// last attempt, and who is stuck (stuck_after or more attempts at the current step without
// meeting its rule); as text and as one self-contained HTML page (a table and a bar chart of how
// many trainees are on each step). Pure functions of what the store returned (allocating; tools
// only); everything from the records is HTML-escaped on the page.

#include <cstddef>
#include <string>
#include <vector>

#include "records/progress.hpp"

namespace lancet::records {

/// The default of `stuck_after`: attempts at one step without meeting its rule.
inline constexpr std::size_t kDefaultStuckAfter = 10;

struct CohortMember {
  Progress progress;          ///< progress.next: the current step (none: the curriculum is done)
  std::size_t attempts = 0;   ///< every attempt of the trainee's
  std::string last_attempt;   ///< when the latest attempt started (ISO 8601 UTC); "" without attempts
  std::size_t on_step = 0;    ///< attempts at the current step's scenario (0 when done)
  bool stuck = false;         ///< on_step >= stuck_after
};

struct Cohort {
  std::string name;
  std::string curriculum;              ///< its name
  std::vector<std::string> steps;      ///< the steps' scenarios, in order
  std::size_t stuck_after = kDefaultStuckAfter;
  std::vector<CohortMember> members;   ///< in the order of `trainees`
};

/// `trainees` are the cohort's; `attempts` theirs in the order made (Store::attempts with a cohort
/// filter; metrics are not needed). stuck_after >= 1.
[[nodiscard]] Cohort cohort(const std::string& name, const std::vector<Trainee>& trainees, const Curriculum& curriculum,
                            const std::vector<Attempt>& attempts, std::size_t stuck_after);

/// For a terminal: one line per trainee, then how many are on each step.
[[nodiscard]] std::string cohort_text(const Cohort& c);

/// The page: a table of the trainees (the stuck ones marked) and a bar chart per step.
[[nodiscard]] std::string cohort_html(const Cohort& c);

}  // namespace lancet::records
