#pragma once
// `lancetctl validate FILE`: checks an arm config (hw_configs/*.toml) against the schema and prints
// every problem as `file:line:col: field: message`, or a one-line summary when it is valid.

#include <cstdio>
#include <string>

namespace lancet::tools {

/// Validates the arm config at `path` and writes the report to `out`. Returns 0 when the config is
/// valid, 1 when it has errors, 2 when the file cannot be read.
int run_validate(const std::string& path, std::FILE* out);

}  // namespace lancet::tools
