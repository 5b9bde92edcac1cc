// The arm's own sections: [kinematics], [[joints]], [[actuators]], [safety], [[buttons]].

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

#include "arm/config/sections.hpp"
#include "arm/config/units.hpp"

namespace lancet::arm::detail {

namespace {

constexpr std::array<std::string_view, 9> kDeltaKeys{"a_mm", "b_mm", "c_mm", "d_mm", "e_mm", "f_mm", "r_mm", "s_mm",
                                                     "leg_angles_deg"};

// model = "delta": Stamper's dimensions and the three leg angles, then the geometry as a whole.
void parse_delta(Section& k, KinematicsConfig& out) {
  out.delta_axes = k.choice<DeltaAxes>("axes", kOpt, {{"model", DeltaAxes::kModel}, {"z_up", DeltaAxes::kZUp}}).value_or(DeltaAxes::kModel);
  constexpr Range kSigned{-10'000, 10'000};
  constexpr Range kLength{0, 10'000};
  const std::array<std::optional<double>, 8> mm{
      k.number("a_mm", kReq, positive_up_to(10'000)), k.number("b_mm", kReq, positive_up_to(10'000)),
      k.number("c_mm", kReq, kSigned), k.number("d_mm", kReq, kLength), k.number("e_mm", kReq, kLength),
      k.number("f_mm", kReq, kSigned), k.number("r_mm", kReq, kSigned), k.number("s_mm", kReq, kSigned)};
  DeltaGeometry& g = out.delta;
  std::array<double*, 8> dims{&g.a, &g.b, &g.c, &g.d, &g.e, &g.f, &g.r, &g.s};
  bool complete = true;
  for (std::size_t i = 0; i < mm.size(); ++i) {
    *dims[i] = mm[i].value_or(0) * kMm;
    complete = complete && mm[i].has_value();
  }
  const std::string expected = "an array of 3 numbers in [-360, 360] (one angle per leg)";
  if (const toml::array* a = k.array("leg_angles_deg", kReq, 3, 3, expected)) {
    for (std::size_t i = 0; i < 3; ++i) {
      const auto v = read_number(k.sink(), *a->get(i), indexed(k.field("leg_angles_deg"), i), Range{-360, 360});
      g.leg_angles[i] = v.value_or(0) * kDeg;
      complete = complete && v.has_value();
    }
  } else {
    complete = false;
  }
  if (!complete) return;
  if (const char* problem = delta_geometry_problem(g)) {
    k.sink().add(k.where(), "kinematics", "a delta geometry whose legs can be assembled", std::string("one where ") + problem);
  }
}

}  // namespace

void parse_kinematics(Section& k, KinematicsConfig& out, Context& ctx) {
  const auto model = k.choice<KinematicModel>(
      "model", kReq, {{"phantom", KinematicModel::kPhantom}, {"dh", KinematicModel::kDh}, {"delta", KinematicModel::kDelta}});
  if (auto v = k.vec3("base_offset_mm", kOpt, kMm)) out.base_offset = *v;
  if (!model) {
    k.skip({"l1_mm", "l2_mm", "links", "tool_offset_mm"});
    for (const std::string_view key : kDeltaKeys) k.skip({key});
    k.skip({"axes"});
    return;
  }
  out.model = *model;
  // Each model's own keys are errors under the others.
  if (*model != KinematicModel::kPhantom) {
    k.forbid("l1_mm", "model = \"phantom\"");
    k.forbid("l2_mm", "model = \"phantom\"");
  }
  if (*model != KinematicModel::kDh) {
    k.forbid("links", "model = \"dh\"");
    k.forbid("tool_offset_mm", "model = \"dh\"");
  }
  if (*model != KinematicModel::kDelta) {
    for (const std::string_view key : kDeltaKeys) k.forbid(key, "model = \"delta\"");
    k.forbid("axes", "model = \"delta\"");
  }
  if (*model == KinematicModel::kPhantom) {
    out.l1 = k.number("l1_mm", kReq, positive_up_to(10'000)).value_or(0) * kMm;
    out.l2 = k.number("l2_mm", kReq, positive_up_to(10'000)).value_or(0) * kMm;
  } else if (*model == KinematicModel::kDelta) {
    parse_delta(k, out);
  }
  if (*model != KinematicModel::kDh) {  // three revolute joints
    ctx.n = 3;
    ctx.types.assign(3, JointType::kRevolute);
    return;
  }
  if (auto v = k.vec3("tool_offset_mm", kOpt, kMm)) out.tool_offset = *v;
  const auto links = k.tables("links", kReq, 1, kMaxJoints);
  if (!links) return;
  bool all_typed = true;
  for (std::size_t i = 0; i < links->size(); ++i) {
    DhLink l;
    if ((*links)[i] == nullptr) {
      all_typed = false;
      out.links.push_back(l);
      continue;
    }
    Section s(k.sink(), *(*links)[i], indexed(k.field("links"), i));
    const auto type = s.choice<JointType>("type", kOpt, {{"revolute", JointType::kRevolute}, {"prismatic", JointType::kPrismatic}});
    if (s.has("type") && !type) all_typed = false;
    l.type = type.value_or(JointType::kRevolute);
    l.a = s.number("a_mm", kReq, kAny).value_or(0) * kMm;
    l.alpha = s.number("alpha_deg", kReq, Range{-360, 360}).value_or(0) * kDeg;
    l.d = s.number("d_mm", kReq, kAny).value_or(0) * kMm;
    l.theta_offset = s.number("theta_offset_deg", kReq, Range{-360, 360}).value_or(0) * kDeg;
    s.finish();
    out.links.push_back(l);
  }
  ctx.n = static_cast<int>(links->size());
  if (all_typed) {
    for (const auto& l : out.links) ctx.types.push_back(l.type);
  }
}

void parse_joints(Section& top, std::vector<JointConfig>& out, const Context& ctx) {
  const auto joints = top.tables("joints", kReq, 1, kMaxJoints);
  if (!joints) return;
  if (ctx.n && static_cast<std::size_t>(*ctx.n) != joints->size()) {
    top.sink().add(top.where("joints"), "joints",
                   std::to_string(*ctx.n) + " [[joints]] entries (one per joint of the kinematic model)",
                   std::to_string(joints->size()));
  }
  config::UniqueValues<std::string> names("joints", "name");
  for (std::size_t i = 0; i < joints->size(); ++i) {
    JointConfig j;
    const toml::table* t = (*joints)[i];
    if (t == nullptr) {
      out.push_back(j);
      continue;
    }
    const bool known_type = i < ctx.types.size();
    j.type = known_type ? ctx.types[i] : JointType::kRevolute;
    Section s(top.sink(), *t, indexed("joints", i));
    if (auto v = s.text("name", kReq, 64)) {
      j.name = *v;
      names.check(s, "name", *v, i);
    }
    j.counts_per_rev = s.integer("counts_per_rev", kReq, 1, std::int64_t{1} << 40).value_or(1);
    j.gear_ratio = s.number("gear_ratio", kReq, positive_up_to(1e6)).value_or(1);
    const std::int64_t dirs[] = {-1, 1};
    j.direction = static_cast<int>(s.integer_in("direction", kReq, dirs).value_or(1));
    if (!known_type) {
      // The model is broken: accept either unit family without judging it.
      s.skip({"offset_deg", "min_deg", "max_deg", "offset_mm", "min_mm", "max_mm", "lead_mm", "max_speed_deg_s",
              "max_speed_mm_s"});
    } else {
      const bool revolute = j.type == JointType::kRevolute;
      const JointFileUnit unit = joint_file_unit(j.type);
      const double scale = unit.to_si;
      const std::string o = unit.key("offset"), lo = unit.key("min"), hi = unit.key("max");
      const std::string why = revolute ? "prismatic joints; this joint is revolute in the kinematic model"
                                       : "revolute joints; this joint is prismatic in the kinematic model";
      static constexpr std::array<const char*, 5> kPrismaticOnly{"offset_mm", "min_mm", "max_mm", "lead_mm", "max_speed_mm_s"};
      static constexpr std::array<const char*, 4> kRevoluteOnly{"offset_deg", "min_deg", "max_deg", "max_speed_deg_s"};
      if (revolute) {
        for (const char* key : kPrismaticOnly) s.forbid(key, why);
      } else {
        for (const char* key : kRevoluteOnly) s.forbid(key, why);
      }
      j.offset = s.number(o, kOpt, kAny).value_or(0) * scale;
      const auto mn = s.number(lo, kReq, kAny);
      const auto mx = s.number(hi, kReq, kAny);
      if (mn && mx && !(*mn < *mx)) {
        s.sink().add(s.where(hi), s.field(hi), "a number > " + lo + " (" + num(*mn) + ")", describe(*t->get(hi)));
      }
      j.min = mn.value_or(0) * scale;
      j.max = mx.value_or(0) * scale;
      if (!revolute) j.lead = s.number("lead_mm", kReq, kPositive).value_or(0) * kMm;
      // Encoder plausibility: a reading that moved faster than this since the last one is a glitch.
      const std::string vmax = unit.key("max_speed") + "_s";
      j.max_speed = s.number(vmax, kOpt, kPositive).value_or(revolute ? JointConfig::kDefaultMaxSpeedDegS
                                                                       : JointConfig::kDefaultMaxSpeedMmS) *
                    scale;
    }
    s.finish();
    out.push_back(j);
  }
}

void parse_actuators(Section& top, std::vector<ActuatorConfig>& out, const Context& ctx) {
  const auto acts = top.tables("actuators", kReq, 1, kMaxJoints);
  if (!acts) return;
  if (ctx.n && static_cast<std::size_t>(*ctx.n) != acts->size()) {
    top.sink().add(top.where("actuators"), "actuators",
                   std::to_string(*ctx.n) + " [[actuators]] entries (one per joint of the kinematic model)",
                   std::to_string(acts->size()));
  }
  for (std::size_t i = 0; i < acts->size(); ++i) {
    ActuatorConfig a;
    const toml::table* t = (*acts)[i];
    if (t == nullptr) {
      out.push_back(a);
      continue;
    }
    Section s(top.sink(), *t, indexed("actuators", i));
    a.name = s.text("name", kOpt, 64).value_or("");
    a.torque_constant = s.number("torque_constant_nm_per_a", kReq, positive_up_to(100)).value_or(0);
    const auto peak = s.number("peak_current_a", kReq, positive_up_to(1000));
    const auto cont = s.number("continuous_current_a", kReq, positive_up_to(1000));
    if (peak && cont && *peak < *cont) {
      s.sink().add(s.where("peak_current_a"), s.field("peak_current_a"),
                   "a number >= continuous_current_a (" + num(*cont) + ")", describe(*t->get("peak_current_a")));
    }
    a.peak_current = peak.value_or(0);
    a.continuous_current = cont.value_or(0);
    s.finish();
    out.push_back(a);
  }
}

void parse_safety(Section& top, SafetyConfig& out, const Context& ctx) {
  const toml::table* t = top.table("safety", kReq);
  if (t == nullptr) return;
  Section s(top.sink(), *t, "safety");
  out.max_force = s.number("max_force_n", kReq, positive_up_to(1000)).value_or(0);
  const std::string tq_expected = ctx.n ? "an array of " + std::to_string(*ctx.n) + " numbers > 0 (one per joint)"
                                        : "an array of numbers > 0 (one per joint)";
  if (const toml::array* a = s.array("max_joint_torque_nm", kReq, tq_expected)) {
    if (ctx.n && a->size() != static_cast<std::size_t>(*ctx.n)) {
      s.sink().add(a->source(), s.field("max_joint_torque_nm"), tq_expected, describe(*a));
    }
    for (std::size_t i = 0; i < a->size(); ++i) {
      out.max_joint_torque.push_back(
          read_number(s.sink(), *a->get(i), indexed(s.field("max_joint_torque_nm"), i), positive_up_to(10'000)).value_or(0));
    }
  }
  out.max_slew = s.number("max_slew_n_per_s", kReq, Range{0, 1e9}).value_or(0);
  const auto wmin = s.vec3("workspace_min_mm", kReq, kMm);
  const auto wmax = s.vec3("workspace_max_mm", kReq, kMm);
  if (wmin && wmax) {
    const std::array<double, 3> lo{wmin->x, wmin->y, wmin->z}, hi{wmax->x, wmax->y, wmax->z};
    const toml::array* amax = t->get("workspace_max_mm")->as_array();
    for (std::size_t i = 0; i < 3; ++i) {
      if (!(lo[i] < hi[i])) {
        s.sink().add(amax->get(i)->source(), indexed(s.field("workspace_max_mm"), i),
                     "a number > workspace_min_mm[" + std::to_string(i) + "] (" + num(lo[i] / kMm) + ")",
                     describe(*amax->get(i)));
      }
    }
  }
  out.workspace_min = wmin.value_or(Vec3{});
  out.workspace_max = wmax.value_or(Vec3{});
  out.watchdog_period = s.number("watchdog_period_ms", kReq, positive_up_to(10'000)).value_or(0) * kMs;
  s.finish();
}

void parse_buttons(Section& top, std::vector<ButtonConfig>& out, const Context& ctx, std::optional<int> button_bits,
                   bool button_source_known) {
  const auto buttons = top.tables("buttons", kOpt, 0, 32);
  if (!buttons || buttons->empty()) return;
  if (button_source_known && !button_bits) {
    std::string source = "a button word in the bus section";
    if (ctx.backend == Backend::kUsb) source = "bus.usb.in_report.buttons";
    if (ctx.backend == Backend::kModbus) source = "bus.modbus.registers.buttons";
    top.sink().add(top.where("buttons"), "buttons", source + " for the buttons to come from", "none");
  }
  const std::int64_t max_bit = button_bits.value_or(32) - 1;
  config::UniqueValues<std::string> names("buttons", "name");
  config::UniqueValues<std::int64_t> bits("buttons", "bit");
  for (std::size_t i = 0; i < buttons->size(); ++i) {
    const toml::table* t = (*buttons)[i];
    if (t == nullptr) continue;
    Section s(top.sink(), *t, indexed("buttons", i));
    ButtonConfig b;
    if (auto v = s.text("name", kReq, 64)) {
      names.check(s, "name", *v, i);
      b.name = *v;
    }
    if (auto v = s.integer("bit", kReq, 0, max_bit)) {
      bits.check(s, "bit", *v, i);
      b.bit = static_cast<int>(*v);
    }
    b.action = s.choice<ButtonAction>("action", kOpt,
                                      {{"none", ButtonAction::kNone}, {"clutch", ButtonAction::kClutch},
                                       {"activate", ButtonAction::kActivate}, {"mode", ButtonAction::kMode}})
                   .value_or(ButtonAction::kNone);
    b.active_low = s.boolean("active_low", kOpt).value_or(false);
    s.finish();
    out.push_back(std::move(b));
  }
}

}  // namespace lancet::arm::detail
