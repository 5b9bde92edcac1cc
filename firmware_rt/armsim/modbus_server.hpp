#pragma once
// ArmServer: a simulated arm (ArmPhysics built from an arm config) served over Modbus with the
// config's register map, through a libmodbus server — the library part of lancet-armsim, so tests
// can run the same server in process.
//
// Two threads once started:
//   physics  ArmPhysics at `physics_rate` (1 kHz): the holding current-command registers → joint
//            torques (the inverse of the driver's current mapping) while the drives are enabled,
//            zero otherwise; encoder counts → their registers; the status word.
//   server   Modbus TCP on 127.0.0.1 (any number of clients, one request at a time) or Modbus RTU
//            on an already open file descriptor (a pty master), with optional fault injection.
//            It never sleeps: a reply that goes out late waits in an outbox (over TCP each late
//            reply on its own, later replies overtake it as a server that answers out of order
//            would; over RTU the line keeps order, so the replies behind it wait too), while the
//            server goes on taking requests and watching the heartbeat.
//
// The drive model behind the map's registers (hw_configs/README.md, "[bus.modbus]"):
//   enable         the drives follow the setpoints only while the enable register holds its `on`
//                  value (a map with no enable register is always enabled);
//   fault_reset    while its register holds the fault-reset value, a latched fault is cleared;
//   heartbeat      the drive-side watchdog: once the heartbeat register changed while enabled, it
//                  must keep changing; when it stays the same longer than the watchdog time
//                  (watchdog_timeout's register when the map has one, else the config's
//                  drive_watchdog_ms; 0: off), the drives go torque-free at once and latch a fault
//                  with the comm_lost bit (cleared by a fault reset);
//   status         its named bits (the config's `bits`): fault (latched; set_drive_fault() injects
//                  one; forces zero torque), comm_lost, enabled, ready (no fault, no e-stop), estop
//                  (set_estop());
//   setpoints      current (A) or motor torque (N·m) = scale · raw + bias, as the driver writes them.
//
// Late replies on command (tests): hold_replies() keeps the next replies back (built when their
// requests arrive, with the registers of that moment) until release_replies(), or until the next
// request (release_replies_with_next_request(): a late reply that arrives while the client waits
// for its next one); a client's timeout is then produced by the test, never by the machine's speed.
// Faults at run time (lancet-armsim --control): control() takes one command line (see there).
//
// Time: the drive model's clock (the heartbeat watchdog's) is CLOCK_MONOTONIC, or,
// with ServerOptions::manual_clock, a clock that only step_physics() advances (tests check the
// watchdog in simulated time). Delays and refusal windows always run on CLOCK_MONOTONIC.
//
// Not real-time: the server takes a mutex shared with the physics, and allocates.

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <limits>
#include <memory>
#include <mutex>
#include <random>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/arm_physics.hpp"
#include "device/device.hpp"
#include "device/modbus_arm.hpp"
#include "lancet/shared_model/geometry.hpp"
#include "lancet/shared_model/result.hpp"

struct _modbus;
struct _modbus_mapping_t;

namespace lancet::armsim {

/// What the simulated hand does with the stylus.
enum class HandMode : std::uint8_t {
  kScript,  ///< follows device::scripted_target around the centre of the config's safety workspace
  kHold,    ///< holds the stylus at the start pose (a spring to where it began)
  kFree,    ///< no hand: only the motors move the arm
};

/// Faults the server injects into its replies; all off by default.
struct FaultInjection {
  double drop_replies = 0;    ///< probability [0, 1] that a request gets no reply at all
  std::int64_t delay_us = 0;  ///< replies go out this late (µs): every one, or those delay_probability picks
                              ///< (the request itself acts at once; the reply carries the registers
                              ///< of its request's time)
  double delay_probability = 1;  ///< probability [0, 1] that a reply is delayed by delay_us
  double corrupt = 0;         ///< probability [0, 1] that one byte of a reply is flipped: over TCP in
                              ///< the framing (transaction id, function code, byte count: the client
                              ///< sees a protocol error, never a wrong value), over RTU anywhere past
                              ///< the byte count (the client sees a CRC error)
  double encoder_glitch = 0;  ///< probability [0, 1] that a reply carrying the encoder registers has
                              ///< one joint's count off by `glitch_counts`
  std::int64_t glitch_counts = 0;  ///< size of a glitch; 0: one motor revolution (counts_per_rev)
};

struct ServerOptions {
  HandMode hand = HandMode::kScript;
  FaultInjection faults;
  double disconnect_after = 0;  ///< s after a client's first write with the drives enabled: close every
                                ///< client's socket (TCP only; 0: never)
  double reconnect_after = 0;   ///< s after that disconnect during which new connections are refused
  std::uint64_t seed = 1;       ///< of the fault injection's random draws
  double physics_rate = 1000;   ///< Hz; 0: no physics thread (tests call step_physics)
  double script_depth = 0.01;   ///< m below the workspace centre that the scripted hand strokes at
  bool manual_clock = false;    ///< the drive model's clock advances only with step_physics() (tests)
};

/// What the server has done so far.
struct ServerStats {
  std::uint64_t requests = 0;     ///< requests received (any function)
  std::uint64_t replies = 0;      ///< replies sent (intact or corrupted)
  std::uint64_t dropped = 0;      ///< requests left unanswered on purpose
  std::uint64_t delayed = 0;      ///< replies sent late on purpose
  std::uint64_t corrupted = 0;    ///< replies sent with a flipped byte
  std::uint64_t glitches = 0;     ///< replies with an encoder glitch
  std::uint64_t connections = 0;  ///< TCP connections accepted
  std::uint64_t forced_disconnects = 0;  ///< times the clients were cut off on purpose
  std::uint64_t watchdog_trips = 0;      ///< times the heartbeat watchdog made the drives torque-free
  double last_trip_silence_ms = 0;       ///< how long the heartbeat had not changed at the last trip
  std::uint64_t held = 0;                ///< replies held back by hold_replies() so far
  std::uint64_t control_commands = 0;    ///< control() commands applied
};

/// A consistent copy of the simulated arm and its registers.
struct ArmSnapshot {
  int n = 0;
  std::array<std::int64_t, device::kMaxJoints> counts{};    ///< encoder counts as published (no glitch)
  std::array<double, device::kMaxJoints> q{};               ///< rad (m), the true joint positions
  std::array<double, device::kMaxJoints> current{};         ///< A, the motor currents the setpoint registers ask for
  std::array<double, device::kMaxJoints> motor_torque{};    ///< N·m (N) the motors gave in the last step
  bool enabled = false;      ///< drives on (enable register `on` and no fault)
  bool drive_fault = false;  ///< latched drive fault
  bool comm_lost = false;    ///< the heartbeat watchdog tripped (latched with the fault)
  bool estop = false;        ///< the e-stop is pressed
  std::uint32_t control = 0, status = 0, buttons = 0, heartbeat = 0;  ///< register words, raw (control: the enable register)
  double watchdog_ms = 0;    ///< the heartbeat watchdog time in force (0: off)
  std::uint64_t steps = 0;   ///< physics steps so far
  std::int64_t clock_ns = 0; ///< the drive model's clock (CLOCK_MONOTONIC, or the manual clock)
  Vec3 tool{}, target{};     ///< m, tool point and hand target (device frame)
  ServerStats stats;
};

class ArmServer {
 public:
  /// From a config with a [bus.modbus] register map (kInvalid otherwise). Starts nothing.
  [[nodiscard]] static Result<std::unique_ptr<ArmServer>> create(const arm::ArmConfig& config, const ServerOptions& options = {});
  ~ArmServer();  ///< stops
  ArmServer(const ArmServer&) = delete;
  ArmServer& operator=(const ArmServer&) = delete;

  /// Listens on 127.0.0.1:port (0: an ephemeral port) and starts the threads; returns the port.
  [[nodiscard]] Result<int> start_tcp(int port);
  /// Serves Modbus RTU on an open descriptor (e.g. a pty master; not closed by the server) and
  /// starts the threads.
  [[nodiscard]] Result<void> start_rtu(int fd);
  /// Stops and joins the threads, closes the clients and the listening socket. Idempotent.
  void stop();

  [[nodiscard]] int port() const noexcept { return port_; }
  [[nodiscard]] ArmSnapshot snapshot() const;

  // Test and demo hooks; thread-safe.
  void set_faults(const FaultInjection& faults);
  /// Latches a drive fault (the status' fault bit, zero torque) or clears it. A sticky fault
  /// ignores the fault reset (a drive that will not come back).
  void set_drive_fault(bool fault, bool sticky = false);
  /// Presses (or releases) the e-stop: the status' estop bit, zero torque while pressed.
  void set_estop(bool pressed);
  /// The raw word of the buttons register.
  void set_buttons(std::uint32_t raw);
  /// Puts the arm at q (rad / m) at rest and publishes its encoders.
  void set_pose(std::span<const double> q);
  /// Stops / resumes the physics thread's stepping (registers stay served).
  void pause_physics(bool paused);
  /// Advances the physics by `steps` steps of dt seconds now, on the calling thread (and the
  /// manual clock, when the server has one, by dt before each step, whose watchdog check sees it).
  void step_physics(double dt, int steps = 1);

  /// kUntilAccepted as a refusal time: until accept_connections().
  static constexpr double kUntilAccepted = std::numeric_limits<double>::infinity();
  /// TCP: stops listening, then closes every client's socket, and refuses connections for
  /// refuse_s seconds (0: listens on at once; kUntilAccepted: until accept_connections()). Returns
  /// once the server has done it. RTU: the same time without any reply (the line goes silent).
  void disconnect_clients(double refuse_s);
  /// Ends a refusal (or an RTU silence) now: listens again before returning.
  void accept_connections();

  /// The next n replies are held back (built when their requests arrive), until released.
  void hold_replies(int n);
  /// Replies held back now.
  [[nodiscard]] int held_replies() const;
  /// Sends the oldest n held replies now, in order (n < 0: all of them), before returning.
  void release_replies(int n = -1);
  /// The held replies go out when the next request arrives, just before its reply.
  void release_replies_with_next_request();
  /// Throws the held replies away: their requests are never answered.
  void discard_held_replies();

  /// A fault at run time (lancet-armsim --control; hw_configs/README.md), one command line:
  ///   fault              latch a drive fault (status fault bit, zero torque) until a fault reset
  ///   drop S             close the connections and refuse new ones for S seconds (RTU: no reply
  ///                      for S seconds)
  ///   late S [US]        every reply US µs late for S seconds (default: the faults' delay_us, or
  ///                      four times the config's response timeout)
  ///   garbage S          every reply corrupted (as FaultInjection::corrupt) for S seconds
  ///   glitch [COUNTS]    the next reply with encoder registers has joint 0 COUNTS off (default:
  ///                      the faults' glitch_counts, or one motor revolution)
  ///   clear              ends drop / late / garbage now (late replies waiting go out now) and
  ///                      forgets a glitch not yet sent; a latched drive fault stays until reset
  /// S may be "inf" (until clear). Returns the command as applied (its words, single-spaced), or
  /// kInvalid with what is wrong. Thread-safe; returns once the command has taken effect.
  [[nodiscard]] Result<std::string> control(const std::string& line);

 private:
  /// One entry of the map: where each of its values is and how it is coded.
  struct Field {
    bool present = false;
    arm::RegisterTable table = arm::RegisterTable::kInput;
    std::array<std::uint16_t, device::kMaxJoints> address{};
    device::modbus::Layout layout;
    double scale = 1, bias = 0;
  };

  ArmServer(const arm::ArmConfig& config, const ServerOptions& options, std::unique_ptr<device::ArmPhysics> physics);

  Result<void> init_mapping();
  void start_threads();
  void physics_loop();
  void tcp_loop();
  void rtu_loop(int fd);
  /// A reply on its way out: sent when due, unless held.
  struct Outgoing {
    int fd = -1;
    std::int64_t due_ns = 0;  // CLOCK_MONOTONIC
    bool held = false;
    bool delayed = false;
    std::vector<std::uint8_t> bytes;
  };

  void handle_request(int fd, const std::uint8_t* req, int len, int header_length);
  std::vector<std::uint8_t> build_reply(const std::uint8_t* req, int len);
  void corrupt_reply(std::vector<std::uint8_t>& bytes, bool tcp);
  bool maybe_glitch(const FaultInjection& f, const std::uint8_t* req, int header_length);
  void close_clients();
  bool relisten();
  void take_requests(std::int64_t now, bool& scheduled_done, std::int64_t& relisten_at);
  int poll_timeout_ms(std::int64_t now) const;

  // Under mu_.
  void send_due(std::int64_t now);
  void send_bytes(int fd, const std::vector<std::uint8_t>& bytes);
  void forget_replies_to(int fd);
  [[nodiscard]] std::int64_t drive_now() const noexcept;

  std::uint16_t* reg(const Field& f, int index = 0) const noexcept;
  std::uint32_t get_word(const Field& f) const noexcept;
  void put_word(const Field& f, std::uint32_t v) noexcept;
  double get_value(const Field& f, int index = 0) const noexcept;  ///< scale · raw + bias
  void put_value(const Field& f, double physical, int index = 0) noexcept;
  std::uint32_t status_word() const noexcept;
  void apply_control() noexcept;
  void watch_heartbeat(std::int64_t now_ns) noexcept;
  void step_locked(double dt) noexcept;
  void publish() noexcept;
  double uniform() noexcept;

  arm::ArmConfig config_;
  ServerOptions options_;
  Field encoders_, setpoints_, status_, buttons_, enable_, fault_reset_, heartbeat_, watchdog_timeout_;
  arm::StatusBits bits_;
  bool torque_setpoints_ = false;  // setpoints in N·m at the motor (else A)
  std::array<double, device::kMaxJoints> amps_per_unit_{};  // motor A per joint N·m (signed)

  mutable std::mutex mu_;
  std::condition_variable cv_;  // a hook's request was taken by the server thread
  std::unique_ptr<device::ArmPhysics> physics_;
  ::_modbus_mapping_t* mapping_ = nullptr;
  std::array<std::int64_t, device::kMaxJoints> published_{};
  std::array<double, device::kMaxJoints> current_{};
  bool enabled_ = false, drive_fault_ = false, fault_sticky_ = false, comm_lost_ = false, estop_ = false;
  // The heartbeat watchdog: armed by a change while enabled, tripped by none for watchdog time.
  std::uint32_t hb_last_ = 0;
  std::int64_t hb_changed_ns_ = 0;
  bool hb_armed_ = false;
  std::uint32_t buttons_raw_ = 0;
  std::uint64_t steps_ = 0;
  double sim_time_ = 0;
  Vec3 start_tool_{}, centre_{}, target_{};
  bool paused_ = false;
  ServerStats stats_;
  FaultInjection faults_;
  std::mt19937_64 rng_;
  double refuse_request_s_ = -1;  // set by disconnect_clients, taken by the server thread
  bool accept_request_ = false;   // set by accept_connections, taken by the server thread
  std::int64_t silent_until_ns_ = 0;  // RTU: no reply before this (disconnect_clients)
  std::int64_t clock_ns_ = 0;     // the manual clock
  // Replies on their way out, oldest first; the hooks that hold and release them.
  std::deque<Outgoing> outbox_;
  int hold_next_ = 0;
  bool release_with_next_ = false;
  // Faults at run time (control()): until when (CLOCK_MONOTONIC ns), and how.
  std::int64_t late_until_ns_ = 0, late_delay_us_ = 0, garbage_until_ns_ = 0;
  bool glitch_next_ = false;
  std::int64_t glitch_next_counts_ = 0;
  bool tcp_ = false;
  std::int64_t first_enabled_ns_ = 0;  // a client's first write that left the drives enabled (0: none yet)

  ::_modbus* ctx_ = nullptr;  // the server's libmodbus context (its socket is set per client)
  int listen_fd_ = -1;
  int port_ = 0;
  std::vector<int> clients_;  // under mu_ (the server thread changes it)
  bool started_ = false;
  std::atomic<bool> stop_{false};
  std::thread physics_thread_, serve_thread_;
};

/// Parses "script" / "hold" / "free".
[[nodiscard]] Result<HandMode> parse_hand_mode(const std::string& s);

}  // namespace lancet::armsim
