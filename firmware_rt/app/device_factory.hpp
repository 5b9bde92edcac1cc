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
  device::ArmPhysics* hand = nullptr;  ///< the simulated hand, for the sim backend (owned by device)
};

/// sim: the in-process simulated arm. Backends not built into this binary are a clear error.
[[nodiscard]] Result<MadeDevice> make_device(const arm::ArmConfig& config);

}  // namespace lancet::app
