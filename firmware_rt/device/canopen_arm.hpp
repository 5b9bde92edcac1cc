#pragma once
// CanopenArm: a haptic arm whose joints are CiA 402 servo drives on one CAN bus, one node per
// joint, driven through a SocketCAN raw socket with the PDO map of the arm's config
// ([bus.canopen] in hw_configs/*.toml; schema and behaviour in hw_configs/README.md). The host is
// the NMT master of its own nodes, the SYNC producer (unless `sync_producer = false`: see below)
// and, while active, a heartbeat producer the drives watch.
// Every frame is built and read with the CANopen codec (device/canopen/codec.hpp), which the
// emulated drives of lancet-armsim use too. The sources: create() and the PDO plan in
// canopen_arm.cpp, the set-up in canopen_arm_setup.cpp, the real-time exchange in
// canopen_arm_exchange.cpp.
//
//   configure()  observe only: open the socket on the interface; per node, by SDO upload, check the
//                device type (0x1000: a CiA 402 drive), read the vendor id (0x1018:1) and the
//                statusword. Nothing is written and no NMT command is sent: the drives' NMT and
//                CiA 402 states stay as they were (lancetctl probe, monitor and calibrate only
//                configure and read, so they can never switch a drive on)
//   read() while inactive: SDO uploads per node (statusword, position actual, the buttons node's
//                digital inputs); no SYNC, no PDOs. Bounded by (2 n + 1) × the SDO timeout
//   activate()   the bus set-up, then the CiA 402 state machine. Per node: NMT reset communication
//                (wait for the boot-up), SDO-download controlword 0 and target torque 0 (a drive
//                left enabled is switched off), the producer heartbeat time (0x1017), the
//                communication cycle period (0x1006, µs = the sync period), in cst mode the
//                interpolation time period (0x60C2:1 value, :2 index), the mode of operation (0x6060,
//                read back from 0x6061: a mismatch fails naming both), rated torque (0x6076, mN·m),
//                max torque (0x6072, ‰), the PDO communication and mapping parameters, and the
//                drive-side watchdog (abort connection option 0x6007 = 2 "disable voltage", then the
//                heartbeat consumer 0x1016:1 = master node id << 16 | drive_watchdog ms); NMT start;
//                SYNCs until every node's TPDOs (and heartbeat) arrive. Then SYNC by SYNC at the sync
//                period with the controlword in the RPDOs (shutdown → switch on → enable operation;
//                a drive in fault gets a fault reset first) until every statusword says operation
//                enabled. A failed activation leaves the bus as deactivate() does
//   read()       drain (sending the master's heartbeat when due), SYNC, then wait (ppoll, at most a fraction of the sync period) for this
//                cycle's TPDOs of every node: position actual (0x6064), statusword (0x6041),
//                digital inputs (0x60FD); decodes EMCY and heartbeats on the way
//   write()      joint torques → target torque (0x6071, ‰ of 0x6076) in each node's RPDO, right
//                after the SYNC of the same cycle; the drives apply it at the next SYNC
//   deactivate() zero torque, controlword shutdown until no drive is enabled, NMT pre-operational,
//                the drives' heartbeat consumer off (0x1016:1 = 0), then the master's heartbeat stops
//   rearm()      a node that rebooted or left operational is configured again and started; then a
//                fault reset (controlword bit 7) and enable again
//   reconnect()  (in fault, after a disconnect) reopen the socket, then the bus set-up of activate()
//                with the drives left disabled (controlword 0, zero torque): only rearm() enables
//
// The drive-side watchdog. From activate() to deactivate() (and in fault) the master sends its own
// heartbeat (COB-ID 0x700 + master_node_id, state operational) every drive_watchdog / 4: read()
// sends one when due, before its SYNC (one frame, no allocation, no wait), and so do the set-up
// steps while they wait. When it stops for drive_watchdog (lancet-rt stalled, killed, the cable
// pulled) each drive applies 0x6007 = 2, disable voltage: its power stage goes off at once and the
// motor turns freely (CiA 402 transition to switch on disabled), and it sends EMCY 0x8130. Not 1
// (fault: the drive first runs its fault reaction 0x605E, often a braking ramp, under power) nor 3
// (quick stop: brakes actively). Back on the bus, the master sees the EMCY (and the drive no longer
// enabled) as a device fault; rearm() enables the drive again. drive_watchdog = 0: no consumer,
// no heartbeat of the master, 0x6007 left as the drive has it.
//
// Two arms on one bus (`sync_producer = false` in one of them). CiA 301 allows one SYNC producer
// per network, so the other arm's master sends it and this one sends none: its socket also takes
// SYNC (0x080), and each SYNC it sees starts a cycle (what came before it is an earlier cycle's).
// read() and the set-up's cycles then wait for a SYNC and this arm's TPDOs after it, within the
// same budget; no SYNC within it is a missing TPDO (kTimeout) that names the absent SYNC. The
// frames of the other arm's nodes pass neither the socket's filters nor the node-id match. Each
// arm keeps its own NMT commands (addressed to its own nodes) and its own heartbeat
// (master_node_id). lancet-rt reads the producer first in the tick, and keeps its SYNC going
// (keep_sync) while the other arm sets up or shuts down (which needs the SYNCs).
//
// read() and write() are real-time safe: no allocation, no exceptions, and each blocks at most
// for the read budget (CanopenTiming::read_budget_fraction × sync period) in ppoll(); the socket is
// non-blocking. What read() reports, most severe first:
//   kDisconnected  the socket failed (interface down, bus-off), a node's heartbeat is overdue
//                  (heartbeat_timeout_factor × heartbeat period), or a heartbeat / boot-up says a
//                  node is no longer operational (it rebooted or was stopped)
//   kDeviceFault   an EMCY with a non-zero error code arrived, a statusword has the fault bit, or
//                  (while active) a drive is no longer in operation enabled
//   kProtocolError a TPDO arrived with the wrong length
//   kTimeout       a TPDO of this cycle did not arrive within the budget (a TPDO sent every nth
//                  SYNC: none for 2n + 1 SYNCs)
// Each error is described for the operator (Device::note_error → last_error(), fault_detail()):
// the node id and what happened, e.g. "node 1: EMCY 0x2310 continuous over-current (output side),
// error register 0x03", "node 3: heartbeat 0x703 overdue: none for 212 ms (every 50 ms)",
// "node 2: statusword 0x0218 has the fault bit". When read() reports kDisconnected or kDeviceFault
// (both trip kFault at once) it sends zero torque at once, before the next write().
//
// JointState.status packs the drives' statuswords: bit j = node j operation enabled, bit 8 + j =
// node j fault, bit 16 + j = node j warning (statusword bit 7). JointState.buttons: bit i = config
// button i pressed, from the 32-bit digital inputs of the buttons node. Encoder counts are the
// 32-bit position actual, unwrapped to 64 bits between reads.

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/canopen/codec.hpp"
#include "device/device.hpp"

struct can_frame;  // <linux/can.h>, kept out of this header

namespace lancet::device {

/// Waits and timeouts (defaults suit a real 1 Mbit/s bus).
struct CanopenTiming {
  double read_budget_fraction = 0.5;     ///< read() waits for TPDOs at most this fraction of the sync period
  double sdo_timeout = 0.1;              ///< s, per SDO request (configure, rearm)
  double boot_timeout = 1.0;             ///< s, to wait for the boot-up messages after NMT reset communication
  double state_timeout = 1.0;            ///< s, for the drives to reach (activate, rearm) or leave (deactivate) operation enabled
  double heartbeat_timeout_factor = 2.0; ///< a node's heartbeat is overdue after this many heartbeat periods
  double mode_timeout = 0.1;             ///< s, for 0x6061 to show the mode written to 0x6060 (activate)
};

/// What went wrong last on the bus (real-time safe to update and to copy).
struct CanopenEvent {
  IoStatus status = IoStatus::kOk;
  int node_id = 0;                 ///< 0 when the bus as a whole (socket, bus-off)
  std::uint32_t cob_id = 0;        ///< the frame concerned, when one
  canopen::Emcy emcy{};            ///< when status is kDeviceFault from an EMCY
  std::uint16_t statusword = 0;    ///< the node's last statusword
  canopen::NmtState nmt = canopen::NmtState::kUnknown;  ///< the node's last heartbeat state
  int err_no = 0;                  ///< errno of a failed socket call
  std::int64_t t_ns = 0;
  enum class What : std::uint8_t {
    kNone, kSocket, kBusOff, kHeartbeatLost, kNotOperational, kEmcy, kFaultBit, kNotEnabled, kBadLength, kMissingTpdo,
    kNotSetUp,  ///< in fault with no bus set up (a reconnect has not got through yet)
  } what = What::kNone;
};

class CanopenArm final : public Device {
 public:
  /// From a loaded config with a [bus.canopen] section (kInvalid otherwise, or when the PDO map
  /// lacks an object the driver needs, a PDO is over 8 bytes, or a rated torque rounds to 0 mN·m).
  /// Opens nothing yet: configure() does.
  [[nodiscard]] static Result<std::unique_ptr<CanopenArm>> create(const arm::ArmConfig& config, FaultPolicy policy = {},
                                                                  CanopenTiming timing = {});
  /// Best effort when the drives may still be enabled: zero torque, shutdown, NMT pre-operational.
  ~CanopenArm() override;

  [[nodiscard]] int joint_count() const noexcept override { return n_; }
  [[nodiscard]] const std::string& interface_name() const noexcept { return bus_.interface_name; }
  /// Whether the nodes are set up and exchanging PDOs (activate() to deactivate(), and in fault);
  /// false after configure(): read() then observes by SDO.
  [[nodiscard]] bool pdos_running() const noexcept { return pdo_running_; }
  /// Heartbeats the master has sent (COB-ID 0x700 + master_node_id) since configure().
  [[nodiscard]] std::uint64_t master_heartbeats() const noexcept { return master_heartbeats_; }

  /// What the driver knows of one node (joint j), real-time safe to read between ticks.
  struct NodeInfo {
    int node_id = 0;
    std::uint16_t statusword = 0;
    std::uint16_t controlword = 0;              ///< last sent
    std::int16_t target_torque = 0;             ///< ‰ of rated_torque_mnm, last sent
    std::uint32_t rated_torque_mnm = 0;         ///< written to 0x6076
    std::int16_t max_torque = 0;                ///< ‰, written to 0x6072 (the peak torque)
    std::uint32_t vendor_id = 0;                ///< 0x1018:1
    std::int8_t mode_display = 0;               ///< 0x6061 as read back at activation
    canopen::NmtState nmt = canopen::NmtState::kUnknown;  ///< from the last heartbeat / boot-up
    std::int64_t last_heartbeat_ns = 0;
    std::uint64_t tpdos = 0, emcys = 0, heartbeats = 0;
    canopen::Emcy last_emcy{};                  ///< the last EMCY (any code)
  };
  [[nodiscard]] const NodeInfo& node(int joint) const noexcept { return nodes_[static_cast<std::size_t>(joint)].info; }
  /// The last thing that went wrong on the bus (status kOk: nothing yet).
  [[nodiscard]] const CanopenEvent& last_event() const noexcept { return last_event_; }
  /// last_event() as a sentence (allocates: not real-time).
  [[nodiscard]] std::string describe(const CanopenEvent& e) const;
  /// While another arm on this bus sets up or shuts down on this arm's SYNC (lancet-rt, before and
  /// after its loop): one cycle's SYNC, and the master's heartbeat when due; what arrived is taken
  /// in as read() would, but nothing is judged (no fault, no counters): the arm is not being read
  /// for the servo, and a late TPDO here says nothing the first read would not. Nothing while the
  /// bus is not set up or when this arm sends no SYNC. Real-time safe; one caller at a time.
  void keep_sync() noexcept;
  /// SYNCs sent since configure() (with sync_producer = false: SYNCs seen on the bus).
  [[nodiscard]] std::uint64_t syncs() const noexcept { return sync_count_; }

 protected:
  // The set-up (canopen_arm_setup.cpp): SDO configuration, PDO mapping, NMT, the CiA 402 states.
  Result<void> on_configure() override;
  Result<void> on_activate() override;
  Result<void> on_deactivate() override;
  Result<void> on_rearm() override;
  Result<void> on_reconnect() override;
  // The exchange (canopen_arm_exchange.cpp): SYNC, PDOs, staleness and faults; real-time safe.
  IoStatus on_read(JointState& out) noexcept override;
  IoStatus on_write(const JointCommand& cmd) noexcept override;

 private:
  CanopenArm(const arm::ArmConfig& config, FaultPolicy policy, CanopenTiming timing);

  /// Where an object sits in a PDO's data.
  struct Slot {
    bool present = false;
    std::uint8_t offset = 0;  ///< bytes
    std::uint8_t bytes = 0;
  };
  struct PdoPlan {
    int number = 0;   ///< 1..4
    int divider = 1;  ///< sent every nth SYNC
    std::uint8_t size = 0;  ///< bytes of mapped data
    Slot statusword, position, inputs;       // TPDO
    Slot controlword, target_torque, mode;   // RPDO
  };
  struct Node {
    NodeInfo info;
    // decoding
    std::int64_t counts = 0;
    std::int32_t last_raw = 0;
    bool have_position = false;
    std::uint32_t inputs = 0;
    std::array<std::uint64_t, 4> tpdo_sync{};  ///< SYNC count when TPDO k last arrived
    std::uint8_t seen_mask = 0;                ///< TPDOs (bit k) received this cycle
    bool emcy_pending = false;                 ///< a non-zero EMCY not yet reported by read()
    bool bad_length = false;
    std::uint32_t bad_cob = 0;
    std::uint8_t bad_len = 0;                  ///< bytes of the frame with the wrong length
    bool consumer_set = false;                 ///< 0x1016:1 written: the drive watches the master's heartbeat
    bool boot_seen = false;                    ///< a boot-up since the last (re)configuration
    // SDO client
    bool sdo_reply = false;
    canopen::Frame sdo_frame{};                ///< the last SDO server frame (8 bytes)
    // estimation
    double q_prev = 0;
  };

  /// Where the driver's objects sit in each PDO of one direction (the same on every node);
  /// `key` names the config table ("tpdo", "rpdo") in the error.
  [[nodiscard]] std::optional<Error> plan_pdos(const std::string& where, const std::vector<arm::PdoConfig>& pdos,
                                               std::array<PdoPlan, 4>& out, int& count, const char* key) const;
  /// Both directions planned, the objects the driver needs all mapped, the TPDOs due every SYNC known.
  [[nodiscard]] std::optional<Error> plan_pdo_map(const std::string& where);

  /// The outcome of one expedited SDO request (no allocation).
  struct SdoReply {
    enum class Kind : std::uint8_t { kOk, kAbort, kTimeout, kSocket, kSegmented } kind = Kind::kTimeout;
    std::uint32_t value = 0;  ///< the uploaded value (kOk), the abort code (kAbort)
  };

  // Socket, frames and the SYNC cycle (canopen_arm_exchange.cpp; real-time safe).
  [[nodiscard]] IoStatus send(const canopen::Frame& f) noexcept;
  [[nodiscard]] IoStatus send_sync() noexcept;
  void send_nmt(canopen::NmtCommand cmd, int node_id) noexcept;
  void handle(const ::can_frame& f, std::int64_t now) noexcept;
  /// A TPDO (tpdos_[k]) of the right length from node nd: its statusword, inputs and position.
  void take_tpdo(Node& nd, int k, const canopen::Frame& f) noexcept;
  /// Reads every frame waiting (at most a bounded number), first sending the master's heartbeat
  /// when it is due. false: the socket failed.
  bool drain(std::int64_t now) noexcept;
  /// The master's heartbeat, when producing and due (one frame; errors are left to the next SYNC).
  void produce_heartbeat(std::int64_t now) noexcept;
  /// ppoll() for a frame until `deadline`, or until the master's next heartbeat is due.
  void wait_frames(std::int64_t deadline) noexcept;
  /// One expedited SDO upload or download to joint i's node, waiting at most the SDO timeout.
  SdoReply sdo_request(int i, const canopen::Frame& request, std::uint16_t index, std::uint8_t sub, bool upload) noexcept;
  /// read() while inactive: one SDO upload, any failure described (note_error) and returned.
  [[nodiscard]] IoStatus sdo_read(int i, std::uint16_t index, std::uint8_t sub, std::uint32_t& value) noexcept;
  /// read() while inactive: the statusword, position and inputs by SDO (see the header comment).
  [[nodiscard]] IoStatus observe(JointState& out) noexcept;
  /// JointState from the nodes' decoded values; `t_ns`: when they were sampled.
  void fill_state(JointState& out, std::int64_t t_ns) noexcept;
  /// The position actual just received (PDO or SDO): unwrapped into nd.counts.
  static void take_position(Node& nd, std::int32_t raw) noexcept;
  /// drain, SYNC, collect until every node's TPDOs of this cycle are in or the wait ends.
  [[nodiscard]] IoStatus exchange(std::int64_t wait_ns) noexcept;
  /// exchange() of an arm that sends no SYNC: wait for another master's SYNC and the TPDOs after it.
  [[nodiscard]] IoStatus exchange_without_sync(std::int64_t wait_ns) noexcept;
  /// Every node has sent every TPDO this cycle expects, each of the right length.
  [[nodiscard]] bool cycle_complete() const noexcept;
  /// The status of the cycle just exchanged (see the header comment for the order).
  [[nodiscard]] IoStatus evaluate(std::int64_t now, bool require_enabled) noexcept;
  /// Each node's RPDOs due at this SYNC (all of them with `all`: zero torque, shutdown).
  [[nodiscard]] IoStatus send_rpdos(bool all = false) noexcept;
  void send_zero_torque() noexcept;
  /// Heartbeat and TPDO staleness counted afresh from now (after a set-up step that paused them).
  void restart_tracking(std::int64_t now) noexcept;
  /// Records the event (last_event()) without reporting it.
  void note(IoStatus s, CanopenEvent::What what, int node_index, std::uint32_t cob, int err_no, std::int64_t now) noexcept;
  /// note(), and describes it to the Device (note_error) as the error read() / write() returns.
  void report(IoStatus s, CanopenEvent::What what, int node_index, std::uint32_t cob, int err_no, std::int64_t now) noexcept;
  /// A failed exchange() or send: the socket (kDisconnected) or a full transmit queue (kTimeout).
  [[nodiscard]] IoStatus report_send_failure(IoStatus s) noexcept;

  // Set-up steps (canopen_arm_setup.cpp; may allocate); failures name the interface, the node and
  // the object.
  Result<void> open_socket();
  Result<void> fail(const std::string& what) const;
  Result<void> sdo_download(int i, std::uint16_t index, std::uint8_t sub, std::uint32_t value, int bytes);
  Result<std::uint32_t> sdo_upload(int i, std::uint16_t index, std::uint8_t sub);
  Result<std::uint32_t> sdo_transfer(int i, const canopen::Frame& request, std::uint16_t index, std::uint8_t sub, bool upload,
                                     const std::string& what);
  void wait_boot_ups(double timeout_s, std::uint32_t node_mask);
  /// Device type (must be CiA 402) and vendor id, by SDO upload.
  Result<void> identify_node(int i);
  Result<void> configure_node(int i);
  /// Joint i's node: every PDO's communication and mapping parameters from the config.
  Result<void> configure_pdos(int i);
  /// 0x6060 = the config's mode, then 0x6061 until it shows it (mode_timeout).
  Result<void> set_mode(int i);
  void start_nodes(std::uint32_t node_mask);
  /// activate() and reconnect(): every node reset, configured (drives disabled, zero torque),
  /// started; returns once every node's TPDOs (and heartbeat) arrive.
  Result<void> setup_bus();
  /// deactivate(), and a failed activate(): drives shut down, NMT pre-operational, the drives'
  /// heartbeat consumer off, then the master's heartbeat stops.
  Result<void> stop_bus();
  /// Every node's decoding state back to "nothing heard", keeping what create() computed.
  void reset_nodes() noexcept;
  /// Runs paced SYNC cycles, each node's controlword from `next_cw`, zero torque, until `done`
  /// holds for every node or the timeout; the error names the nodes that did not get there.
  template <class NextCw, class Done>
  Result<void> drive_states(NextCw next_cw, Done done, const std::string& goal);
  Result<void> enable_drives(const char* goal);

  arm::ArmConfig config_;
  arm::CanopenBusConfig bus_;
  CanopenTiming timing_;
  int n_ = 0;
  int fd_ = -1;
  bool pdo_running_ = false;  ///< nodes operational: PDOs flow
  std::array<Node, kMaxJoints> nodes_{};
  std::array<std::int8_t, 128> index_of_id_{};  ///< node id → joint, −1 when not ours
  std::array<PdoPlan, 4> tpdos_{}, rpdos_{};
  int n_tpdos_ = 0, n_rpdos_ = 0;
  std::uint8_t expected_mask_ = 0;  ///< TPDOs due every SYNC (bit k of tpdos_)
  int buttons_joint_ = 0;
  std::int64_t sync_period_ns_ = 1'000'000;
  std::int64_t read_budget_ns_ = 500'000;
  std::int64_t heartbeat_timeout_ns_ = 0;  ///< 0: no heartbeat consumer
  std::int64_t sdo_timeout_ns_ = 100'000'000;
  std::int64_t master_heartbeat_ns_ = 0;   ///< the master's heartbeat period (drive_watchdog / 4); 0: none
  std::int64_t next_master_heartbeat_ns_ = 0;
  bool producing_ = false;                 ///< the master's heartbeat goes out (set-up to deactivate)
  std::uint64_t master_heartbeats_ = 0;
  std::optional<canopen::InterpolationPeriod> interpolation_;  ///< 0x60C2 (cst mode)
  std::uint64_t sync_count_ = 0;
  std::uint64_t tracking_since_ = 0;     ///< SYNC count when TPDO tracking (re)started
  std::int64_t cycle_t_ns_ = 0;          ///< when this cycle's SYNC went out (or was seen)
  bool sync_seen_ = false;               ///< sync_producer = false: a SYNC came since this exchange began
  std::int64_t prev_good_t_ns_ = 0;      ///< SYNC time of the previous good read (0: none)
  bool socket_failed_ = false;
  int socket_errno_ = 0;
  bool bus_off_ = false;
  CanopenEvent last_event_{};
};

}  // namespace lancet::device
