#include "haptics/haptic_step.hpp"

#include <algorithm>

#include "haptics/tool_steps.hpp"

namespace lancet::haptics {

HapticModel HapticModel::defaults() {
  HapticModel m;
  //                     k      D    yield  mu_s  mu_d  along across density
  const MaterialParams skin{600, 1.0, 3.0, 0.5, 0.3, 2.0, 20.0, 1100};
  const MaterialParams vessel{300, 0.8, 1.5, 0.3, 0.2, 1.5, 15.0, 1060};
  m.materials.fill(skin);
  m.materials[2] = vessel;
  return m;
}

const MaterialParams& detail::material(const HapticModel& m, std::uint32_t id) noexcept {
  return m.materials[std::min<std::size_t>(id, kMaxMaterials - 1)];
}

const PatchBvh* detail::patch_tree(const HapticData& d, const HapticInput& in) noexcept {
  if (in.patch == nullptr || in.patch_version == 0) return nullptr;
  if (in.tree != nullptr && in.tree->version == in.patch_version) return in.tree;
  return d.bvh.version == in.patch_version ? &d.bvh : nullptr;
}

void haptic_step(const HapticModel& m, HapticData& d, const HapticInput& in, HapticOutput& out) noexcept {
  out = HapticOutput{};
  const bool new_patch = in.patch != nullptr && in.patch_version != 0 && in.patch_version != d.patch_version;
  if (new_patch) {
    d.patch_version = in.patch_version;
    if (in.tree == nullptr || in.tree->version != in.patch_version) build_patch_bvh(d.bvh, *in.patch, in.patch_version);
  }
  Vec3 prev_proxy = d.initialised ? d.proxy : in.device;
  d.initialised = true;
  // The riding proxy: a proxy resting on the surface moves with the triangle under it when a newer
  // patch moves that triangle (tool_steps' probe_step anchors it every tick it rests).
  ProbeData& probe = d.probe;
  if (new_patch && probe.anchor.valid && d.contact && d.stage == Stage::kDeform) {
    if (carry_proxy(*in.patch, detail::patch_tree(d, in), probe.anchor, prev_proxy, m.ride_max_move + 4 * m.proxy_radius, m.ride_max_move,
                    prev_proxy)) {
      ++probe.carried;
    } else {
      ++probe.carry_lost;
    }
  }
  probe.anchor.valid = false;

  if (d.stage == Stage::kRupture) d.stage = Stage::kCutting;  // rupture lasts one tick
  if (d.retractor.grabbed && in.mode != ToolMode::kRetractor) {  // changing tools lets go
    d.retractor.grabbed = false;
    d.stage = Stage::kFree;
    out.events |= event::kRelease;
  }

  Vec3 raw{};
  if (in.mode == ToolMode::kDrill && in.patch != nullptr && in.patch->brick.valid == 1) {
    raw = detail::drill_step(m, d, in, prev_proxy, out);
  } else if (in.mode == ToolMode::kRetractor && (d.retractor.grabbed || in.patch != nullptr)) {
    raw = detail::retractor_step(m, d, in, out);
  } else if (d.stage == Stage::kCutting) {
    raw = detail::scalpel_step(m, d, in, prev_proxy, out);
  } else if (in.patch != nullptr) {
    raw = detail::probe_step(m, d, in, prev_proxy, out);
  } else {
    d.proxy = in.device;  // no tissue known: the proxy follows freely
    d.stage = Stage::kFree;
  }

  if (out.contact != d.contact) out.events |= out.contact ? event::kContactBegin : event::kContactEnd;
  d.contact = out.contact;
  out.force = apply_safety(m.safety, d.safety, raw, in.device, in.velocity, m.dt, out.events);
  out.proxy = d.proxy;
  out.stage = d.stage;
}

}  // namespace lancet::haptics
