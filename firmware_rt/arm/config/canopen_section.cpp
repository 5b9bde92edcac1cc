// [bus.canopen]: the CiA 402 drives on SocketCAN: interface, nodes, timing, objects and PDOs.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>

#include "arm/config/sections.hpp"
#include "arm/config/units.hpp"

namespace lancet::arm::detail {

namespace {

struct PdoParse {
  std::vector<PdoConfig> pdos;
  // every object mapped at subindex 0, with its width
  struct Mapped {
    std::uint16_t index;
    std::uint8_t bits;
  };
  std::vector<Mapped> mapped;
  bool complete = true;  // false when some entry could not be read (skip the "is it mapped" checks)
};

PdoParse parse_pdos(Section& s, std::string_view key, std::string_view label) {
  PdoParse out;
  const auto pdos = s.tables(key, kReq, 1, 4);
  if (!pdos) {
    out.complete = false;
    return out;
  }
  config::UniqueValues<std::int64_t> numbers(s.field(key), std::string(label) + " number");
  for (std::size_t i = 0; i < pdos->size(); ++i) {
    const toml::table* t = (*pdos)[i];
    if (t == nullptr) {
      out.complete = false;
      continue;
    }
    Section p(s.sink(), *t, indexed(s.field(key), i));
    PdoConfig pc;
    if (auto n = p.integer("number", kReq, 1, 4)) {
      numbers.check(p, "number", *n, i);
      pc.number = static_cast<int>(*n);
    } else {
      out.complete = false;
    }
    pc.sync_divider = static_cast<int>(p.integer("sync_divider", kOpt, 1, 240).value_or(1));
    const std::string expected = "an array of 1..8 inline tables { index, subindex, bits }";
    if (const toml::array* entries = p.array("entries", kReq, expected)) {
      if (entries->empty() || entries->size() > 8) {
        p.sink().add(entries->source(), p.field("entries"), expected, describe(*entries));
      }
      int total_bits = 0;
      for (std::size_t e = 0; e < entries->size(); ++e) {
        const toml::node& en = *entries->get(e);
        const std::string ef = indexed(p.field("entries"), e);
        const auto* et = en.as_table();
        if (et == nullptr) {
          p.sink().add(en.source(), ef, "a table { index, subindex, bits }", describe(en));
          out.complete = false;
          continue;
        }
        Section es(s.sink(), *et, ef);
        const auto index = es.integer("index", kReq, 0x1000, 0xFFFF, true);
        const auto sub = es.integer("subindex", kReq, 0, 255);
        const std::int64_t widths[] = {8, 16, 32};
        const auto bits = es.integer_in("bits", kReq, widths);
        es.finish();
        if (!index || !sub || !bits) {
          out.complete = false;
          continue;
        }
        total_bits += static_cast<int>(*bits);
        pc.entries.push_back({static_cast<std::uint16_t>(*index), static_cast<std::uint8_t>(*sub),
                              static_cast<std::uint8_t>(*bits)});
        if (*sub == 0) out.mapped.push_back({static_cast<std::uint16_t>(*index), static_cast<std::uint8_t>(*bits)});
      }
      if (total_bits > 64) {
        p.sink().add(entries->source(), p.field("entries"), "at most 64 bits of mapped objects (one CAN frame)",
                     std::to_string(total_bits) + " bits");
      }
    } else {
      out.complete = false;
    }
    p.finish();
    out.pdos.push_back(std::move(pc));
  }
  return out;
}

// The driver needs these objects in PDOs of the right direction and width.
void check_pdo_objects(Section& s, const Cia402Objects& objects, const PdoParse& rp, const PdoParse& tp, bool has_buttons) {
  struct Need402 {
    const char* what;
    std::uint16_t index;
    std::uint8_t bits;
    bool in_tpdo;
    bool needed;
  };
  const Need402 needs[] = {
      {"controlword", objects.controlword, 16, false, true},
      {"target_torque", objects.target_torque, 16, false, true},
      {"statusword", objects.statusword, 16, true, true},
      {"position_actual", objects.position_actual, 32, true, true},
      {"digital_inputs", objects.digital_inputs, 32, true, has_buttons},
  };
  for (const auto& nd : needs) {
    const PdoParse& p = nd.in_tpdo ? tp : rp;
    if (!nd.needed || !p.complete) continue;
    const std::string key = nd.in_tpdo ? "tpdo" : "rpdo";
    const auto it = std::find_if(p.mapped.begin(), p.mapped.end(), [&](const auto& m) { return m.index == nd.index; });
    const std::string expected = std::string(nd.what) + " (" + num(nd.index, true) + ":00, " +
                                 std::to_string(nd.bits) + " bits) mapped in a " + (nd.in_tpdo ? "TPDO" : "RPDO");
    if (it == p.mapped.end()) {
      s.sink().add(s.where(key), s.field(key), expected, "it in no " + std::string(nd.in_tpdo ? "TPDO" : "RPDO"));
    } else if (it->bits != nd.bits) {
      s.sink().add(s.where(key), s.field(key), expected, "it mapped with " + std::to_string(it->bits) + " bits");
    }
  }
}

}  // namespace

CanopenBusConfig parse_canopen(Section& s, const Context& ctx, bool has_buttons, std::optional<int>& button_bits) {
  CanopenBusConfig c;
  c.interface_name = s.text("interface", kReq, 15).value_or("");
  const std::int64_t rates[] = {10'000, 20'000, 50'000, 125'000, 250'000, 500'000, 800'000, 1'000'000};
  c.bitrate = static_cast<int>(s.integer_in("bitrate", kReq, rates).value_or(1'000'000));
  c.mode = s.choice<Cia402Mode>("mode", kOpt, {{"cst", Cia402Mode::kCyclicSyncTorque}, {"tq", Cia402Mode::kProfileTorque}})
               .value_or(Cia402Mode::kCyclicSyncTorque);
  c.sync_period = s.number("sync_period_us", kOpt, Range{100, 100'000}).value_or(1000) * kUs;
  c.heartbeat_period = s.number("heartbeat_ms", kOpt, Range{0, 65'535}).value_or(100) * kMs;
  // 0x1006 takes whole µs, and cyclic synchronous mode writes the period to 0x60C2 as value · 10^index s
  // with value 1..255: 1000 µs is 1 · 10^-3, 2500 µs is 25 · 10^-4, 333 µs has no exact form.
  if (const toml::node* sp = s.has("sync_period_us") ? s.get("sync_period_us") : nullptr) {
    const double us = c.sync_period * 1e6;
    std::int64_t mantissa = std::llround(us);
    if (std::abs(us - static_cast<double>(mantissa)) > 1e-6) {
      s.sink().add(sp->source(), s.field("sync_period_us"), "a whole number of microseconds (0x1006 is in µs)", describe(*sp));
    } else if (c.mode == Cia402Mode::kCyclicSyncTorque) {
      while (mantissa % 10 == 0 && mantissa > 0) mantissa /= 10;
      if (mantissa > 255) {
        s.sink().add(sp->source(), s.field("sync_period_us"),
                     "a period 0x60C2 (interpolation time) can express exactly: value · 10^index s with value 1..255 "
                     "(e.g. 1000, 2500, 250, 125)", describe(*sp));
      }
    }
  }
  c.master_node_id = static_cast<int>(s.integer("master_node_id", kOpt, 1, 127).value_or(127));
  c.sync_producer = s.boolean("sync_producer", kOpt).value_or(true);
  const std::optional<std::int64_t> watchdog_ms = s.integer("drive_watchdog_ms", kOpt, 0, 65'535);
  c.drive_watchdog = static_cast<double>(watchdog_ms.value_or(100)) * kMs;
  if (watchdog_ms && *watchdog_ms > 0) {
    // The master's heartbeat goes out every drive_watchdog_ms / 4, from the servo tick: at least a SYNC period.
    const double floor_ms = std::max(10.0, 4.0 * c.sync_period * 1e3);
    if (static_cast<double>(*watchdog_ms) < floor_ms) {
      s.sink().add(s.where("drive_watchdog_ms"), s.field("drive_watchdog_ms"),
                   "0 (off) or at least " + num(static_cast<std::int64_t>(std::ceil(floor_ms))) +
                       " ms (10 ms and 4 SYNC periods: the master's heartbeat goes out every drive_watchdog_ms / 4)",
                   "integer " + num(*watchdog_ms));
    }
  }

  const std::string ids_expected = ctx.n ? "an array of " + std::to_string(*ctx.n) + " node ids (one per joint)"
                                         : "an array of node ids (one per joint)";
  if (const toml::array* ids = s.array("node_ids", kReq, ids_expected)) {
    if (ctx.n && ids->size() != static_cast<std::size_t>(*ctx.n)) {
      s.sink().add(ids->source(), s.field("node_ids"), ids_expected, describe(*ids));
    }
    for (std::size_t i = 0; i < ids->size(); ++i) {
      const std::string f = indexed(s.field("node_ids"), i);
      const auto id = read_integer(s.sink(), *ids->get(i), f, 1, 127);
      if (!id) continue;
      if (std::find(c.node_ids.begin(), c.node_ids.end(), *id) != c.node_ids.end()) {
        s.sink().add(ids->get(i)->source(), f, "a node id not used by another joint", describe(*ids->get(i)));
      }
      c.node_ids.push_back(static_cast<int>(*id));
    }
  }
  if (std::find(c.node_ids.begin(), c.node_ids.end(), c.master_node_id) != c.node_ids.end()) {
    s.sink().add(s.where("master_node_id"), s.field("master_node_id"), "a node id that no drive uses (the host's own)",
                 "integer " + num(std::int64_t{c.master_node_id}) + (s.has("master_node_id") ? "" : " (the default), one of node_ids"));
  }
  if (auto b = s.integer("buttons_node", kOpt, 1, 127)) {
    c.buttons_node = static_cast<int>(*b);
    if (!c.node_ids.empty() && std::find(c.node_ids.begin(), c.node_ids.end(), *b) == c.node_ids.end()) {
      s.sink().add(s.where("buttons_node"), s.field("buttons_node"), "one of node_ids",
                   "integer " + num(*b));
    }
  }

  if (const toml::table* ot = s.table("objects", kOpt)) {
    Section o(s.sink(), *ot, s.field("objects"));
    auto idx = [&](std::string_view k, std::uint16_t dflt) {
      return static_cast<std::uint16_t>(o.integer(k, kOpt, 0x1000, 0xFFFF, true).value_or(dflt));
    };
    c.objects.controlword = idx("controlword", c.objects.controlword);
    c.objects.statusword = idx("statusword", c.objects.statusword);
    c.objects.position_actual = idx("position_actual", c.objects.position_actual);
    c.objects.target_torque = idx("target_torque", c.objects.target_torque);
    c.objects.digital_inputs = idx("digital_inputs", c.objects.digital_inputs);
    o.finish();
  }

  PdoParse rp = parse_pdos(s, "rpdo", "RPDO");
  PdoParse tp = parse_pdos(s, "tpdo", "TPDO");
  c.rpdos = std::move(rp.pdos);
  c.tpdos = std::move(tp.pdos);

  check_pdo_objects(s, c.objects, rp, tp, has_buttons);
  button_bits = 32;
  s.finish();
  return c;
}

}  // namespace lancet::arm::detail
