// [bus]: the one section of the configured backend, read by that bus's parser; a section of
// another backend is an error.

#include "arm/config/sections.hpp"

namespace lancet::arm::detail {

std::string_view backend_key(Backend b) {
  switch (b) {
    case Backend::kSim: return "sim";
    case Backend::kUsb: return "usb";
    case Backend::kModbus: return "modbus";
    case Backend::kCanopen: return "canopen";
    case Backend::kFalcon: return "falcon";
  }
  return "sim";
}

void parse_bus(Section& top, ArmConfig& cfg, const Context& ctx, bool has_buttons, std::optional<int>& button_bits,
               bool& button_source_known) {
  const bool sim = ctx.backend == Backend::kSim;
  const toml::table* bt = top.table("bus", (ctx.backend && !sim) ? kReq : kOpt);
  // The button word is known once the backend's own section has been read (sim needs none).
  button_source_known = sim;
  if (sim) {
    cfg.sim = SimBusConfig{};
    button_bits = 32;
  }
  if (bt == nullptr) return;
  Section bus(top.sink(), *bt, "bus");
  const std::string_view keys[] = {"sim", "usb", "modbus", "canopen", "falcon"};
  const Backend kinds[] = {Backend::kSim, Backend::kUsb, Backend::kModbus, Backend::kCanopen, Backend::kFalcon};
  for (std::size_t i = 0; i < std::size(kinds); ++i) {
    const std::string_view key = keys[i];
    const bool matches = ctx.backend == kinds[i];
    const toml::node* n = bus.get(key);
    if (n == nullptr) {
      if (matches && !sim) bus.missing(key, "a table [bus." + std::string(key) + "] (backend = \"" + ctx.backend_name + "\")");
      continue;
    }
    if (ctx.backend && !matches) {
      top.sink().add(n->source(), bus.field(key),
                     "only [bus." + std::string(backend_key(*ctx.backend)) + "] (backend = \"" + ctx.backend_name + "\")",
                     "[bus." + std::string(key) + "], the section of backend \"" + std::string(key) + "\"");
      continue;
    }
    const toml::table* t = n->as_table();
    if (t == nullptr) {
      top.sink().add(n->source(), bus.field(key), "a table", describe(*n));
      continue;
    }
    Section s(top.sink(), *t, bus.field(key));
    std::optional<int> bits;
    switch (kinds[i]) {
      case Backend::kSim: cfg.sim = parse_sim(s); bits = 32; break;
      case Backend::kUsb: cfg.usb = parse_usb(s, ctx, bits); break;
      case Backend::kModbus: cfg.modbus = parse_modbus(s, ctx, bits); break;
      case Backend::kCanopen: cfg.canopen = parse_canopen(s, ctx, has_buttons, bits); break;
      case Backend::kFalcon: cfg.falcon = parse_falcon(s, ctx, bits); break;
    }
    if (matches) {
      button_bits = bits;
      button_source_known = true;
    }
  }
  bus.finish();
}

}  // namespace lancet::arm::detail
