#pragma once
// The Device for an arm config's backend (configure time).

#include <memory>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "device/device.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::app {

struct MadeDevice {
  std::unique_ptr<device::Device> device;
};

/// The encoder plausibility limits of a config's joints (max speed, one count).
[[nodiscard]] device::Plausibility plausibility_of(const arm::ArmConfig& config);

/// sim: the in-process simulated arm. Backends not built into this binary are a clear error.
/// The device checks encoder plausibility with plausibility_of(config).
[[nodiscard]] Result<MadeDevice> make_device(const arm::ArmConfig& config);

}  // namespace lancet::app
