// The drill: volume haptics on the patch's voxel brick (volume_haptics.hpp); pressing harder than
// drill_min_force removes burr spheres at drill_rate·(|f| − min)·(2000 / ρ) per second, ρ = HU + 1000
// (haptic_step.hpp says why).
#include <algorithm>

#include "haptics/tool_steps.hpp"

namespace lancet::haptics::detail {

Vec3 drill_step(const HapticModel& m, HapticData& d, const HapticInput& in, Vec3 prev_proxy, HapticOutput& out) noexcept {
  DrillData& dr = d.drill;
  // The brick travels with each patch; keep our carved copy until the viz sends a newer one.
  if (in.patch->seq != dr.brick_seq) {
    dr.brick = in.patch->brick;
    dr.brick_seq = in.patch->seq;
    // Removals after the newest sample the viz had applied are not in it yet: carve them again.
    for (std::size_t i = 0; i < dr.n_carves; ++i) {
      const DrillData::Carve& c = dr.carves[(dr.carve_head + DrillData::kCarveMemory - dr.n_carves + i) % DrillData::kCarveMemory];
      if (c.tick > in.patch->samples_applied) {
        carve_sphere(dr.brick, c.centre, c.radius);
        ++dr.reapplied;
      }
    }
  }
  const VolumeContact vc = volume_proxy_step(dr.brick, m.drill_iso_hu, prev_proxy, in.device);
  d.proxy = vc.position;
  out.contact = vc.contact && dot(d.proxy - in.device, vc.normal) > 0;
  d.stage = out.contact ? Stage::kDrilling : Stage::kFree;
  const Vec3 raw = out.contact ? m.drill_stiffness * (d.proxy - in.device) : Vec3{};
  const double f = norm(raw);
  if (out.contact && f > m.drill_min_force) {
    // Denser tissue resists: removal slows in proportion to the density in front of the burr.
    // One removal takes about one voxel: the burr sphere, centred outside the contact, reaches
    // a voxel's depth into the bone.
    const double layer = std::min({dr.brick.spacing.x, dr.brick.spacing.y, dr.brick.spacing.z});
    const Vec3 front = d.proxy + (m.drill_burr_radius - layer) * vc.normal;
    const double density = std::max(100.0, sample_hu(dr.brick, d.proxy - layer * vc.normal) + 1000.0);  // ~kg/m³
    dr.progress += m.drill_rate * (f - m.drill_min_force) * m.dt * (2000.0 / density);
    if (dr.progress >= 1.0) {
      dr.progress -= 1.0;
      carve_sphere(dr.brick, front, m.drill_burr_radius);
      ++dr.removals;
      dr.carves[dr.carve_head] = DrillData::Carve{front, m.drill_burr_radius, in.tick};
      dr.carve_head = (dr.carve_head + 1) % DrillData::kCarveMemory;
      dr.n_carves = std::min(dr.n_carves + 1, DrillData::kCarveMemory);
      out.events |= event::kDrillRemove;
      out.payload = EventPayload{front, m.drill_burr_radius};
    }
  }
  return raw;
}

}  // namespace lancet::haptics::detail
