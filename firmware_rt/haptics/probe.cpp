// The probe's contact (also the swab's, and the scalpel's until it ruptures the surface).
#include <cmath>

#include "haptics/tool_steps.hpp"

namespace lancet::haptics::detail {

Vec3 probe_step(const HapticModel& m, HapticData& d, const HapticInput& in, Vec3 prev_proxy, HapticOutput& out) noexcept {
  ProbeData& p = d.probe;
  // A free proxy found inside the tissue (the stylus was below the surface before the tissue
  // around it arrived) starts on the surface, so the hand is pushed out, not ignored. The jump
  // is not a motion: velocities count from where it starts.
  const PatchBvh* tree = patch_tree(d, in);
  const Vec3 start = d.contact ? prev_proxy : surface_entry(*in.patch, tree, prev_proxy, m.proxy_radius, m.capture_depth);
  ProxyResult rf = update_proxy(*in.patch, tree, start, in.device, m.proxy_radius, p.scratch);
  const Vec3 frictionless = rf.position;
  std::uint32_t tri_material = 1;
  if (rf.n_active > 0) tri_material = in.patch->triangles[rf.triangle].material;
  const MaterialParams& mat = material(m, tri_material);
  apply_friction(rf, start, in.device, mat.friction_static, mat.friction_dynamic, p.sliding, p.scratch);
  p.sliding = rf.n_active > 0 && !rf.stuck && norm(rf.position - frictionless) > 0;
  d.proxy = rf.position;
  const Vec3 v_proxy = (1.0 / m.dt) * (d.proxy - start);
  out.contact = rf.n_active > 0 && dot(d.proxy - in.device, rf.normal) > 0;
  const Vec3 raw = out.contact ? mat.stiffness * (d.proxy - in.device) - mat.damping * (in.velocity - v_proxy) : Vec3{};
  if (out.contact && !(start == prev_proxy)) {
    // The spring found compressed on capture holds energy the hand put in before the tissue was
    // known: credit it to the passivity observer, or it would fight the push-out as if the
    // tissue were creating energy (and, with the hand nearly still, chatter).
    const Vec3 compressed = d.proxy - in.device;
    d.safety.energy -= 0.5 * mat.stiffness * dot(compressed, compressed);
  }
  d.stage = out.contact ? Stage::kDeform : Stage::kFree;
  if (out.contact) p.anchor = anchor_proxy(*in.patch, rf.triangle, d.proxy);
  // Rupture: a scalpel pressing harder than the material yields starts a cut, exactly once.
  if (out.contact && in.mode == ToolMode::kScalpel && norm(raw) > mat.yield_force) {
    ScalpelData& c = d.scalpel;
    d.stage = Stage::kRupture;
    c.normal = rf.normal;
    c.entry = d.proxy;
    c.material = tri_material;
    c.last_event = d.proxy;
    ++c.ruptures;
    out.events |= event::kRupture;
    out.payload = EventPayload{d.proxy, norm(raw)};
  }
  return raw;
}

}  // namespace lancet::haptics::detail
