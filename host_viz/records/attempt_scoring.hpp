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

/// lancet-report's page (score::report_html) for the recording at `path`, scored against the
/// scenario it holds, under the name `shown`. Errors name the file: it cannot be read (gone, say,
/// once its outbox entry was stored), or it holds no scenario this build reads.
[[nodiscard]] Result<std::string> attempt_report_html(const std::string& path, const std::string& shown);

}  // namespace lancet::records
