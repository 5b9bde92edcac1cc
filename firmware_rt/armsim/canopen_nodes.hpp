#pragma once
// CanopenNodeSet: emulated CiA 402 servo drives on a SocketCAN interface (vcan in the tests), one
// node per joint of an arm config, moving an ArmPhysics: the other end of CanopenArm.
//
// Each node answers, as a CiA 301 / CiA 402 slave would:
//   NMT          start, stop, enter pre-operational, reset node, reset communication (boot-up
//                message 0x700 + id [0x00] after a reset and at start)
//   SDO          expedited upload and download of its object dictionary (0x1000 device type,
//                0x1001, 0x1017, 0x1018, PDO communication 0x1400/0x1800 and mapping 0x1600/0x1A00
//                parameters with the CiA 301 rules for changing them, 0x6040 controlword, 0x6041
//                statusword, 0x6060/0x6061 mode, 0x6064 position actual, 0x6071 target torque,
//                0x6072 max torque, 0x6076 rated torque, 0x6077 torque actual, 0x60FD digital
//                inputs, 0x6502); aborts with the CiA 301 codes otherwise
//   SYNC         applies the RPDO data received since the last SYNC (synchronous RPDOs), advances
//                the physics, then sends each valid synchronous TPDO (transmission type n: every
//                nth SYNC since NMT start) from its mapping
//   CiA 402      the power state machine driven by the controlword; torque only in operation
//                enabled, NMT operational and mode 4 or 10: target torque ‰ of 0x6076 (mN·m),
//                clamped to 0x6072, through the arm config's torque constant, gear and direction
//   heartbeat    producer, every 0x1017 ms (0: off)
//   EMCY         on an injected fault (and 0x0000 "error reset" after a fault reset)
// All nodes share one receive thread and one socket; everything is guarded by one mutex.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::armsim {

class CanopenNodeSet {
 public:
  struct Options {
    double fixed_dt = 0;                    ///< s of physics per SYNC; 0: the time since the last SYNC (≤ 5 sync periods)
    std::uint32_t vendor_id = 0x004C4E43;   ///< 0x1018:1
    std::uint32_t device_type = 0x00020192; ///< 0x1000: CiA 402, servo drive
    bool boot_up_at_start = true;           ///< send the boot-up messages when started
  };

  /// Opens a raw socket on config.canopen->interface_name and starts the nodes' thread. kSystem
  /// when the socket cannot be opened (no SocketCAN, no such interface).
  [[nodiscard]] static Result<std::unique_ptr<CanopenNodeSet>> start(const arm::ArmConfig& config, Options options);
  [[nodiscard]] static Result<std::unique_ptr<CanopenNodeSet>> start(const arm::ArmConfig& config) { return start(config, Options{}); }
  ~CanopenNodeSet();
  CanopenNodeSet(const CanopenNodeSet&) = delete;
  CanopenNodeSet& operator=(const CanopenNodeSet&) = delete;

  // ---- fault injection (any thread) ----
  /// The node neither receives nor sends anything (unplugged); its motor gives no torque.
  void set_silent(int node_id, bool silent);
  /// The node sends no TPDOs (it still answers SDO, sends heartbeats and EMCY).
  void set_drop_tpdos(int node_id, bool drop);
  /// The node's next `count` TPDOs go out one byte short.
  void corrupt_next_tpdos(int node_id, int count);
  /// Heartbeat producer on or off (0x1017 keeps its value).
  void set_heartbeat_enabled(int node_id, bool on);
  /// A drive fault: the node enters the CiA 402 fault state and sends an EMCY.
  void inject_fault(int node_id, std::uint16_t error_code, std::uint8_t error_register);
  /// The value of 0x60FD (bits 16..31: general-purpose inputs).
  void set_digital_inputs(int node_id, std::uint32_t inputs);
  /// Power cycle: every object back to its default, boot-up, pre-operational.
  void power_cycle(int node_id);

  // ---- observation (any thread) ----
  struct PdoView {
    std::uint32_t cob_id = 0;  ///< bit 31: invalid
    std::uint8_t type = 0;
    std::uint8_t count = 0;
    std::array<std::uint32_t, 8> map{};
  };
  struct NodeView {
    int node_id = 0;
    std::uint8_t nmt = 0;  ///< 0x04 stopped, 0x05 operational, 0x7F pre-operational
    std::uint16_t statusword = 0, controlword = 0;
    std::int16_t target_torque = 0;   ///< ‰, as last applied at a SYNC
    std::int16_t torque_actual = 0;   ///< ‰, what the motor gives (0 unless enabled)
    std::int8_t mode = 0;
    std::uint32_t rated_torque_mnm = 0;
    std::uint16_t max_torque = 0, heartbeat_ms = 0;
    std::array<PdoView, 4> tpdo{}, rpdo{};
    std::uint64_t syncs = 0, rpdos = 0, tpdos = 0, sdo_requests = 0, fault_resets = 0, heartbeats = 0;
  };
  [[nodiscard]] NodeView node(int node_id) const;
  /// The physics under the nodes' lock.
  template <class F>
  decltype(auto) with_physics(F&& f) {
    std::lock_guard<std::mutex> lock(mu_);
    return f(*physics_);
  }

 private:
  struct Pdo {
    std::uint32_t cob_id = 0;
    std::uint8_t type = 255;
    std::uint8_t count = 0;
    std::array<std::uint32_t, 8> map{};
    std::uint32_t syncs = 0;  ///< SYNCs since NMT start (TPDO)
  };
  enum class Drive : std::uint8_t { kNotReady, kSwitchOnDisabled, kReady, kSwitchedOn, kEnabled, kQuickStop, kFault };
  struct Emu {
    int id = 0;
    int joint = 0;
    std::uint8_t nmt = 0x7F;
    Drive drive = Drive::kSwitchOnDisabled;
    std::uint16_t controlword = 0;
    std::int16_t target_torque = 0;
    std::int16_t torque_actual = 0;
    std::int8_t mode = 0;
    std::uint16_t max_torque = 1000;
    std::uint32_t rated_mnm = 1000;
    std::uint16_t heartbeat_ms = 0;
    std::int64_t next_heartbeat_ns = 0;
    std::uint8_t error_register = 0;
    std::uint32_t inputs = 0;
    std::array<Pdo, 4> tpdo{}, rpdo{};
    // synchronous RPDO data, applied at the next SYNC
    bool has_cw = false, has_tt = false, has_mode = false;
    std::uint16_t pending_cw = 0;
    std::int16_t pending_tt = 0;
    std::int8_t pending_mode = 0;
    // injection
    bool silent = false, drop_tpdos = false, heartbeat_on = true;
    int corrupt = 0;
    // counters
    std::uint64_t syncs = 0, rpdos = 0, tpdos = 0, sdo_requests = 0, fault_resets = 0, heartbeats = 0;
  };

  CanopenNodeSet(const arm::ArmConfig& config, Options options, std::unique_ptr<device::ArmPhysics> physics);
  void run();
  // All below run with mu_ held.
  void handle(const void* frame, std::int64_t now);
  void on_nmt(std::uint8_t cs, int target, std::int64_t now);
  void on_sync(std::int64_t now);
  void on_sdo(Emu& e, const std::uint8_t* d, std::int64_t now);
  void on_rpdo(Emu& e, int k, const std::uint8_t* d, int len);
  void apply_controlword(Emu& e, std::uint16_t cw);
  [[nodiscard]] std::uint16_t statusword(const Emu& e) const;
  /// Object value and size in bytes; 0 = the abort code when it cannot be read.
  [[nodiscard]] std::uint32_t read_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t& value, int& bytes);
  [[nodiscard]] std::uint32_t write_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes, std::int64_t now);
  [[nodiscard]] static int mappable_bits(std::uint16_t index, bool rpdo);
  void reset_communication(Emu& e);
  void reset_application(Emu& e);
  void boot(Emu& e, std::int64_t now);
  void send(std::uint32_t cob, const std::uint8_t* data, int len);
  void send_emcy(Emu& e, std::uint16_t code, std::uint8_t reg);
  [[nodiscard]] Emu* find(int node_id);
  [[nodiscard]] const Emu* find(int node_id) const;

  arm::ArmConfig config_;
  Options options_;
  std::unique_ptr<device::ArmPhysics> physics_;
  double sync_period_ = 0.001;
  int fd_ = -1;
  int stop_fd_ = -1;
  mutable std::mutex mu_;
  std::array<Emu, device::kMaxJoints> nodes_{};
  int n_ = 0;
  std::int64_t last_sync_ns_ = 0;
  std::thread thread_;
};

}  // namespace lancet::armsim
