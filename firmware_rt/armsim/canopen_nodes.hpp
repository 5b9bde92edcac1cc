#pragma once
// CanopenNodeSet: emulated CiA 402 servo drives on a SocketCAN interface (vcan in the tests), one
// node per joint of an arm config, moving an ArmPhysics: the other end of CanopenArm.
//
// Each node answers, as a CiA 301 / CiA 402 slave would:
//   NMT          start, stop, enter pre-operational, reset node, reset communication (boot-up
//                message 0x700 + id [0x00] after a reset and at start)
//   SDO          expedited upload and download of its object dictionary (0x1000 device type,
//                0x1001, 0x1006 communication cycle period, 0x1016:1 heartbeat consumer, 0x1017,
//                0x1018, PDO communication 0x1400/0x1800 and mapping 0x1600/0x1A00 parameters with
//                the CiA 301 rules for changing them, 0x6007 abort connection option, 0x6040
//                controlword, 0x6041 statusword, 0x6060 mode (requested) / 0x6061 (display),
//                0x6064 position actual, 0x6071 target torque, 0x6072 max torque, 0x6076 rated
//                torque, 0x6077 torque actual, 0x60C2 interpolation time period, 0x60FD digital
//                inputs, 0x6502); aborts with the CiA 301 codes otherwise
//   SYNC         applies the RPDO data received since the last SYNC (synchronous RPDOs), advances
//                the physics, then sends each valid synchronous TPDO (transmission type n: every
//                nth SYNC since NMT start) from its mapping
//   CiA 402      the power state machine driven by the controlword; torque only in operation
//                enabled, NMT operational and mode 4 or 10: target torque ‰ of 0x6076 (mN·m),
//                clamped to 0x6072, through the arm config's torque constant, gear and direction
//   heartbeat    producer, every 0x1017 ms (0: off); consumer of the node 0x1016:1 names (the
//                master): armed by its first heartbeat, it fires when none came for the consumer
//                time: EMCY 0x8130, and a drive in operation enabled applies 0x6007 at once
//                (1 fault, 2 disable voltage, 3 quick stop; 0 nothing): torque off
//   EMCY         on an injected fault, on a heartbeat consumer timeout (and 0x0000 "error reset"
//                after a fault reset)
// Frames are read and written with the CANopen codec (device/canopen/codec.hpp) the driver uses.
// All nodes share one receive thread and one socket; everything is guarded by one mutex.

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "device/canopen/cia402.hpp"
#include "device/canopen/frame.hpp"
#include "device/canopen/nmt.hpp"
#include "device/canopen/pdo.hpp"
#include "device/canopen/sdo.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::armsim {

class CanopenNodeSet {
 public:
  struct Options {
    double fixed_dt = 0;                    ///< s of physics per SYNC; 0: the time since the last SYNC (≤ 5 sync periods)
    std::uint32_t vendor_id = 0x004C4E43;   ///< 0x1018:1
    std::uint32_t device_type = 0x00020192; ///< 0x1000: CiA 402, servo drive
    bool boot_up_at_start = true;           ///< send the boot-up messages when started
    std::int64_t tpdo_delay_us = 0;         ///< every node sends its TPDOs this long after the SYNC
    /// Told what the nodes do on their own, one line each: a heartbeat consumer that starts
    /// watching (its first heartbeat of the producer since 0x1016:1 was written or since it last
    /// timed out), e.g. "node 1: watching the master heartbeat (0x77F, consumer time 200 ms)", and
    /// a consumer timeout, e.g. "node 1: master heartbeat (0x77F) lost after 203 ms (consumer time
    /// 200 ms): torque off, disable voltage (0x6007 = 2), EMCY 0x8130". Called on the nodes' thread
    /// with their lock held.
    std::function<void(const std::string&)> on_event;
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
  /// A drive fault: the node enters the CiA 402 fault state and sends an EMCY (unless `with_emcy`
  /// is false: then only its statusword tells).
  void inject_fault(int node_id, std::uint16_t error_code, std::uint8_t error_register, bool with_emcy = true);
  /// The node takes writes of `mode` to 0x6060 but stays in its mode (0x6061 tells); 0: none refused.
  void set_refused_mode(int node_id, std::int8_t mode);
  /// The node sends its TPDOs this long after each SYNC (0: at once).
  void set_tpdo_delay_us(int node_id, std::int64_t delay_us);
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
    // TPDOs: the last frame sent (0, 0: none since the PDO was last reset). Tests use them to tell
    // a TPDO the master missed from one that went out late.
    std::uint64_t answered_sync = 0;  ///< which SYNC it answered: syncs_heard() when that SYNC came
    std::int64_t sent_ns = 0;         ///< CLOCK_MONOTONIC once its write() returned (vcan has delivered it)
  };
  struct NodeView {
    int node_id = 0;
    std::uint8_t nmt = 0;  ///< 0x04 stopped, 0x05 operational, 0x7F pre-operational
    std::uint16_t statusword = 0, controlword = 0;
    std::int16_t target_torque = 0;   ///< ‰, as last applied at a SYNC
    std::int16_t torque_actual = 0;   ///< ‰, what the motor gives (0 unless enabled)
    std::int8_t mode = 0;             ///< 0x6061, the mode in effect
    std::int8_t mode_requested = 0;   ///< 0x6060
    std::uint32_t rated_torque_mnm = 0;
    std::uint16_t max_torque = 0, heartbeat_ms = 0;
    std::uint32_t consumer = 0;           ///< 0x1016:1: producer node id << 16 | time (ms)
    std::int16_t abort_option = 0;        ///< 0x6007
    std::uint32_t cycle_period_us = 0;    ///< 0x1006
    std::uint8_t ip_value = 0;            ///< 0x60C2:1
    std::int8_t ip_index = 0;             ///< 0x60C2:2
    std::array<PdoView, 4> tpdo{}, rpdo{};
    std::uint64_t syncs = 0, rpdos = 0, tpdos = 0, sdo_requests = 0, fault_resets = 0, heartbeats = 0;
    std::uint64_t sdo_downloads = 0;      ///< SDO download requests (writes), taken or not
    std::uint64_t nmt_commands = 0;       ///< NMT commands addressed to the node (or to all)
    std::uint64_t master_heartbeats = 0;  ///< heartbeats heard from the consumer's producer
    bool watching = false;                ///< the consumer is armed: it heard its producer since 0x1016:1 was written or it last timed out
    double max_gap_ms = 0;                ///< the longest wait between two of them while the consumer was armed
    std::uint64_t heartbeat_losses = 0;   ///< consumer timeouts
    double last_loss_ms = 0;              ///< at the last timeout: ms since the producer's last heartbeat
    std::uint64_t emcys = 0;              ///< EMCY messages sent
    std::uint16_t last_emcy = 0;          ///< the last one's error code
  };
  [[nodiscard]] NodeView node(int node_id) const;
  /// SYNC frames received since start(), from anyone (silent nodes or not).
  [[nodiscard]] std::uint64_t syncs_heard() const;
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
    std::uint64_t answered_sync = 0;  ///< (TPDO) see PdoView
    std::int64_t sent_ns = 0;
  };
  struct Emu {
    int id = 0;
    int joint = 0;
    device::canopen::NmtState nmt = device::canopen::NmtState::kPreOperational;
    device::canopen::Cia402State drive = device::canopen::Cia402State::kSwitchOnDisabled;
    std::uint16_t controlword = 0;
    std::int16_t target_torque = 0;
    std::int16_t torque_actual = 0;
    std::int8_t mode = 0;            // in effect (0x6061)
    std::int8_t mode_requested = 0;  // 0x6060
    std::uint16_t max_torque = 1000;
    std::uint32_t rated_mnm = 1000;
    std::uint16_t heartbeat_ms = 0;
    std::int64_t next_heartbeat_ns = 0;
    std::uint8_t error_register = 0;
    std::uint32_t inputs = 0;
    // heartbeat consumer (0x1016:1) and what a lost heartbeat does (0x6007)
    std::uint32_t consumer = 0;
    bool consumer_armed = false;
    std::int64_t producer_seen_ns = 0;
    std::int16_t abort_option = 1;
    std::uint32_t cycle_period_us = 0;
    std::uint8_t ip_value = 1;
    std::int8_t ip_index = -3;
    std::array<Pdo, 4> tpdo{}, rpdo{};
    // synchronous RPDO data, applied at the next SYNC
    bool has_cw = false, has_tt = false, has_mode = false;
    std::uint16_t pending_cw = 0;
    std::int16_t pending_tt = 0;
    std::int8_t pending_mode = 0;
    // injection
    bool silent = false, drop_tpdos = false, heartbeat_on = true;
    int corrupt = 0;
    std::int8_t refused_mode = 0;
    std::int64_t tpdo_delay_ns = 0;
    // counters
    std::uint64_t syncs = 0, rpdos = 0, tpdos = 0, sdo_requests = 0, fault_resets = 0, heartbeats = 0;
    std::uint64_t sdo_downloads = 0, nmt_commands = 0, master_heartbeats = 0, heartbeat_losses = 0, emcys = 0;
    double last_loss_ms = 0;
    double max_gap_ms = 0;
    std::uint16_t last_emcy = 0;
  };
  /// A TPDO held back by tpdo_delay_ns.
  struct Delayed {
    std::int64_t due_ns = 0;
    int node = 0, pdo = 0;  ///< nodes_[node].tpdo[pdo]
    std::uint64_t answered_sync = 0;
    device::canopen::Frame frame{};
  };

  CanopenNodeSet(const arm::ArmConfig& config, Options options, std::unique_ptr<device::ArmPhysics> physics);
  void run();
  // All below run with mu_ held.
  void handle(const device::canopen::Frame& f, std::int64_t now);
  void on_nmt(const device::canopen::NmtRequest& rq, std::int64_t now);
  /// Applies the synchronous RPDOs, steps the physics, then send_tpdos() for every node.
  void on_sync(std::int64_t now);
  /// The TPDOs of nodes_[j] due at this SYNC (or held back by its TPDO delay).
  void send_tpdos(int j, std::int64_t now);
  void on_sdo(Emu& e, const device::canopen::SdoRequest& rq, std::int64_t now);
  void on_rpdo(Emu& e, int k, const device::canopen::Frame& f);
  /// The CiA 402 transition for controlword cw; a fault reset clears the error register and sends EMCY 0x0000.
  void apply_controlword(Emu& e, std::uint16_t cw);
  /// 0x6060 = m (a supported mode): entered at once unless the node refuses it (set_refused_mode).
  static void request_mode(Emu& e, std::int8_t m);
  [[nodiscard]] std::uint16_t statusword(const Emu& e) const;
  /// Object value and size in bytes; 0 = the abort code when it cannot be read.
  [[nodiscard]] std::uint32_t read_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t& value, int& bytes);
  [[nodiscard]] std::uint32_t write_object(Emu& e, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes, std::int64_t now);
  /// A PDO's communication or mapping parameter, with the CiA 301 rules for changing them.
  [[nodiscard]] static std::uint32_t write_pdo_parameter(Emu& e, const device::canopen::PdoParameter& pp, std::uint8_t sub,
                                                         std::uint32_t value, int bytes);
  [[nodiscard]] static Pdo& pdo(Emu& e, const device::canopen::PdoParameter& pp);
  [[nodiscard]] static const Pdo& pdo(const Emu& e, const device::canopen::PdoParameter& pp);
  [[nodiscard]] static int mappable_bits(std::uint16_t index, bool rpdo);
  void reset_communication(Emu& e);
  void reset_application(Emu& e);
  void boot(Emu& e, std::int64_t now);
  void send(const device::canopen::Frame& f);
  void send_emcy(Emu& e, std::uint16_t code, std::uint8_t reg);
  /// A heartbeat from node `producer` (any 0x700 frame): the consumers watching it are (re)armed.
  void on_heartbeat(int producer, std::int64_t now);
  /// Consumer timeouts due by `now` (their reaction); returns the ns until the next one could be.
  std::int64_t check_consumers(std::int64_t now);
  /// Sends the delayed TPDOs due by `now`; returns the ns until the next one.
  std::int64_t send_delayed(std::int64_t now);
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
  std::uint64_t syncs_heard_ = 0;
  std::array<Delayed, 64> delayed_{};
  int n_delayed_ = 0;
  std::thread thread_;
};

}  // namespace lancet::armsim
