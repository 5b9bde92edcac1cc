#pragma once
// One problem in a config file, and the report lines they make. Free of toml++: the loaders'
// public headers include this one, not config/schema.hpp.

#include <string>
#include <vector>

namespace lancet::config {

/// One problem in a config file. line and column are 1-based; 0 when the problem is with the file
/// as a whole (unreadable).
struct ConfigError {
  std::string file;
  int line = 0;
  int column = 0;
  std::string field;     ///< dotted path, e.g. joints[1].gear_ratio; empty for syntax errors
  std::string expected;  ///< what the schema wants (may be empty)
  std::string found;     ///< what the file has (may be empty)
  std::string message;   ///< the whole sentence, built from expected/found or a specific note
};

/// Orders errors by line, then column; errors at one place keep the order they were found in.
void sort_errors(std::vector<ConfigError>& errors);

/// One line per error, `file:line:col: field: message` (no field for syntax errors; `file:
/// message` when line is 0), each ending in '\n'. Empty when there is no error.
[[nodiscard]] std::string format_errors(const std::vector<ConfigError>& errors);

}  // namespace lancet::config
