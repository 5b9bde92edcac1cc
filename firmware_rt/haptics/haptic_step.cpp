#include "haptics/haptic_step.hpp"

#include <algorithm>
#include <cmath>

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

namespace {

const MaterialParams& material(const HapticModel& m, std::uint32_t id) {
  return m.materials[std::min<std::size_t>(id, kMaxMaterials - 1)];
}

// Follow fraction per tick of a proxy pulled by spring k through viscous drag D, integrated
// implicitly (D·v_proxy = k·(x_device − x_proxy,new)): k·dt/(D + k·dt), always in (0, 1], and
// the steady force at device speed v is exactly D·v.
double follow(double k, double drag, double dt) { return drag > 0 ? k * dt / (drag + k * dt) : 1.0; }

}  // namespace

void haptic_step(const HapticModel& m, HapticData& d, const HapticInput& in, HapticOutput& out) noexcept {
  out = HapticOutput{};
  const Vec3 prev_proxy = d.initialised ? d.proxy : in.device;
  d.initialised = true;
  Vec3 raw{};
  const MaterialParams* mat = &material(m, 1);

  if (d.stage == Stage::kRupture) d.stage = Stage::kCutting;  // rupture lasts one tick
  if (d.grabbed && in.mode != ToolMode::kRetractor) {  // changing tools lets go
    d.grabbed = false;
    d.stage = Stage::kFree;
    out.events |= event::kRelease;
  }

  if (in.mode == ToolMode::kDrill && in.patch != nullptr && in.patch->brick.valid == 1) {
    // The brick travels with each patch; keep our carved copy until the viz sends a newer one.
    if (in.patch->seq != d.brick_seq) {
      d.brick = in.patch->brick;
      d.brick_seq = in.patch->seq;
      // Removals after the newest sample the viz had applied are not in it yet: carve them again.
      for (std::size_t i = 0; i < d.n_carves; ++i) {
        const HapticData::Carve& c = d.carves[(d.carve_head + HapticData::kCarveMemory - d.n_carves + i) % HapticData::kCarveMemory];
        if (c.tick > in.patch->samples_applied) {
          carve_sphere(d.brick, c.centre, c.radius);
          ++d.reapplied;
        }
      }
    }
    const VolumeContact vc = volume_proxy_step(d.brick, m.drill_iso_hu, prev_proxy, in.device);
    d.proxy = vc.position;
    out.contact = vc.contact && dot(d.proxy - in.device, vc.normal) > 0;
    d.stage = out.contact ? Stage::kDrilling : Stage::kFree;
    raw = out.contact ? m.drill_stiffness * (d.proxy - in.device) : Vec3{};
    const double f = norm(raw);
    if (out.contact && f > m.drill_min_force) {
      // Denser tissue resists: removal slows in proportion to the density in front of the burr.
      // One removal takes about one voxel: the burr sphere, centred outside the contact, reaches
      // a voxel's depth into the bone.
      const double layer = std::min({d.brick.spacing.x, d.brick.spacing.y, d.brick.spacing.z});
      const Vec3 front = d.proxy + (m.drill_burr_radius - layer) * vc.normal;
      const double density = std::max(100.0, sample_hu(d.brick, d.proxy - layer * vc.normal) + 1000.0);  // ~kg/m³
      d.drill_progress += m.drill_rate * (f - m.drill_min_force) * m.dt * (2000.0 / density);
      if (d.drill_progress >= 1.0) {
        d.drill_progress -= 1.0;
        carve_sphere(d.brick, front, m.drill_burr_radius);
        ++d.removals;
        d.carves[d.carve_head] = HapticData::Carve{front, m.drill_burr_radius, in.tick};
        d.carve_head = (d.carve_head + 1) % HapticData::kCarveMemory;
        d.n_carves = std::min(d.n_carves + 1, HapticData::kCarveMemory);
        out.events |= event::kDrillRemove;
        out.payload = EventPayload{front, m.drill_burr_radius};
      }
    }
  } else if (in.mode == ToolMode::kRetractor && (d.grabbed || in.patch != nullptr)) {
    if (!d.grabbed) {
      // Nearest surface point; grab it when close enough.
      double best = m.snap_distance * m.snap_distance;
      bool found = false;
      const std::uint32_t n = std::min(in.patch->n_triangles, kPatchCapacity);
      for (std::uint32_t i = 0; i < n; ++i) {
        const PatchTriangle& t = in.patch->triangles[i];
        const Vec3 a = to_vec3(t.v[0]), b = to_vec3(t.v[1]), c = to_vec3(t.v[2]);
        if (!is_finite(a) || !is_finite(b) || !is_finite(c)) continue;
        const Vec3 q = closest_point_on_triangle(in.device, a, b, c);
        const double dist2 = dot(in.device - q, in.device - q);
        if (dist2 <= best) {
          best = dist2;
          found = true;
          d.control = q;
          d.cut_material = t.material;
        }
      }
      if (found) {
        d.grabbed = true;
        d.last_pull_event = in.device;
        out.events |= event::kGrab;
        out.payload = EventPayload{d.control, 0};
      }
    }
    if (d.grabbed) {
      mat = &material(m, d.cut_material);
      const Vec3 disp = in.device - d.control;
      const double len = norm(disp);
      if (len > m.elastic_limit * m.release_factor) {
        d.grabbed = false;  // the grip slips
        d.stage = Stage::kFree;
        d.proxy = in.device;
        out.events |= event::kRelease;
        out.payload = EventPayload{d.control, m.elastic_limit};
      } else {
        d.stage = Stage::kPulling;
        d.proxy = d.control;  // the magnetic snap: the hand is drawn to the control point
        raw = mat->stiffness * (d.control - in.device);
        out.contact = true;
        if (norm(in.device - d.last_pull_event) > 0.0005) {
          out.events |= event::kPull;
          out.payload = EventPayload{d.control, std::min(len, m.elastic_limit)};
          d.last_pull_event = in.device;
        }
      }
    } else {
      d.proxy = in.device;
      d.stage = Stage::kFree;
    }
  } else if (d.stage == Stage::kCutting) {
    mat = &material(m, d.cut_material);
    const Vec3 blade = rotate(in.orientation, m.blade_axis);
    // (1) cutting direction: the blade projected onto the surface.
    Vec3 u = normalized(blade - dot(blade, d.cut_normal) * d.cut_normal);
    if (u == Vec3{}) u = normalized(cross(d.cut_normal, Vec3{0, 0, 1}));
    // (2)-(4): follow along the cut (never backward) with low drag, sideways with high drag.
    const Vec3 mv = in.device - prev_proxy;
    const double along = dot(mv, u);
    const Vec3 side = mv - along * u;
    d.proxy = prev_proxy + (along > 0 ? follow(mat->stiffness, mat->cut_drag_along, m.dt) * along : 0.0) * u +
              follow(mat->stiffness, mat->cut_drag_across, m.dt) * side;
    raw = mat->stiffness * (d.proxy - in.device);
    out.contact = true;
    if (norm(d.proxy - d.last_cut_event) > 0.0005) {  // every 0.5 mm of cut
      out.events |= event::kCutProgress;
      out.payload = EventPayload{d.proxy, 0};
      d.last_cut_event = d.proxy;
    }
    // Exit: the device has come back out above the entry plane.
    if (dot(in.device - d.cut_entry, d.cut_normal) > m.proxy_radius) {
      d.stage = Stage::kFree;
      d.proxy = in.device;
      raw = Vec3{};
      out.contact = false;
      out.events |= event::kContactEnd;
    }
  } else if (in.patch != nullptr) {
    // A free proxy found inside the tissue (the stylus was below the surface before the tissue
    // around it arrived) starts on the surface, so the hand is pushed out, not ignored. The jump
    // is not a motion: velocities count from where it starts.
    const Vec3 start =
        d.contact ? prev_proxy : surface_entry(*in.patch, prev_proxy, m.proxy_radius, m.capture_depth);
    ProxyResult rf = update_proxy(*in.patch, start, in.device, m.proxy_radius, d.scratch);
    const Vec3 frictionless = rf.position;
    std::uint32_t tri_material = 1;
    if (rf.n_active > 0) tri_material = in.patch->triangles[rf.triangle].material;
    mat = &material(m, tri_material);
    apply_friction(rf, start, in.device, mat->friction_static, mat->friction_dynamic, d.sliding, d.scratch);
    d.sliding = rf.n_active > 0 && !rf.stuck && norm(rf.position - frictionless) > 0;
    d.proxy = rf.position;
    const Vec3 v_proxy = (1.0 / m.dt) * (d.proxy - start);
    out.contact = rf.n_active > 0 && dot(d.proxy - in.device, rf.normal) > 0;
    raw = out.contact ? mat->stiffness * (d.proxy - in.device) - mat->damping * (in.velocity - v_proxy) : Vec3{};
    if (out.contact && !(start == prev_proxy)) {
      // The spring found compressed on capture holds energy the hand put in before the tissue was
      // known: credit it to the passivity observer, or it would fight the push-out as if the
      // tissue were creating energy (and, with the hand nearly still, chatter).
      const Vec3 compressed = d.proxy - in.device;
      d.safety.energy -= 0.5 * mat->stiffness * dot(compressed, compressed);
    }
    d.stage = out.contact ? Stage::kDeform : Stage::kFree;
    // Rupture: a scalpel pressing harder than the material yields starts a cut, exactly once.
    if (out.contact && in.mode == ToolMode::kScalpel && norm(raw) > mat->yield_force) {
      d.stage = Stage::kRupture;
      d.cut_normal = rf.normal;
      d.cut_entry = d.proxy;
      d.cut_material = tri_material;
      d.last_cut_event = d.proxy;
      ++d.ruptures;
      out.events |= event::kRupture;
      out.payload = EventPayload{d.proxy, norm(raw)};
    }
  } else {
    d.proxy = in.device;  // no tissue known: the proxy follows freely
    d.stage = Stage::kFree;
  }

  if (out.contact != d.contact) out.events |= out.contact ? event::kContactBegin : event::kContactEnd;
  d.contact = out.contact;
  out.force = apply_safety(m.safety, d.safety, raw, in.device, in.velocity, in.patch ? in.patch_age_ns : -1, m.dt,
                           out.events);
  out.proxy = d.proxy;
  out.stage = d.stage;
}

}  // namespace lancet::haptics
