#pragma once
// One sample of a scripted hand for the scene tests: tick `seq` (1 ms apart), the proxy and the
// tool where given, the events' payload at the proxy.

#include <cstdint>

#include "lancet/shared_model/messages.hpp"

namespace lancet::hybrid::test {

inline ToolSample scripted_sample(std::uint64_t seq, ToolMode mode, Stage stage, Vec3 proxy, Vec3 tool, std::uint32_t events) {
  ToolSample t{};
  t.seq = seq;
  t.t_ns = static_cast<std::int64_t>(seq) * 1'000'000;
  t.mode = mode;
  t.stage = stage;
  t.proxy.position = proxy;
  t.tool.position = tool;
  t.events = events;
  t.payload.position = proxy;
  return t;
}

}  // namespace lancet::hybrid::test
