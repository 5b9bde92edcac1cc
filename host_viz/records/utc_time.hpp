#pragma once
// Times as the records write them: ISO 8601 UTC to the second ("2026-11-27T03:04:05Z"), the form
// recordings carry (Recording::created).

#include <ctime>
#include <string>

namespace lancet::records {

/// `t` as "YYYY-MM-DDTHH:MM:SSZ".
inline std::string iso_utc(std::time_t t) {
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

}  // namespace lancet::records
