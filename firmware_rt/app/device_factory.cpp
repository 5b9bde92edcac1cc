#include "app/device_factory.hpp"


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
    case arm::Backend::kUsb: {
      auto usb = device::UsbArm::create(config);
      if (!usb.ok()) return usb.error();
      MadeDevice m;
      m.device = std::move(usb).value();
      return m;
    }
    default:
      break;
  }
  const char* names[] = {"sim", "usb", "modbus", "canopen"};
  return Error{ErrorCode::kInvalid, config.source + ": backend '" + names[static_cast<int>(config.backend)] +
                                        "' is not available in this build yet (sim is)"};
}

}  // namespace lancet::app
