#pragma once
// A trainee's progress through the curriculum, and the records as CSV: pure functions of what the
// store returned (allocating; tools only).

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "records/proficiency.hpp"
#include "records/store.hpp"

namespace lancet::records {

struct StepProgress {
  CurriculumStep step;
  Standing standing;                ///< the step's rule applied to the trainee's attempts at its scenario
  std::size_t other_versions = 0;   ///< of those attempts, scored against another text of the scenario than the curriculum's
};

struct Progress {
  Trainee trainee;
  std::string curriculum;            ///< its name
  std::vector<StepProgress> steps;   ///< in curriculum order
  std::optional<std::size_t> next;   ///< the first step not yet proficient (none: the curriculum is done)
  std::size_t outside = 0;           ///< attempts at scenarios the curriculum does not have
};

/// `attempts` are the trainee's, in the order made (Store::attempts with a trainee filter).
[[nodiscard]] Progress progress(const Trainee& trainee, const Curriculum& curriculum, const std::vector<Attempt>& attempts);

/// Progress as text for a terminal: one line per step (attempts, passes, the rule, proficient or
/// not), then the next scenario.
[[nodiscard]] std::string progress_text(const Progress& p);

/// Every attempt's every metric as CSV (RFC 4180, a header row, one row per metric; an attempt
/// without metrics has one row with the metric columns empty). Numbers are locale-free, the shortest
/// text that reads back exactly; an unmeasured value or a missing band is empty.
[[nodiscard]] std::string export_csv(const std::vector<Attempt>& attempts, const std::vector<Trainee>& trainees);

}  // namespace lancet::records
