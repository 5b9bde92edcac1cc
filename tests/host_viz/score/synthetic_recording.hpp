#pragma once
// Synthetic recordings for the metrics and report tests: a 1 kHz tick stream whose tool path,
// stages, forces and events the test sets, and small scenarios to score them against.

#include <cstdint>
#include <functional>
#include <string>

#include "recording/recording.hpp"
#include "scenarios/scenario.hpp"

namespace lancet::record::test {

inline constexpr std::int64_t kT0Ns = 5'000'000'000;  // an arbitrary CLOCK_MONOTONIC start
inline constexpr std::int64_t kPeriodNs = 1'000'000;

/// n ticks at 1 kHz (seq 1..n, t = kT0Ns + i ms), in contact (Stage::kDeform) at the origin with
/// zero force; `each(i, t_s, sample)` then sets what the test needs.
inline Recording make_recording(std::size_t n, const std::function<void(std::size_t, double, ToolSample&)>& each = {}) {
  Recording r;
  r.lancet_version = "test";
  r.created = "2025-01-02T03:04:05Z";
  r.scenario_name = "synthetic";
  r.period_ns = kPeriodNs;
  r.samples.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    ToolSample s{};
    s.seq = i + 1;
    s.t_ns = kT0Ns + static_cast<std::int64_t>(i) * kPeriodNs;
    s.mode = ToolMode::kScalpel;
    s.stage = Stage::kDeform;
    s.tool.orientation = Quat{};
    if (each) each(i, static_cast<double>(i) * 1e-3, s);
    s.proxy = s.tool;
    r.samples[i] = s;
  }
  return r;
}

/// n ticks at 1 kHz of two hands (hands = 2): each tick's right sample, then its left one, both
/// with the tick's seq (1..n) and time (kT0Ns + i ms), as make_recording's; `each(i, t_s, sample)`
/// sets what the test needs (sample.hand says whose it is).
inline Recording make_two_hand_recording(std::size_t n, const std::function<void(std::size_t, double, ToolSample&)>& each = {}) {
  Recording r = make_recording(0);
  r.hands = 2;
  r.samples.reserve(2 * n);
  for (std::size_t i = 0; i < n; ++i) {
    for (const Hand h : {Hand::kRight, Hand::kLeft}) {
      ToolSample s{};
      s.seq = i + 1;
      s.t_ns = kT0Ns + static_cast<std::int64_t>(i) * kPeriodNs;
      s.mode = h == Hand::kRight ? ToolMode::kScalpel : ToolMode::kRetractor;
      s.stage = Stage::kDeform;
      s.hand = h;
      s.tool.orientation = Quat{};
      if (each) each(i, static_cast<double>(i) * 1e-3, s);
      s.proxy = s.tool;
      r.samples.push_back(s);
    }
  }
  return r;
}

/// Marks a kCutProgress event every 0.5 mm of x travel while cutting, as the scalpel's step does
/// (payload: the tool's position).
inline void mark_cut_progress(Recording& rec) {
  double last_x = -1;
  for (ToolSample& s : rec.samples) {
    if (s.stage != Stage::kCutting || s.tool.position.x - last_x < 0.0005) continue;
    s.events |= event::kCutProgress;
    s.payload = EventPayload{s.tool.position, 0};
    last_x = s.tool.position.x;
  }
}

/// A valid incision scenario: the line from (-15, -12) to (15, -12) mm, tolerance 3 mm, two
/// structures to avoid; `extra` is appended (a [score] section).
inline std::string incision_toml(const std::string& extra = {}) {
  return R"(schema_version = 1
name = "synthetic-incision"
tools = ["probe", "scalpel"]
[tissue]
source = "phantom"
[task]
kind = "incision"
line_mm = [[-15, -12, 0], [15, -12, 0]]
tolerance_mm = 3
[[avoid]]
name = "radial artery"
shape = "label"
label = 6
[[avoid]]
name = "nerve <b>"
shape = "sphere"
centre_mm = [0, 0, -20]
radius_mm = 2
)" + extra;
}

/// A valid drill scenario: a 10 mm window 4 mm deep at (0, 6, -32) mm.
inline std::string drill_toml(const std::string& extra = {}) {
  return R"(schema_version = 1
name = "synthetic-drill"
tools = ["probe", "drill"]
[tissue]
source = "phantom"
surface = "bone"
[task]
kind = "drill"
centre_mm = [0, 6, -32]
radius_mm = 5
depth_mm = 4
)" + extra;
}

/// Parses a scenario text that the test knows to be valid (an empty Scenario on failure, with the
/// message in `error`).
inline scenario::Scenario parse_or_fail(const std::string& text, std::string* error = nullptr) {
  auto r = scenario::parse_scenario(text, "synthetic.toml");
  if (!r.ok()) {
    if (error) *error = r.error().message;
    return {};
  }
  return std::move(r.value());
}

}  // namespace lancet::record::test
