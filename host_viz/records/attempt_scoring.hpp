#pragma once
// One recording made into an attempt: read (common/recording), scored by the project's one scorer
// (score::compute_metrics against the scenario the recording holds, as lancet-report does), keyed
// by the file's SHA-256.
// Tools only (allocates, reads the whole file).

#include <string>

#include "lancet/shared_model/result.hpp"
#include "records/store.hpp"

namespace lancet::records {

/// The attempt in the recording at `path`, for `trainee_id` ("" for none). Errors (each naming the
/// file): it cannot be read or is not a whole recording (corrupt, truncated); it was made without
/// a scenario; its scenario does not load in this build; `curriculum` has steps and none is the
/// recording's scenario (kInvalid, naming the scenario and the curriculum's).
[[nodiscard]] Result<Attempt> score_attempt(const std::string& path, const std::string& trainee_id, const Curriculum& curriculum);

}  // namespace lancet::records
