#include "app/device_factory.hpp"


#include "device/canopen_arm.hpp"
#include "device/modbus_arm.hpp"
#include "device/sim_arm.hpp"
#include "device/usb_arm.hpp"

namespace lancet::app {

Result<MadeDevice> make_device(const arm::ArmConfig& config) {
  switch (config.backend) {
    case arm::Backend::kSim: {
      auto sim = device::SimArm::create(config);
      if (!sim.ok()) return sim.error();
      MadeDevice m;
      m.hand = &sim.value()->physics();
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

}  // namespace lancet::app
