#include "config/error.hpp"

#include <algorithm>
#include <utility>

namespace lancet::config {

void sort_errors(std::vector<ConfigError>& errors) {
  std::stable_sort(errors.begin(), errors.end(), [](const ConfigError& a, const ConfigError& b) {
    return std::pair(a.line, a.column) < std::pair(b.line, b.column);
  });
}

std::string format_errors(const std::vector<ConfigError>& errors) {
  std::string out;
  for (const ConfigError& e : errors) {
    out += e.file;
    if (e.line > 0) out += ":" + std::to_string(e.line) + ":" + std::to_string(e.column);
    out += ": ";
    if (!e.field.empty()) out += e.field + ": ";
    out += e.message;
    out += '\n';
  }
  return out;
}

}  // namespace lancet::config
