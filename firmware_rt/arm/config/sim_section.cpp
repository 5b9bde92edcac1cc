// [bus.sim]: the simulated arm's stylus and hand (all keys optional).

#include "arm/config/sections.hpp"

namespace lancet::arm::detail {

SimBusConfig parse_sim(Section& s) {
  SimBusConfig c;
  c.stylus_mass = s.number("stylus_mass_kg", kOpt, positive_up_to(100)).value_or(c.stylus_mass);
  c.hand_stiffness = s.number("hand_stiffness_n_per_m", kOpt, Range{0, 1e6}).value_or(c.hand_stiffness);
  c.hand_damping = s.number("hand_damping_ns_per_m", kOpt, Range{0, 1e5}).value_or(c.hand_damping);
  c.encoder_noise_counts = s.integer("encoder_noise_counts", kOpt, 0, 1'000'000).value_or(0);
  s.finish();
  return c;
}

}  // namespace lancet::arm::detail
