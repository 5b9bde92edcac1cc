#pragma once
// A curriculum file: the scenarios a trainee takes, in order, each with its progression rule
// (records/proficiency.hpp). TOML, read with common/config's schema reader:
//
//   schema_version = 1
//   name = "Open surgery basics"
//   [[step]]
//   scenario = "../../host_viz/scenarios/skin_incision.toml"  # a scenario file; relative paths
//                                                            # are taken from this file's folder
//   required = 3       # proficient attempts needed (1..100)
//   consecutive = 2    # of them in a row (1..required; default: required)
//
// Each scenario file is loaded (a missing or invalid one is an error naming the curriculum's line
// and the scenario's path); a step keeps the scenario's name and the SHA-256 of its text.
// Configure time only (allocates, reads files).

#include <string>
#include <string_view>

#include "lancet/shared_model/result.hpp"
#include "records/store.hpp"

namespace lancet::records {

/// Parses a curriculum; relative scenario paths are resolved against the folder of `source_name`.
/// Every problem at once in Error::message (ErrorCode::kInvalid), one a line, as
/// "<source_name>:<line>:<col>: <field>: ...".
[[nodiscard]] Result<Curriculum> parse_curriculum(std::string_view text, const std::string& source_name);
/// Reads the file and parses it.
[[nodiscard]] Result<Curriculum> load_curriculum(const std::string& path);

}  // namespace lancet::records
