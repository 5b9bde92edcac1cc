#include "app/device_factory.hpp"

#include <algorithm>
#include <cmath>


#include "device/canopen_arm.hpp"
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

Result<MadeDevice> make_backend(const arm::ArmConfig& config) {
  switch (config.backend) {
    case arm::Backend::kSim: {
      auto sim = device::SimArm::create(config);
      if (!sim.ok()) return sim.error();
      MadeDevice m;
      m.device = std::move(sim).value();
      return m;
    }
    case arm::Backend::kModbus: {
      auto mb = device::ModbusArm::create(config);
      if (!mb.ok()) return mb.error();
      MadeDevice m;
      m.device = std::move(mb).value();
      return m;
    }
    case arm::Backend::kCanopen: {
      auto can = device::CanopenArm::create(config);
      if (!can.ok()) return can.error();
      MadeDevice m;
      m.device = std::move(can).value();
      return m;
    }
    case arm::Backend::kUsb: {
      auto usb = device::UsbArm::create(config);
      if (!usb.ok()) return usb.error();
      MadeDevice m;
      m.device = std::move(usb).value();
      return m;
    }
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
