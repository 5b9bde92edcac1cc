#pragma once
// One ToolSample as a scripted hand makes it (lancet-cut-script's scripts, the scene tests): the
// proxy and the tool where given, the events' payload at the proxy, everything else zero.

#include <cstdint>

#include "lancet/shared_model/messages.hpp"

namespace lancet::tissue {

inline ToolSample scripted_sample(std::uint64_t seq, std::int64_t t_ns, ToolMode mode, Stage stage, Vec3 proxy, Vec3 tool,
                                  std::uint32_t events) {
  ToolSample t{};
  t.seq = seq;
  t.t_ns = t_ns;
  t.mode = mode;
  t.stage = stage;
  t.proxy.position = proxy;
  t.tool.position = tool;
  t.events = events;
  t.payload.position = proxy;
  return t;
}

}  // namespace lancet::tissue
