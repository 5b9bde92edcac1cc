#include "armsim/modbus_server.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <modbus.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <numbers>
#include <string>

#include "device/modbus_arm.hpp"
#include "device/sim_stylus.hpp"

namespace lancet::armsim {

namespace {

namespace mb = device::modbus;

constexpr int kTcpHeader = 7;  // MBAP header: the function code follows it
constexpr int kRtuHeader = 1;  // slave address
constexpr int kMaxClients = 16;
constexpr int kPollMs = 20;
constexpr double kApproachS = 1.5;  // the scripted hand's move from the start pose to the script

std::int64_t mono_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

bool is_write(int function) {
  return function == MODBUS_FC_WRITE_SINGLE_REGISTER || function == MODBUS_FC_WRITE_MULTIPLE_REGISTERS ||
         function == MODBUS_FC_WRITE_AND_READ_REGISTERS || function == MODBUS_FC_MASK_WRITE_REGISTER;
}

}  // namespace

Result<HandMode> parse_hand_mode(const std::string& s) {
  if (s == "script") return HandMode::kScript;
  if (s == "hold") return HandMode::kHold;
  if (s == "free") return HandMode::kFree;
  return Error{ErrorCode::kInvalid, "hand mode: expected script, hold or free, found '" + s + "'"};
}

ArmServer::ArmServer(const arm::ArmConfig& config, const ServerOptions& options, std::unique_ptr<device::ArmPhysics> physics)
    : config_(config), options_(options), physics_(std::move(physics)), faults_(options.faults), rng_(options.seed) {}

Result<std::unique_ptr<ArmServer>> ArmServer::create(const arm::ArmConfig& config, const ServerOptions& options) {
  if (!config.modbus)
    return Error{ErrorCode::kInvalid, (config.source.empty() ? config.name : config.source) +
                                          ": lancet-armsim serves the [bus.modbus] register map, and this config has none"};
  auto physics = device::ArmPhysics::create(config);
  if (!physics.ok()) return physics.error();
  std::unique_ptr<ArmServer> s(new ArmServer(config, options, std::move(physics).value()));
  const Result<void> o = s->init_mapping();
  if (!o.ok()) return o.error();
  return s;
}

ArmServer::~ArmServer() {
  stop();
  if (ctx_ != nullptr) modbus_free(ctx_);
  if (mapping_ != nullptr) modbus_mapping_free(mapping_);
}

Result<void> ArmServer::init_mapping() {
  const arm::ModbusRegisterMap& map = config_.modbus->registers;
  const int n = physics_->joint_count();
  const auto field = [](const arm::RegisterField& f) {
    Field out{true, f.table, {}, mb::layout_of(f), f.scale, f.bias};
    for (std::size_t i = 0; i < f.address.size() && i < out.address.size(); ++i) out.address[i] = f.address[i];
    return out;
  };
  encoders_ = field(map.encoder_counts);
  setpoints_ = field(map.setpoint);
  torque_setpoints_ = map.setpoint_kind == arm::SetpointKind::kTorque;
  if (map.status) status_ = field(*map.status);
  bits_ = map.status_bits;
  if (map.buttons) buttons_ = field(*map.buttons);
  if (map.enable) enable_ = field(*map.enable);
  if (map.fault_reset) fault_reset_ = field(*map.fault_reset);
  if (map.heartbeat) heartbeat_ = field(*map.heartbeat);
  if (map.watchdog_timeout) watchdog_timeout_ = field(*map.watchdog_timeout);

  // Each table spans from its lowest to its highest mapped register.
  struct Span {
    unsigned lo = 0xFFFFFFFFu, hi = 0;
  } input, holding;
  const auto cover = [&](const Field& f, int values) {
    if (!f.present) return;
    Span& s = f.table == arm::RegisterTable::kInput ? input : holding;
    for (int v = 0; v < values; ++v) {
      const unsigned a = f.address[static_cast<std::size_t>(v)];
      s.lo = std::min<unsigned>(s.lo, a);
      s.hi = std::max<unsigned>(s.hi, a + static_cast<unsigned>(mb::register_count(f.layout.type)));
    }
  };
  cover(encoders_, n);
  cover(setpoints_, n);
  for (const Field* f : {&status_, &buttons_, &enable_, &fault_reset_, &heartbeat_, &watchdog_timeout_}) cover(*f, 1);
  const auto start = [](const Span& s) { return s.hi > s.lo ? s.lo : 0u; };
  const auto count = [](const Span& s) { return s.hi > s.lo ? s.hi - s.lo : 0u; };
  mapping_ = modbus_mapping_new_start_address(0, 0, 0, 0, start(holding), count(holding), start(input), count(input));
  if (mapping_ == nullptr)
    return Result<void>::failure(ErrorCode::kSystem, std::string("lancet-armsim: cannot allocate the register mapping: ") + modbus_strerror(errno));
  // The enable register starts `off`, the fault reset released.
  if (enable_.present) put_word(enable_, map.enable_off);

  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    amps_per_unit_[uj] = arm::motor_current_for_joint_torque(config_.joints[uj], config_.actuators[uj], 1.0);
  }
  start_tool_ = physics_->tool_position();
  centre_ = 0.5 * (config_.safety.workspace_min + config_.safety.workspace_max);
  target_ = start_tool_;
  if (options_.hand == HandMode::kFree) physics_->set_hand_holding(false);
  std::lock_guard lock(mu_);
  apply_control();
  publish();
  return Result<void>::success();
}

// ---------------------------------------------------------------------------------------------
// Registers and the drive model (under mu_)

std::uint16_t* ArmServer::reg(const Field& f, int index) const noexcept {
  const int at = f.address[static_cast<std::size_t>(index)];
  if (f.table == arm::RegisterTable::kInput) return mapping_->tab_input_registers + (at - mapping_->start_input_registers);
  return mapping_->tab_registers + (at - mapping_->start_registers);
}

std::uint32_t ArmServer::get_word(const Field& f) const noexcept {
  if (!f.present) return 0;
  return mb::decode_word(f.layout, std::span<const std::uint16_t>(reg(f), static_cast<std::size_t>(mb::register_count(f.layout.type))));
}

void ArmServer::put_word(const Field& f, std::uint32_t v) noexcept {
  if (!f.present) return;
  mb::encode_word(f.layout, v, std::span<std::uint16_t>(reg(f), static_cast<std::size_t>(mb::register_count(f.layout.type))));
}

double ArmServer::get_value(const Field& f, int index) const noexcept {
  if (!f.present) return 0;
  const auto n = static_cast<std::size_t>(mb::register_count(f.layout.type));
  return f.scale * mb::decode_value(f.layout, std::span<const std::uint16_t>(reg(f, index), n)) + f.bias;
}

void ArmServer::put_value(const Field& f, double physical, int index) noexcept {
  if (!f.present) return;
  const auto n = static_cast<std::size_t>(mb::register_count(f.layout.type));
  (void)mb::encode_value(f.layout, (physical - f.bias) / f.scale, std::span<std::uint16_t>(reg(f, index), n));
}

std::uint32_t ArmServer::status_word() const noexcept {
  std::uint32_t w = 0;
  const auto set = [&w](const arm::StatusBit& b, bool active) {
    if (b.mapped() && active != b.active_low) w |= 1u << b.bit;
  };
  set(bits_.fault, drive_fault_);
  set(bits_.comm_lost, comm_lost_);
  set(bits_.enabled, enabled_);
  set(bits_.ready, !drive_fault_ && !estop_);
  set(bits_.estop, estop_);
  return w;
}

void ArmServer::apply_control() noexcept {
  const arm::ModbusRegisterMap& map = config_.modbus->registers;
  if (fault_reset_.present && get_word(fault_reset_) == map.fault_reset_value && !fault_sticky_) {
    drive_fault_ = false;
    comm_lost_ = false;
  }
  const bool on = !enable_.present || get_word(enable_) == map.enable_on;
  enabled_ = on && !drive_fault_ && !estop_;
  watch_heartbeat(drive_now());
  put_word(status_, status_word());
}

void ArmServer::watch_heartbeat(std::int64_t now_ns) noexcept {
  if (!heartbeat_.present) return;
  const std::uint32_t hb = get_word(heartbeat_);
  if (hb != hb_last_) {
    hb_last_ = hb;
    hb_changed_ns_ = now_ns;
    if (enabled_) hb_armed_ = true;
  }
  if (!enabled_) {
    hb_armed_ = false;
    return;
  }
  // The watchdog time the drive was given (its register), else the config's.
  const double ms = watchdog_timeout_.present ? get_value(watchdog_timeout_) : config_.modbus->drive_watchdog * 1e3;
  if (!hb_armed_ || !(ms > 0) || static_cast<double>(now_ns - hb_changed_ns_) <= ms * 1e6) return;
  // The host stopped: torque-free now, and a fault that only a fault reset clears.
  hb_armed_ = false;
  drive_fault_ = true;
  comm_lost_ = true;
  enabled_ = false;
  for (auto& c : current_) c = 0;
  ++stats_.watchdog_trips;
  stats_.last_trip_silence_ms = static_cast<double>(now_ns - hb_changed_ns_) * 1e-6;
  put_word(status_, status_word());
}

void ArmServer::publish() noexcept {
  for (int j = 0; j < physics_->joint_count(); ++j) {
    const std::int64_t c = physics_->encoder_counts(j);
    published_[static_cast<std::size_t>(j)] = c;
    put_value(encoders_, static_cast<double>(c), j);
  }
  put_word(buttons_, buttons_raw_);
  put_word(status_, status_word());
}

std::int64_t ArmServer::drive_now() const noexcept { return options_.manual_clock ? clock_ns_ : mono_ns(); }

void ArmServer::step_locked(double dt) noexcept {
  if (options_.manual_clock) clock_ns_ += std::llround(dt * 1e9);
  apply_control();
  device::JointCommand cmd{};
  cmd.n = physics_->joint_count();
  for (int j = 0; j < cmd.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double setpoint = get_value(setpoints_, j);
    current_[uj] = torque_setpoints_ ? setpoint / config_.actuators[uj].torque_constant : setpoint;
    // The inverse of the driver's mapping: joint torque = current / (current per unit torque).
    cmd.tau[uj] = enabled_ && amps_per_unit_[uj] != 0 ? current_[uj] / amps_per_unit_[uj] : 0.0;
  }
  if (options_.hand == HandMode::kScript) {
    const Vec3 first = centre_ + device::scripted_target(0, options_.script_depth);
    if (sim_time_ < kApproachS) {
      const double s = 0.5 - 0.5 * std::cos(std::numbers::pi * sim_time_ / kApproachS);
      target_ = start_tool_ + s * (first - start_tool_);
    } else {
      target_ = centre_ + device::scripted_target(sim_time_ - kApproachS, options_.script_depth);
    }
    physics_->set_hand_target(target_);
  }
  physics_->step(cmd, dt);
  sim_time_ += dt;
  ++steps_;
  publish();
}

double ArmServer::uniform() noexcept { return std::uniform_real_distribution<double>(0.0, 1.0)(rng_); }

// ---------------------------------------------------------------------------------------------
// Hooks

ArmSnapshot ArmServer::snapshot() const {
  std::lock_guard lock(mu_);
  ArmSnapshot s;
  s.n = physics_->joint_count();
  for (int j = 0; j < s.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    s.counts[uj] = published_[uj];
    s.q[uj] = physics_->q(j);
    const double setpoint = get_value(setpoints_, j);
    s.current[uj] = torque_setpoints_ ? setpoint / config_.actuators[uj].torque_constant : setpoint;
    s.motor_torque[uj] = physics_->motor_torque(j);
  }
  s.enabled = enabled_;
  s.drive_fault = drive_fault_;
  s.comm_lost = comm_lost_;
  s.estop = estop_;
  s.control = get_word(enable_);
  s.status = get_word(status_);
  s.buttons = buttons_raw_;
  s.heartbeat = get_word(heartbeat_);
  s.watchdog_ms = !heartbeat_.present ? 0.0 : watchdog_timeout_.present ? get_value(watchdog_timeout_) : config_.modbus->drive_watchdog * 1e3;
  s.steps = steps_;
  s.clock_ns = drive_now();
  s.tool = physics_->tool_position();
  s.target = target_;
  s.stats = stats_;
  return s;
}

void ArmServer::set_faults(const FaultInjection& faults) {
  std::lock_guard lock(mu_);
  faults_ = faults;
}

void ArmServer::set_drive_fault(bool fault, bool sticky) {
  std::lock_guard lock(mu_);
  drive_fault_ = fault;
  fault_sticky_ = fault && sticky;
  apply_control();
}

void ArmServer::set_estop(bool pressed) {
  std::lock_guard lock(mu_);
  estop_ = pressed;
  apply_control();
}

void ArmServer::set_buttons(std::uint32_t raw) {
  std::lock_guard lock(mu_);
  buttons_raw_ = raw;
  put_word(buttons_, raw);
}

void ArmServer::set_pose(std::span<const double> q) {
  std::lock_guard lock(mu_);
  physics_->reset(q);
  publish();
}

void ArmServer::pause_physics(bool paused) {
  std::lock_guard lock(mu_);
  paused_ = paused;
}

void ArmServer::step_physics(double dt, int steps) {
  std::lock_guard lock(mu_);
  for (int i = 0; i < steps; ++i) step_locked(dt);
}

void ArmServer::disconnect_clients(double refuse_s) {
  std::unique_lock lock(mu_);
  refuse_request_s_ = refuse_s > 0 ? refuse_s : 0.0;  // NaN: 0
  // The server thread takes it within its poll period; without one there is nothing to cut.
  if (serve_thread_.joinable()) cv_.wait(lock, [this] { return refuse_request_s_ < 0 || stop_; });
}

void ArmServer::accept_connections() {
  std::unique_lock lock(mu_);
  accept_request_ = true;
  if (serve_thread_.joinable()) cv_.wait(lock, [this] { return !accept_request_ || stop_; });
}

void ArmServer::hold_replies(int n) {
  std::lock_guard lock(mu_);
  hold_next_ += std::max(0, n);
}

int ArmServer::held_replies() const {
  std::lock_guard lock(mu_);
  return static_cast<int>(std::count_if(outbox_.begin(), outbox_.end(), [](const Outgoing& o) { return o.held; }));
}

void ArmServer::release_replies(int n) {
  std::lock_guard lock(mu_);
  for (Outgoing& o : outbox_) {
    if (n == 0) break;
    if (!o.held) continue;
    o.held = false;
    o.due_ns = 0;
    if (n > 0) --n;
  }
  send_due(mono_ns());
}

void ArmServer::release_replies_with_next_request() {
  std::lock_guard lock(mu_);
  release_with_next_ = true;
}

void ArmServer::discard_held_replies() {
  std::lock_guard lock(mu_);
  std::erase_if(outbox_, [](const Outgoing& o) { return o.held; });
}

Result<std::string> ArmServer::control(const std::string& line) {
  std::vector<std::string> words;
  for (std::size_t i = 0; i < line.size();) {
    while (i < line.size() && std::isspace(static_cast<unsigned char>(line[i])) != 0) ++i;
    std::size_t j = i;
    while (j < line.size() && std::isspace(static_cast<unsigned char>(line[j])) == 0) ++j;
    if (j > i) words.push_back(line.substr(i, j - i));
    i = j;
  }
  std::string applied;
  for (const std::string& w : words) applied += (applied.empty() ? "" : " ") + w;
  const auto bad = [&](const std::string& why) { return Error{ErrorCode::kInvalid, "'" + applied + "': " + why}; };
  if (words.empty()) return bad("an empty command (expected fault, drop S, late S [US], garbage S, glitch [COUNTS] or clear)");
  const std::string& cmd = words[0];
  // S: seconds, >= 0, or inf; US / COUNTS: whole numbers.
  const auto seconds = [&](std::size_t i, double& out) {
    if (i >= words.size()) return false;
    char* end = nullptr;
    out = std::strtod(words[i].c_str(), &end);
    return end != nullptr && *end == '\0' && out >= 0;  // NaN fails
  };
  const auto whole = [&](std::size_t i, std::int64_t& out, std::int64_t lo, std::int64_t hi) {
    char* end = nullptr;
    const long long v = std::strtoll(words[i].c_str(), &end, 10);
    out = v;
    return end != nullptr && *end == '\0' && !words[i].empty() && v >= lo && v <= hi;
  };
  const auto until = [](double s) {
    return std::isinf(s) ? std::numeric_limits<std::int64_t>::max() : mono_ns() + static_cast<std::int64_t>(std::min(s, 1e9) * 1e9);
  };
  double s = 0;
  if (cmd == "fault" && words.size() == 1) {
    set_drive_fault(true);
  } else if (cmd == "drop" && words.size() == 2 && seconds(1, s)) {
    disconnect_clients(s);
  } else if (cmd == "late" && (words.size() == 2 || words.size() == 3) && seconds(1, s)) {
    std::int64_t us = 0;
    if (words.size() == 3 && !whole(2, us, 1, 3'600'000'000)) return bad("the delay: expected microseconds, 1..3600000000");
    std::lock_guard lock(mu_);
    if (us == 0) us = faults_.delay_us > 0 ? faults_.delay_us : std::max<std::int64_t>(1000, std::llround(4e6 * config_.modbus->response_timeout));
    late_delay_us_ = us;
    late_until_ns_ = until(s);
  } else if (cmd == "garbage" && words.size() == 2 && seconds(1, s)) {
    std::lock_guard lock(mu_);
    garbage_until_ns_ = until(s);
  } else if (cmd == "glitch" && words.size() <= 2) {
    std::int64_t counts = 0;
    if (words.size() == 2 && !whole(1, counts, 1, 1'000'000'000)) return bad("the size: expected counts, 1..1000000000");
    std::lock_guard lock(mu_);
    glitch_next_ = true;
    glitch_next_counts_ = counts;
  } else if (cmd == "clear" && words.size() == 1) {
    {
      std::lock_guard lock(mu_);
      late_until_ns_ = garbage_until_ns_ = 0;
      glitch_next_ = false;
      // Late replies already waiting go out now (in their order).
      for (Outgoing& o : outbox_)
        if (o.delayed) o.due_ns = 0;
      send_due(mono_ns());
    }
    accept_connections();
  } else {
    return bad("expected fault, drop S, late S [US], garbage S, glitch [COUNTS] or clear (S: seconds or inf)");
  }
  std::lock_guard lock(mu_);
  ++stats_.control_commands;
  return applied;
}

// ---------------------------------------------------------------------------------------------
// Threads

Result<int> ArmServer::start_tcp(int port) {
  if (started_) return Error{ErrorCode::kInUse, "lancet-armsim: already serving"};
  // Bind with a throwaway context (it may ask for port 0), then serve with one that knows the port
  // we got, so that a re-listen after a refusal window takes the same port.
  modbus_t* probe = modbus_new_tcp("127.0.0.1", port);
  if (probe == nullptr) return Error{ErrorCode::kSystem, std::string("lancet-armsim: modbus_new_tcp: ") + modbus_strerror(errno)};
  listen_fd_ = modbus_tcp_listen(probe, kMaxClients);
  const int listen_err = errno;
  modbus_free(probe);
  if (listen_fd_ < 0)
    return Error{ErrorCode::kSystem, "lancet-armsim: cannot listen on 127.0.0.1:" + std::to_string(port) + ": " + modbus_strerror(listen_err)};
  sockaddr_in addr{};
  socklen_t len = sizeof addr;
  if (getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
    const int err = errno;
    close(listen_fd_);
    listen_fd_ = -1;
    return Error{ErrorCode::kSystem, std::string("lancet-armsim: getsockname: ") + std::strerror(err)};
  }
  port_ = ntohs(addr.sin_port);
  ctx_ = modbus_new_tcp("127.0.0.1", port_);
  if (ctx_ == nullptr) {
    close(listen_fd_);
    listen_fd_ = -1;
    return Error{ErrorCode::kSystem, std::string("lancet-armsim: modbus_new_tcp: ") + modbus_strerror(errno)};
  }
  (void)modbus_set_slave(ctx_, config_.modbus->unit_id);
  (void)modbus_set_indication_timeout(ctx_, 1, 0);
  tcp_ = true;
  start_threads();
  serve_thread_ = std::thread([this] { tcp_loop(); });
  return port_;
}

Result<void> ArmServer::start_rtu(int fd) {
  if (started_) return Result<void>::failure(ErrorCode::kInUse, "lancet-armsim: already serving");
  // The serial settings do not matter: the context never opens a device, it is given fd.
  ctx_ = modbus_new_rtu("/dev/null", 115200, 'N', 8, 1);
  if (ctx_ == nullptr)
    return Result<void>::failure(ErrorCode::kSystem, std::string("lancet-armsim: modbus_new_rtu: ") + modbus_strerror(errno));
  if (modbus_set_slave(ctx_, config_.modbus->unit_id) == -1)
    return Result<void>::failure(ErrorCode::kInvalid, "lancet-armsim: bad unit id " + std::to_string(config_.modbus->unit_id));
  (void)modbus_set_indication_timeout(ctx_, 1, 0);
  (void)modbus_set_socket(ctx_, fd);
  tcp_ = false;
  start_threads();
  serve_thread_ = std::thread([this, fd] { rtu_loop(fd); });
  return Result<void>::success();
}

void ArmServer::start_threads() {
  started_ = true;
  stop_ = false;
  if (options_.physics_rate > 0) physics_thread_ = std::thread([this] { physics_loop(); });
}

void ArmServer::stop() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (physics_thread_.joinable()) physics_thread_.join();
  if (serve_thread_.joinable()) serve_thread_.join();
  std::lock_guard lock(mu_);
  close_clients();
  if (listen_fd_ >= 0) {
    close(listen_fd_);
    listen_fd_ = -1;
  }
  outbox_.clear();
}

void ArmServer::physics_loop() {
  const double dt = 1.0 / options_.physics_rate;
  const auto period = static_cast<std::int64_t>(1e9 * dt);
  std::int64_t next = mono_ns();
  while (!stop_) {
    {
      std::lock_guard lock(mu_);
      if (!paused_) step_locked(dt);
    }
    next += period;
    const std::int64_t now = mono_ns();
    if (now - next > 50'000'000) next = now;  // fell far behind (debugger, loaded machine): no catch-up burst
    timespec ts{static_cast<time_t>(next / 1'000'000'000), static_cast<long>(next % 1'000'000'000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
  }
}

void ArmServer::close_clients() {
  for (int fd : clients_) {
    forget_replies_to(fd);
    shutdown(fd, SHUT_RDWR);
    close(fd);
  }
  clients_.clear();
}

bool ArmServer::relisten() {
  listen_fd_ = modbus_tcp_listen(ctx_, kMaxClients);
  return listen_fd_ >= 0;
}

void ArmServer::take_requests(std::int64_t now, bool& scheduled_done, std::int64_t& relisten_at) {
  std::lock_guard lock(mu_);
  // Cutting the clients off: on schedule (--disconnect-after, from a client's first write with the
  // drives enabled) or on request (disconnect_clients, control()).
  double refuse_s = -1;
  if (!scheduled_done && first_enabled_ns_ != 0 && now - first_enabled_ns_ >= static_cast<std::int64_t>(options_.disconnect_after * 1e9)) {
    scheduled_done = true;
    refuse_s = options_.reconnect_after;
  }
  if (refuse_request_s_ >= 0) {
    refuse_s = refuse_request_s_;
    refuse_request_s_ = -1;
    cv_.notify_all();
  }
  const auto end_of = [now](double s) {
    return std::isinf(s) ? std::numeric_limits<std::int64_t>::max() : now + static_cast<std::int64_t>(std::min(s, 1e9) * 1e9);
  };
  if (refuse_s >= 0) {
    ++stats_.forced_disconnects;
    if (tcp_) {
      // The listening socket first: a client that sees its connection go finds nobody listening.
      if (refuse_s > 0) {
        if (listen_fd_ >= 0) close(listen_fd_);  // connection attempts now get ECONNREFUSED
        listen_fd_ = -1;
        relisten_at = end_of(refuse_s);
      }
      close_clients();
    } else {
      silent_until_ns_ = end_of(refuse_s);
    }
  }
  if (accept_request_) {
    accept_request_ = false;
    relisten_at = 0;
    silent_until_ns_ = 0;
    if (tcp_ && listen_fd_ < 0 && !relisten()) relisten_at = now + 50'000'000;
    cv_.notify_all();
  }
  if (tcp_ && listen_fd_ < 0 && now >= relisten_at && !relisten()) relisten_at = now + 50'000'000;
  // The drive-side watchdog runs with or without the physics thread.
  watch_heartbeat(drive_now());
  send_due(now);
}

int ArmServer::poll_timeout_ms(std::int64_t now) const {
  std::lock_guard lock(mu_);
  std::int64_t ms = kPollMs;
  std::vector<int> seen;  // RTU: only the first reply on the line can go
  for (const Outgoing& o : outbox_) {
    if (!tcp_) {
      if (std::find(seen.begin(), seen.end(), o.fd) != seen.end()) continue;
      seen.push_back(o.fd);
    }
    if (!o.held) ms = std::min(ms, std::max<std::int64_t>(0, (o.due_ns - now + 999'999) / 1'000'000));
  }
  return static_cast<int>(ms);
}

void ArmServer::tcp_loop() {
  std::vector<std::uint8_t> query(MODBUS_TCP_MAX_ADU_LENGTH);
  std::vector<pollfd> pfds;
  bool scheduled_done = options_.disconnect_after <= 0;
  std::int64_t relisten_at = 0;
  while (!stop_) {
    take_requests(mono_ns(), scheduled_done, relisten_at);
    pfds.clear();
    {
      std::lock_guard lock(mu_);
      if (listen_fd_ >= 0) pfds.push_back({listen_fd_, POLLIN, 0});
      for (int fd : clients_) pfds.push_back({fd, POLLIN, 0});
    }
    if (poll(pfds.data(), pfds.size(), poll_timeout_ms(mono_ns())) <= 0) continue;
    std::size_t i = 0;
    if (!pfds.empty() && pfds[0].fd == listen_fd_ && listen_fd_ >= 0) {
      if ((pfds[0].revents & POLLIN) != 0) {
        const int fd = accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
        if (fd >= 0) {
          std::lock_guard lock(mu_);
          if (static_cast<int>(clients_.size()) >= kMaxClients) {
            close(fd);
          } else {
            const int one = 1;
            (void)setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
            clients_.push_back(fd);
            ++stats_.connections;
          }
        }
      }
      i = 1;
    }
    std::vector<int> gone;
    for (; i < pfds.size(); ++i) {
      if ((pfds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
      const int fd = pfds[i].fd;
      (void)modbus_set_socket(ctx_, fd);
      const int rc = modbus_receive(ctx_, query.data());
      if (rc > 0) {
        handle_request(fd, query.data(), rc, kTcpHeader);
      } else if (rc < 0) {
        gone.push_back(fd);  // closed by the client, or garbage we cannot frame
      }
    }
    std::lock_guard lock(mu_);
    for (int fd : gone) {
      forget_replies_to(fd);
      close(fd);
      clients_.erase(std::remove(clients_.begin(), clients_.end(), fd), clients_.end());
    }
  }
}

void ArmServer::rtu_loop(int fd) {
  std::vector<std::uint8_t> query(MODBUS_RTU_MAX_ADU_LENGTH);
  bool scheduled_done = true;  // no connections to cut
  std::int64_t relisten_at = 0;
  while (!stop_) {
    take_requests(mono_ns(), scheduled_done, relisten_at);
    pollfd p{fd, POLLIN, 0};
    if (poll(&p, 1, poll_timeout_ms(mono_ns())) <= 0) continue;
    if ((p.revents & POLLIN) == 0) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));  // nobody has the other end open
      continue;
    }
    (void)modbus_set_socket(ctx_, fd);
    const int rc = modbus_receive(ctx_, query.data());
    if (rc > 0) {
      handle_request(fd, query.data(), rc, kRtuHeader);
    } else if (rc < 0) {
      if (errno == EIO) std::this_thread::sleep_for(std::chrono::milliseconds(10));
      (void)modbus_flush(ctx_);  // a garbled or partial request: start afresh
    }
  }
}

bool ArmServer::maybe_glitch(const FaultInjection& f, const std::uint8_t* req, int h) {
  const bool once = glitch_next_;
  const int function = req[h];
  if ((!once && !(f.encoder_glitch > 0)) || (function != MODBUS_FC_READ_INPUT_REGISTERS && function != MODBUS_FC_READ_HOLDING_REGISTERS)) return false;
  const auto table = function == MODBUS_FC_READ_INPUT_REGISTERS ? arm::RegisterTable::kInput : arm::RegisterTable::kHolding;
  if (table != encoders_.table) return false;
  const int addr = (req[h + 1] << 8) | req[h + 2];
  const int nb = (req[h + 3] << 8) | req[h + 4];
  const int rc = mb::register_count(encoders_.layout.type);
  const int n = physics_->joint_count();
  // The joints whose registers this request reads.
  int joints[device::kMaxJoints];
  int k = 0;
  for (int j = 0; j < n; ++j) {
    const int a = encoders_.address[static_cast<std::size_t>(j)];
    if (a + rc > addr && a < addr + nb) joints[k++] = j;
  }
  if (k == 0) return false;
  int j = joints[0];
  std::int64_t size = 0;
  if (once) {
    // control("glitch"): the first joint this reply carries, upwards.
    glitch_next_ = false;
    size = glitch_next_counts_ != 0 ? glitch_next_counts_ : f.glitch_counts;
  } else {
    if (!(uniform() < f.encoder_glitch)) return false;
    j = joints[static_cast<int>(uniform() * k) % k];
    size = f.glitch_counts;
  }
  if (size == 0) size = config_.joints[static_cast<std::size_t>(j)].counts_per_rev;
  if (!once && uniform() < 0.5) size = -size;
  put_value(encoders_, static_cast<double>(published_[static_cast<std::size_t>(j)] + size), j);
  ++stats_.glitches;
  return true;
}

std::vector<std::uint8_t> ArmServer::build_reply(const std::uint8_t* req, int len) {
  // Let libmodbus build the reply into a socket pair and take it from the other end.
  std::vector<std::uint8_t> out;
  int sp[2];
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sp) != 0) return out;
  (void)modbus_set_socket(ctx_, sp[0]);
  (void)modbus_reply(ctx_, req, len, mapping_);
  std::uint8_t buf[MODBUS_TCP_MAX_ADU_LENGTH + 8];
  const ssize_t got = recv(sp[1], buf, sizeof buf, MSG_DONTWAIT);
  close(sp[0]);
  close(sp[1]);
  if (got > 0) out.assign(buf, buf + got);
  return out;
}

void ArmServer::corrupt_reply(std::vector<std::uint8_t>& buf, bool tcp) {
  const std::size_t size = buf.size();
  if (size == 0) return;
  std::size_t at = 0;
  if (tcp) {
    // A byte the client checks: the transaction id, the function code or (reads) the byte count.
    const std::size_t choices[4] = {0, 1, 7, 8};
    const bool read_reply = size > 9 && (buf[7] == MODBUS_FC_READ_INPUT_REGISTERS || buf[7] == MODBUS_FC_READ_HOLDING_REGISTERS);
    const std::size_t k = static_cast<std::size_t>(uniform() * (read_reply ? 4 : 3)) % (read_reply ? 4 : 3);
    at = std::min(choices[k], size - 1);
  } else {
    // Past slave, function and byte count: the CRC catches it, the frame length stays right.
    at = size > 3 ? 3 + static_cast<std::size_t>(uniform() * static_cast<double>(size - 3)) % (size - 3) : size - 1;
  }
  const auto mask = static_cast<std::uint8_t>(1 + static_cast<int>(uniform() * 255) % 255);
  buf[at] = static_cast<std::uint8_t>(buf[at] ^ mask);
}

void ArmServer::send_bytes(int fd, const std::vector<std::uint8_t>& bytes) {
  if (bytes.empty()) return;
  if (tcp_)
    (void)send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
  else
    (void)write(fd, bytes.data(), bytes.size());
  ++stats_.replies;
}

void ArmServer::send_due(std::int64_t now) {
  // Over RTU a reply waits for every earlier one on the line; over TCP each goes when due.
  std::vector<int> blocked;
  for (auto it = outbox_.begin(); it != outbox_.end();) {
    const bool behind = !tcp_ && std::find(blocked.begin(), blocked.end(), it->fd) != blocked.end();
    if (!behind && !it->held && it->due_ns <= now) {
      send_bytes(it->fd, it->bytes);
      it = outbox_.erase(it);
      continue;
    }
    if (!tcp_) blocked.push_back(it->fd);
    ++it;
  }
}

void ArmServer::forget_replies_to(int fd) {
  std::erase_if(outbox_, [fd](const Outgoing& o) { return o.fd == fd; });
}

void ArmServer::handle_request(int fd, const std::uint8_t* req, int len, int header_length) {
  std::lock_guard lock(mu_);
  const std::int64_t now = mono_ns();
  ++stats_.requests;
  if (release_with_next_) {
    // The held replies go out first: late replies arriving while the client waits for this one.
    release_with_next_ = false;
    for (Outgoing& o : outbox_) {
      if (!o.held) continue;
      o.held = false;
      o.due_ns = 0;
    }
  }
  send_due(now);
  // The start-up faults, with what control() asked for on top.
  FaultInjection f = faults_;
  if (now < late_until_ns_) {
    f.delay_us = late_delay_us_;
    f.delay_probability = 1;
  }
  if (now < garbage_until_ns_) f.corrupt = 1;
  const bool silent = now < silent_until_ns_;
  const bool drop = silent || (f.drop_replies > 0 && uniform() < f.drop_replies);
  const bool corrupt = !drop && f.corrupt > 0 && (f.corrupt >= 1 || uniform() < f.corrupt);
  const bool delay = !drop && f.delay_us > 0 && (f.delay_probability >= 1 || uniform() < f.delay_probability);
  const bool hold = !drop && hold_next_ > 0;
  if (drop) {
    ++stats_.dropped;
    return;  // as if the request was lost: not applied, not answered
  }
  if (hold) {
    --hold_next_;
    ++stats_.held;
  }
  if (delay) ++stats_.delayed;
  const bool glitched = maybe_glitch(f, req, header_length);
  const bool waiting = !tcp_ && std::any_of(outbox_.begin(), outbox_.end(), [fd](const Outgoing& o) { return o.fd == fd; });
  if (!corrupt && !delay && !hold && !waiting) {
    (void)modbus_set_socket(ctx_, fd);
    (void)modbus_reply(ctx_, req, len, mapping_);
    ++stats_.replies;
  } else {
    Outgoing o{fd, delay ? now + f.delay_us * 1000 : now, hold, delay, build_reply(req, len)};
    if (corrupt) {
      corrupt_reply(o.bytes, tcp_);
      ++stats_.corrupted;
    }
    outbox_.push_back(std::move(o));
    send_due(now);
    (void)modbus_set_socket(ctx_, fd);
  }
  if (glitched)
    for (int j = 0; j < physics_->joint_count(); ++j) put_value(encoders_, static_cast<double>(published_[static_cast<std::size_t>(j)]), j);
  // Control writes act at once (a fault reset clears the status the client reads next).
  if (is_write(req[header_length])) {
    apply_control();
    if (enabled_ && first_enabled_ns_ == 0) first_enabled_ns_ = now;  // --disconnect-after counts from here
  }
}

}  // namespace lancet::armsim
