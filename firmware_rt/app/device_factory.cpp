#include "app/device_factory.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <utility>

#include "device/canopen_arm.hpp"
#include "device/falcon_arm.hpp"
#include "device/modbus_arm.hpp"
#include "device/sim_arm.hpp"
#include "device/usb_arm.hpp"

namespace lancet::app {

device::Plausibility plausibility_of(const arm::ArmConfig& config) {
  device::Plausibility p;
  p.n = std::min<int>(static_cast<int>(config.joints.size()), device::kMaxJoints);
  for (int j = 0; j < p.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const arm::JointConfig& jc = config.joints[uj];
    p.max_speed[uj] = jc.max_speed;
    p.resolution[uj] = std::abs(arm::joint_position_from_counts(jc, 1) - arm::joint_position_from_counts(jc, 0));
  }
  return p;
}

namespace {

// A backend's create() result as a MadeDevice (the error passed on as it is).
template <class Backend>
Result<MadeDevice> made(Result<std::unique_ptr<Backend>> created) {
  if (!created.ok()) return created.error();
  MadeDevice m;
  m.device = std::move(created).value();
  return m;
}

Result<MadeDevice> make_backend(const arm::ArmConfig& config) {
  switch (config.backend) {
    case arm::Backend::kSim: return made(device::SimArm::create(config));
    case arm::Backend::kModbus: return made(device::ModbusArm::create(config));
    case arm::Backend::kCanopen: return made(device::CanopenArm::create(config));
    case arm::Backend::kUsb: return made(device::UsbArm::create(config));
    case arm::Backend::kFalcon: return made(device::FalconArm::create(config));
  }
  return Error{ErrorCode::kInvalid, config.source + ": unknown backend"};
}

}  // namespace

Result<MadeDevice> make_device(const arm::ArmConfig& config) {
  auto made = make_backend(config);
  if (made.ok()) made.value().device->set_plausibility(plausibility_of(config));
  return made;
}

}  // namespace lancet::app
