#pragma once
// An emulated Novint Falcon behind umockdev: a scripted FTDI FT232 (0403:cb48) that checks the
// vendor control requests it gets, the Falcon's loader (handshake, firmware upload with each byte
// echoed), and from then on its firmware: every 16-byte command packet is answered with a reply
// packet from a simulated delta mechanism (device::ArmPhysics built from the Falcon's config)
// driven by the commanded motor torques. Written apart from the product's codec on purpose: the
// packet layout and the FTDI divisor are decoded here from the protocol's description.
//
// The chip: IN packets carry two modem-status bytes and up to 62 data bytes; an IN transfer pends
// while nothing is queued and completes when data is (the real chip answers with the two status
// bytes alone every latency period; pending instead keeps umockdev's thread quiet). A UART only
// hears the host at the rate it expects: the loader answers its handshake only at 9600 baud (8N1,
// no flow control, after DTR went high), the upload request only at 140 kbaud with DTR low, and
// the firmware its commands only at 1.5 Mbaud; anything else is ignored, as garbled bytes would be.
//
// The mechanism: powered up at rest, its encoders count from there (relative) until homing mode
// is on and a motor's thigh passes its home switch (home_angles); from then that motor's counts
// are absolute, counts = (θ − offset) / (rad per count) as the config says, and its homed bit is set.
// Motor torque at the thigh from a command: τ = command / (direction · motor_command_per_nm).
// The force felt at the grip is J⁻ᵀ τ at the mechanism's pose, and the emulator also keeps the
// force the servo meant: J⁻ᵀ τ at the pose the host last read (the counts in the reply before).

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "arm/kinematics.hpp"
#include "device/arm_physics.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "usbdevfs_emulator.hpp"

namespace lancet::test {

struct FalconEmulatorOptions {
  std::vector<std::uint8_t> firmware;         ///< the image the loader expects (what the host should upload)
  bool firmware_running = false;              ///< powered with the firmware already loaded (no upload needed)
  bool start_after_upload = true;             ///< false: the upload goes in but the firmware never answers
  std::optional<std::size_t> corrupt_echo_at; ///< the loader echoes this byte of the upload wrong
  std::array<double, 3> home_angles{};        ///< rad: each thigh's home switch
  std::array<double, 3> start_q{};            ///< rad: the pose at power-up
};

/// One vendor request as the chip saw it.
struct FtdiRequest {
  std::uint8_t request_type = 0, request = 0;
  std::uint16_t value = 0, index = 0;
};

struct FalconSnapshot {
  enum class Mode { kLoader, kHello, kUploadReady, kUploading, kRunning };
  Mode mode = Mode::kLoader;
  std::vector<FtdiRequest> requests;       ///< every control request, in order (all power cycles)
  std::uint64_t unexpected_requests = 0;   ///< requests a Falcon's chip would not get (stalled)
  double baud = 0;                         ///< as the last baud-rate request set it
  int latency_ms = 16;
  bool dtr = false, rts = false, eight_n_one = false, flow_none = false;
  std::size_t uploaded = 0;                ///< firmware bytes received this power cycle
  std::uint64_t uploads_completed = 0;
  std::uint64_t commands = 0, replies = 0, bad_commands = 0, ignored_bytes = 0;
  std::array<std::int16_t, 3> motor{};     ///< the last command's motor values
  std::uint8_t leds = 0;
  bool homing_mode = false;
  std::uint8_t homed = 0;
  std::array<double, 3> tau{};             ///< N·m at the thighs, from the last command
  Vec3 felt{};                             ///< N at the grip: J⁻ᵀ τ at the mechanism's pose
  Vec3 meant{};                            ///< N: J⁻ᵀ τ at the pose of the counts the host last read
  Vec3 tool{};                             ///< m, device frame
  std::uint64_t power_cycles = 0;
  int drops_left = 0, corruptions_left = 0;  ///< of the bursts drop_replies() / corrupt_replies() asked for
};

class FalconEmulator final : public UsbdevfsDevice {
 public:
  FalconEmulator(const arm::ArmConfig& config, FalconEmulatorOptions options);
  ~FalconEmulator() override;

  /// The next `n` command packets get no reply (the mechanism still steps).
  void drop_replies(int n);
  /// The next `n` replies have a nibble out of range.
  void corrupt_replies(int n);
  void set_grip(std::uint8_t buttons);
  /// Unplugged and plugged back: the Falcon loses its firmware and its homing.
  void power_cycle();
  void with_physics(const std::function<void(device::ArmPhysics&)>& f);
  [[nodiscard]] FalconSnapshot snapshot() const;
  [[nodiscard]] const arm::Kinematics& kinematics() const { return kin_; }

 protected:
  UrbReply on_control(const ControlSetup& setup, std::span<std::uint8_t> data) override;
  UrbReply on_out(std::uint8_t endpoint, std::span<const std::uint8_t> data) override;
  UrbReply on_in(std::uint8_t endpoint, std::span<std::uint8_t> buffer) override;

 private:
  void loader_byte(std::uint8_t b);
  void firmware_bytes(std::span<const std::uint8_t> data);
  void command(const std::uint8_t* p);
  void queue(std::span<const std::uint8_t> bytes);
  [[nodiscard]] std::int16_t wire_counts(int j);
  [[nodiscard]] Vec3 force_at(std::span<const double> q, const std::array<double, 3>& tau) const;
  [[nodiscard]] bool baud_near(double want) const;

  arm::ArmConfig config_;
  arm::Kinematics kin_;
  FalconEmulatorOptions options_;
  std::unique_ptr<device::ArmPhysics> physics_;
  FalconSnapshot snap_;
  std::deque<std::uint8_t> to_host_;
  std::vector<std::uint8_t> command_bytes_;   // a command packet being received
  std::vector<std::uint8_t> hello_bytes_;
  std::array<std::int64_t, 3> powerup_counts_{};
  std::array<double, 3> q_read_{};            // the pose of the counts in the last reply
  std::array<double, 3> last_q_{};
  bool dtr_rose_ = false;
  int drop_ = 0, corrupt_ = 0;
  std::uint8_t grip_ = 0;
};

}  // namespace lancet::test
