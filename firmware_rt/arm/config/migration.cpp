#include "arm/config/migration.hpp"

#include <cmath>
#include <cstdint>
#include <optional>

namespace lancet::arm::detail {

void replaced_key(Section& s, std::string_view key, const std::string& now) {
  if (const toml::node* n = s.get(key)) {
    s.sink().add(n->source(), s.field(key), now, describe(*n), "\"" + std::string(key) + "\" was replaced: " + now);
  }
}

void replaced_control(Section& r, bool modbus) {
  const toml::node* n = r.has("control") ? r.get("control") : nullptr;
  if (n == nullptr) return;
  std::string place = modbus ? "table = \"holding\", address = N" : "offset = N";
  std::string type = modbus ? "u16" : "u8";
  if (const auto* t = n->as_table()) {
    const char* key = modbus ? "address" : "offset";
    if (const auto v = t->get(key) ? t->get(key)->value<std::int64_t>() : std::nullopt)
      place = modbus ? "table = \"holding\", address = " + num(*v) : "offset = " + num(*v);
    if (const auto v = t->get("type") ? t->get("type")->value<std::string>() : std::nullopt) type = *v;
  }
  const std::string head = "{ " + place + ", type = \"" + type + "\", ";
  replaced_key(r, "control", "enable = " + head + "on = 1, off = 0 } and fault_reset = " + head + "value = 2 } (the old control bits 0 and 1)");
}

void replaced_scale_keys(Section& f, bool modbus) {
  if (const toml::node* n = f.has("lsb_ma") ? f.get("lsb_ma") : nullptr) {
    std::string now = "scale = A per count (lsb_ma = 1.0 is scale = 0.001)";
    if (const auto v = n->value<double>(); v && std::isfinite(*v)) now = "scale = " + num(*v * 1e-3) + " (A per count; lsb_ma was mA per count)";
    replaced_key(f, "lsb_ma", now);
  }
  if (modbus) replaced_key(f, "offset", "bias (physical = scale * raw + bias; the register is `address`)");
}

}  // namespace lancet::arm::detail
