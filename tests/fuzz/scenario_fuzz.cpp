// libFuzzer target: training scenarios (host_viz/scenarios TOML) through the loader, and a loaded
// scenario's task geometry. Any input must give a scenario or a report, never a crash, a hang or
// an escaping exception; a scenario that loads must satisfy the loader's promises.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <vector>

#include "scenarios/scenario.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lancet::scenario;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto r = parse_scenario(text, "fuzz/scenario.toml");
  if (!r.ok()) {
    if (r.error().message.empty()) std::abort();  // every failure says why
    return 0;
  }
  const Scenario& s = r.value();
  // The loader's promises: tools offered and the start tool among them, a task line with length.
  if (s.tools.empty() || s.tools.size() > 4) std::abort();
  bool start_offered = false;
  for (const auto t : s.tools) start_offered = start_offered || t == s.start_tool;
  if (!start_offered) std::abort();
  if (s.task == TaskKind::kIncision) {
    if (s.incision.line.size() < 2 || !(s.incision.tolerance > 0)) std::abort();
    // Progress of a cut along the task line itself stays in range.
    const auto p = incision_progress(s.incision, {s.incision.line});
    if (!(p.covered >= 0 && p.covered <= 1) || !(p.outside >= 0 && p.outside <= 1)) std::abort();
  }
  for (const Structure& st : s.avoid) (void)touches(st, s.drill.centre, s.drill.radius);
  return 0;
}
