// The retractor (ALGORITHMS.md §2, thesis 4.2.4): snap, grab, pull, slip.
#include <algorithm>

#include "haptics/tool_steps.hpp"

namespace lancet::haptics::detail {

Vec3 retractor_step(const HapticModel& m, HapticData& d, const HapticInput& in, HapticOutput& out) noexcept {
  RetractorData& r = d.retractor;
  if (!r.grabbed && in.patch != nullptr) {
    // Nearest surface point; grab it when close enough.
    Vec3 q{};
    const std::uint32_t i = nearest_triangle(*in.patch, patch_tree(d, in), in.device, m.snap_distance, q);
    const bool found = i < std::min(in.patch->n_triangles, kPatchCapacity);
    if (found) {
      r.control = q;
      r.material = in.patch->triangles[i].material;
    }
    if (found) {
      r.grabbed = true;
      r.last_pull_event = in.device;
      out.events |= event::kGrab;
      out.payload = EventPayload{r.control, 0};
    }
  }
  if (!r.grabbed) {
    d.proxy = in.device;
    d.stage = Stage::kFree;
    return {};
  }
  const MaterialParams& mat = material(m, r.material);
  const Vec3 disp = in.device - r.control;
  const double len = norm(disp);
  if (len > m.elastic_limit * m.release_factor) {
    r.grabbed = false;  // the grip slips
    d.stage = Stage::kFree;
    d.proxy = in.device;
    out.events |= event::kRelease;
    out.payload = EventPayload{r.control, m.elastic_limit};
    return {};
  }
  d.stage = Stage::kPulling;
  d.proxy = r.control;  // the magnetic snap: the hand is drawn to the control point
  out.contact = true;
  if (norm(in.device - r.last_pull_event) > 0.0005) {
    out.events |= event::kPull;
    out.payload = EventPayload{r.control, std::min(len, m.elastic_limit)};
    r.last_pull_event = in.device;
  }
  return mat.stiffness * (r.control - in.device);
}

}  // namespace lancet::haptics::detail
