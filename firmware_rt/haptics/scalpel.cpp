// The scalpel's cut (ALGORITHMS.md §2): directional friction from the rupture until the blade
// comes back out above the entry plane.
#include "haptics/tool_steps.hpp"

namespace lancet::haptics::detail {

namespace {
// Follow fraction per tick of a proxy pulled by spring k through viscous drag D, integrated
// implicitly (D·v_proxy = k·(x_device − x_proxy,new)): k·dt/(D + k·dt), always in (0, 1], and
// the steady force at device speed v is exactly D·v.
double follow(double k, double drag, double dt) { return drag > 0 ? k * dt / (drag + k * dt) : 1.0; }
}  // namespace

Vec3 scalpel_step(const HapticModel& m, HapticData& d, const HapticInput& in, Vec3 prev_proxy, HapticOutput& out) noexcept {
  ScalpelData& c = d.scalpel;
  const MaterialParams& mat = material(m, c.material);
  const Vec3 blade = rotate(in.orientation, m.blade_axis);
  // (1) cutting direction: the blade projected onto the surface.
  Vec3 u = normalized(blade - dot(blade, c.normal) * c.normal);
  if (u == Vec3{}) u = normalized(cross(c.normal, Vec3{0, 0, 1}));
  // (2)-(4): follow along the cut (never backward) with low drag, sideways with high drag.
  const Vec3 mv = in.device - prev_proxy;
  const double along = dot(mv, u);
  const Vec3 side = mv - along * u;
  d.proxy = prev_proxy + (along > 0 ? follow(mat.stiffness, mat.cut_drag_along, m.dt) * along : 0.0) * u +
            follow(mat.stiffness, mat.cut_drag_across, m.dt) * side;
  Vec3 raw = mat.stiffness * (d.proxy - in.device);
  out.contact = true;
  if (norm(d.proxy - c.last_event) > 0.0005) {  // every 0.5 mm of cut
    out.events |= event::kCutProgress;
    out.payload = EventPayload{d.proxy, 0};
    c.last_event = d.proxy;
  }
  // Exit: the device has come back out above the entry plane.
  if (dot(in.device - c.entry, c.normal) > m.proxy_radius) {
    d.stage = Stage::kFree;
    d.proxy = in.device;
    raw = Vec3{};
    out.contact = false;
    out.events |= event::kContactEnd;
  }
  return raw;
}

}  // namespace lancet::haptics::detail
