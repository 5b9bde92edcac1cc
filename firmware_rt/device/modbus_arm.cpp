#include "device/modbus_arm.hpp"

#include "device/joint_signals.hpp"
#include "lancet/shared_model/units.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <modbus.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>

#include <algorithm>
#include <bit>
#include <cassert>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <limits>
#include <thread>

#include "text/text.hpp"

namespace lancet::device {

namespace {

using modbus::RegisterBlock;
using modbus::RegisterSpan;

constexpr std::int64_t kSettleNs = 200'000'000;  // how long activate / rearm wait for the status bits to settle
constexpr std::uint8_t kReadHolding = 0x03, kReadInput = 0x04, kWriteMultiple = 0x10;
constexpr std::size_t kMbap = 7;  // TCP: transaction id, protocol id, length, unit id

const char* table_name(arm::RegisterTable t) { return t == arm::RegisterTable::kInput ? "input" : "holding"; }

std::string describe(const std::vector<RegisterBlock>& blocks) {
  std::string s;
  for (const RegisterBlock& b : blocks) {
    if (!s.empty()) s += ", ";
    s += std::string(table_name(b.table)) + " registers " + std::to_string(b.address) + ".." +
         std::to_string(b.address + b.count - 1);
  }
  return s;
}

RegisterSpan span_of(const arm::RegisterField& f, std::size_t value) {
  return {f.table, f.address[value], static_cast<std::uint16_t>(modbus::register_count(f.type))};
}

// Where a value landed in the planned blocks (its offset in the block buffer); false if absent.
bool locate(const std::vector<RegisterBlock>& blocks, const RegisterSpan& s, std::uint16_t& offset) {
  for (const RegisterBlock& b : blocks) {
    if (b.table == s.table && s.address >= b.address && s.address + s.count <= b.address + b.count) {
      offset = static_cast<std::uint16_t>(b.offset + (s.address - b.address));
      return true;
    }
  }
  return false;
}

bool touches(const RegisterSpan& s, const std::vector<RegisterBlock>& blocks) {
  for (const RegisterBlock& b : blocks)
    if (b.table == s.table && s.address <= b.address + b.count && b.address <= s.address + s.count) return true;
  return false;
}

int total(const std::vector<RegisterBlock>& blocks) {
  int n = 0;
  for (const RegisterBlock& b : blocks) n += b.count;
  return n;
}

std::string format_ms(double s) { return text::format("%g ms", s * 1e3); }

timespec to_timespec(std::int64_t ns) { return {static_cast<time_t>(ns / 1'000'000'000), static_cast<long>(ns % 1'000'000'000)}; }

std::uint16_t be16(const std::uint8_t* p) { return static_cast<std::uint16_t>((p[0] << 8) | p[1]); }

void put_be16(std::uint8_t* p, std::uint16_t v) {
  p[0] = static_cast<std::uint8_t>(v >> 8);
  p[1] = static_cast<std::uint8_t>(v & 0xFF);
}

bool same_place(const arm::RegisterField& a, const arm::RegisterField& b) {
  return a.table == b.table && a.address == b.address && a.type == b.type;
}

}  // namespace

void ModbusArm::ContextDeleter::operator()(::_modbus* ctx) const noexcept {
  modbus_close(ctx);
  modbus_free(ctx);
}

ModbusArm::ModbusArm(const arm::ArmConfig& config, FaultPolicy policy)
    : Device("modbus arm '" + config.name + "'", policy), config_(config), bus_(*config.modbus) {}

ModbusArm::~ModbusArm() = default;

Result<std::unique_ptr<ModbusArm>> ModbusArm::create(const arm::ArmConfig& config, FaultPolicy policy) {
  const std::string src = config.source.empty() ? "arm '" + config.name + "'" : config.source;
  if (!config.modbus)
    return Error{ErrorCode::kInvalid, src + ": the modbus backend needs a [bus.modbus] section (backend is not \"modbus\" or the section is missing)"};
  const int n = config.joint_count();
  if (n < 1 || n > kMaxJoints || static_cast<int>(config.joints.size()) != n || static_cast<int>(config.actuators.size()) != n)
    return Error{ErrorCode::kInvalid, src + ": the arm needs 1.." + std::to_string(kMaxJoints) + " joints with one joint and one actuator entry each (model has " +
                                          std::to_string(n) + ", found " + std::to_string(config.joints.size()) + " joints, " +
                                          std::to_string(config.actuators.size()) + " actuators)"};
  const arm::ModbusRegisterMap& map = config.modbus->registers;
  // What the loader guarantees, checked again for configs built in code.
  const auto bad = [&](const char* entry, const arm::RegisterField& f, std::size_t values, bool written, bool word) -> std::string {
    const std::string at = src + ": bus.modbus.registers." + entry + ": ";
    if (f.address.size() != values) return at + "expected " + std::to_string(values) + " address(es), found " + std::to_string(f.address.size());
    if (modbus::register_count(f.type) == 0) return at + "8-bit types do not fit Modbus registers";
    if (word && f.type != arm::FieldType::kU16 && f.type != arm::FieldType::kU32) return at + "expected type u16 or u32";
    if (written && f.table != arm::RegisterTable::kHolding) return at + "written registers must be holding registers";
    if (!(f.scale > 0) || !std::isfinite(f.scale) || !std::isfinite(f.bias)) return at + "scale must be > 0 and bias finite";
    return {};
  };
  const auto un = static_cast<std::size_t>(n);
  for (const std::string& e : {bad("encoder_counts", map.encoder_counts, un, false, false),
                               bad(map.setpoint_kind == arm::SetpointKind::kCurrent ? "current_command" : "torque_command", map.setpoint, un, true, false),
                               map.status ? bad("status", *map.status, 1, false, true) : std::string{},
                               map.buttons ? bad("buttons", *map.buttons, 1, false, true) : std::string{},
                               map.enable ? bad("enable", *map.enable, 1, true, true) : std::string{},
                               map.fault_reset ? bad("fault_reset", *map.fault_reset, 1, true, true) : std::string{},
                               map.heartbeat ? bad("heartbeat", *map.heartbeat, 1, true, true) : std::string{},
                               map.watchdog_timeout ? bad("watchdog_timeout", *map.watchdog_timeout, 1, true, true) : std::string{}})
    if (!e.empty()) return Error{ErrorCode::kInvalid, e};
  if (!(config.modbus->response_timeout > 0))
    return Error{ErrorCode::kInvalid, src + ": bus.modbus.response_timeout_ms: expected > 0"};

  std::unique_ptr<ModbusArm> a(new ModbusArm(config, policy));
  a->n_ = n;
  a->timeout_ns_ = std::max<std::int64_t>(1000, std::llround(config.modbus->response_timeout * 1e9));
  if (config.modbus->transport == arm::ModbusTransport::kTcp) {
    const bool ipv6 = config.modbus->host.find(':') != std::string::npos;
    a->endpoint_ = (ipv6 ? "[" + config.modbus->host + "]" : config.modbus->host) + ":" + std::to_string(config.modbus->port);
  } else {
    a->endpoint_ = config.modbus->device;
  }
  for (int j = 0; j < n; ++j) {
    const auto& jc = config.joints[static_cast<std::size_t>(j)];
    a->q_per_count_[static_cast<std::size_t>(j)] = arm::joint_position_from_counts(jc, 1) - arm::joint_position_from_counts(jc, 0);
  }

  // Reads: encoders, status, buttons, merged where their registers touch.
  std::vector<RegisterSpan> reads;
  for (std::size_t j = 0; j < un; ++j) reads.push_back(span_of(map.encoder_counts, j));
  if (map.status) reads.push_back(span_of(*map.status, 0));
  if (map.buttons) reads.push_back(span_of(*map.buttons, 0));
  a->read_blocks_ = modbus::plan_blocks(reads, MODBUS_MAX_READ_REGISTERS);
  const auto place = [](const std::vector<RegisterBlock>& blocks, const arm::RegisterField& f, std::size_t value, Slot& slot) {
    slot.present = locate(blocks, span_of(f, value), slot.offset);
    slot.layout = modbus::layout_of(f);
    return slot.present;
  };
  bool placed = true;
  for (std::size_t j = 0; j < un; ++j) placed = place(a->read_blocks_, map.encoder_counts, j, a->encoders_[j]) && placed;
  if (map.status) placed = place(a->read_blocks_, *map.status, 0, a->status_) && placed;
  if (map.buttons) placed = place(a->read_blocks_, *map.buttons, 0, a->buttons_) && placed;
  a->rbuf_.assign(static_cast<std::size_t>(total(a->read_blocks_)), 0);

  // Writes every tick: setpoints and the heartbeat; the enable word rides along (holding it as a
  // level) only where it costs no extra transaction.
  std::vector<RegisterSpan> writes;
  for (std::size_t j = 0; j < un; ++j) writes.push_back(span_of(map.setpoint, j));
  if (map.heartbeat) writes.push_back(span_of(*map.heartbeat, 0));
  a->write_blocks_ = modbus::plan_blocks(writes, MODBUS_MAX_WRITE_REGISTERS);
  if (map.enable && touches(span_of(*map.enable, 0), a->write_blocks_)) {
    writes.push_back(span_of(*map.enable, 0));
    auto merged = modbus::plan_blocks(writes, MODBUS_MAX_WRITE_REGISTERS);
    if (merged.size() <= a->write_blocks_.size()) a->write_blocks_ = std::move(merged);
  }
  for (std::size_t j = 0; j < un; ++j) placed = place(a->write_blocks_, map.setpoint, j, a->setpoints_[j]) && placed;
  if (map.heartbeat) placed = place(a->write_blocks_, *map.heartbeat, 0, a->heartbeat_) && placed;
  if (map.enable) (void)place(a->write_blocks_, *map.enable, 0, a->enable_);  // absent: written on its own
  a->wbuf_.assign(static_cast<std::size_t>(total(a->write_blocks_)), 0);
  if (!placed) return Error{ErrorCode::kInvalid, src + ": bus.modbus.registers: a value does not fit one Modbus transaction"};
  a->enable_word_ = map.enable_off;
  a->put_enable_word();
  return a;
}

// ---------------------------------------------------------------------------------------------
// Configure-time steps

Result<void> ModbusArm::fail(const std::string& what) const {
  const std::string where = tcp() ? "tcp " + endpoint_ + ", unit " + std::to_string(bus_.unit_id)
                                  : "rtu " + endpoint_ + " " + std::to_string(bus_.baud) + " baud, unit " + std::to_string(bus_.unit_id);
  return Result<void>::failure(ErrorCode::kInvalid, name() + " (" + where + "): " + what);
}

Result<void> ModbusArm::check(IoStatus s, const std::string& what) const {
  if (s == IoStatus::kOk) return Result<void>::success();
  Result<void> o = fail(what + " failed: " + last_error().c_str());
  // The link (refused, gone, silent) is a system failure; an arm that answers wrongly is invalid.
  if (s == IoStatus::kDisconnected || s == IoStatus::kTimeout) o.error().code = ErrorCode::kSystem;
  return o;
}

Result<void> ModbusArm::open_link(const std::string& what) {
  ::_modbus* c = ctx_.get();
  // connect() waits the response timeout; give it a sensible minimum.
  const auto us = std::max<std::int64_t>(1, std::llround(std::max(bus_.response_timeout, 1.0) * 1e6));
  (void)modbus_set_response_timeout(c, static_cast<std::uint32_t>(us / 1'000'000), static_cast<std::uint32_t>(us % 1'000'000));
  // The whole reply must arrive within the response timeout: no separate byte timeout.
  (void)modbus_set_byte_timeout(c, 0, 0);
  if (modbus_connect(c) == -1) {
    const int err = errno;
    last_errno_ = err;
    Result<void> o = fail(what + ": " + modbus_strerror(err));
    o.error().code = ErrorCode::kSystem;
    return o;
  }
  reset_stream();
  if (!tcp()) (void)modbus_flush(c);  // what the line held before we opened it is nobody's reply
  return Result<void>::success();
}

Result<void> ModbusArm::reopen_link(const std::string& what) {
  modbus_close(ctx_.get());
  link_broken_ = false;
  return open_link(what);
}

void ModbusArm::reset_stream() noexcept {
  rx_len_ = 0;
  tid_done_ = tid_;
  late_first_ = late_count_ = 0;
  need_flush_ = false;
}

void ModbusArm::set_response_timeout(double seconds) noexcept {
  if (!(seconds > 0) || !std::isfinite(seconds)) return;
  timeout_ns_ = std::max<std::int64_t>(1000, std::llround(std::min(seconds, 1e6) * 1e9));
  bus_.response_timeout = seconds;
}

void ModbusArm::set_clock(Clock clock) noexcept { clock_ = clock; }

Result<void> ModbusArm::write_word(const arm::RegisterField& f, std::uint32_t word, const std::string& what) {
  std::array<std::uint16_t, 2> regs{};
  modbus::encode_word(modbus::layout_of(f), word, regs);
  const int count = modbus::register_count(f.type);
  const IoStatus s = transact(kWriteMultiple, f.address[0], static_cast<std::uint16_t>(count), regs.data(), nullptr, f.table);
  char hex[16];
  std::snprintf(hex, sizeof hex, "0x%04X", static_cast<unsigned>(word));
  return check(s, what + " (" + hex + " to holding register " + std::to_string(f.address[0]) + ")");
}

void ModbusArm::put_enable_word() noexcept {
  if (enable_.present) modbus::encode_word(enable_.layout, enable_word_, std::span(wbuf_).subspan(enable_.offset));
}

Result<void> ModbusArm::write_enable(std::uint32_t word, const std::string& what) {
  enable_word_ = word;
  put_enable_word();
  if (!bus_.registers.enable) return Result<void>::success();
  return write_word(*bus_.registers.enable, word, what);
}

Result<void> ModbusArm::write_zero_setpoints(const std::string& what) {
  JointCommand zero{};
  zero.n = n_;
  encode_setpoints(zero);
  return check(write_blocks(), what + " (" + describe(write_blocks_) + ")");
}

Result<void> ModbusArm::read_status(const std::string& what, std::uint32_t& word) {
  Result<void> o = check(read_blocks(), what + " (" + describe(read_blocks_) + ")");
  word = o.ok() && status_.present ? modbus::decode_word(status_.layout, std::span<const std::uint16_t>(rbuf_).subspan(status_.offset)) : 0;
  return o;
}

Result<void> ModbusArm::enable_drives(const std::string& step, bool always_reset) {
  const arm::ModbusRegisterMap& m = bus_.registers;
  const arm::StatusBits& bits = m.status_bits;
  std::uint32_t word = 0;
  Result<void> o = read_status(step + ": reading the status", word);
  if (!o.ok()) return o;
  const auto faulted = [&](std::uint32_t w) { return bits.fault.active(w) || bits.comm_lost.active(w) || bits.estop.active(w); };
  if (m.fault_reset && (always_reset || faulted(word))) {
    o = write_word(*m.fault_reset, m.fault_reset_value, step + ": cannot write the fault reset");
    // A reset register of its own is pulsed: the next reset is a fresh edge.
    if (o.ok() && !(m.enable && same_place(*m.enable, *m.fault_reset)))
      o = write_word(*m.fault_reset, 0, step + ": cannot release the fault reset");
    if (!o.ok()) return o;
  }
  o = write_enable(m.enable_on, step + ": cannot switch the drives on");
  drives_on_ = o.ok();
  // A drive may take a moment to leave its fault or become enabled: give it kSettleNs.
  const std::int64_t give_up = monotonic_ns() + kSettleNs;
  char text[112];
  while (o.ok() && status_.present) {
    o = read_status(step + ": reading the status", word);
    if (!o.ok() || describe_status(bits, word, true, text, sizeof text) == 0) break;
    if (monotonic_ns() >= give_up) {
      if (faulted(word))
        o = fail(step + (m.fault_reset ? ": the drive still reports a fault after the fault reset (" : ": the drive reports a fault and the map has no fault_reset (") + text + ")");
      else
        o = fail(step + ": the drive is not ready " + format_ms(kSettleNs * 1e-9) + " after the enable (" + text + ")");
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  if (!o.ok()) {
    drives_on_ = false;
    (void)write_enable(m.enable_off, step + ": cannot switch the drives off again");  // best effort: stay disabled
  }
  return o;
}

Result<void> ModbusArm::on_configure() {
  ctx_.reset();
  link_broken_ = drives_on_ = false;
  ::_modbus* c = nullptr;
  if (tcp()) {
    in_addr probe{};
    if (inet_pton(AF_INET, bus_.host.c_str(), &probe) == 1)
      c = modbus_new_tcp(bus_.host.c_str(), bus_.port);
    else  // a name or an IPv6 address
      c = modbus_new_tcp_pi(bus_.host.c_str(), std::to_string(bus_.port).c_str());
  } else {
    const char parity = bus_.parity == arm::Parity::kNone ? 'N' : bus_.parity == arm::Parity::kEven ? 'E' : 'O';
    c = modbus_new_rtu(bus_.device.c_str(), bus_.baud, parity, bus_.data_bits, bus_.stop_bits);
  }
  if (c == nullptr) return fail(std::string("cannot create the libmodbus context: ") + modbus_strerror(errno));
  ctx_.reset(c);
  if (modbus_set_slave(c, bus_.unit_id) == -1) {
    const int err = errno;
    ctx_.reset();
    return fail("cannot set unit id " + std::to_string(bus_.unit_id) + ": " + modbus_strerror(err));
  }
  (void)modbus_set_error_recovery(c, MODBUS_ERROR_RECOVERY_NONE);  // we flush and reconnect ourselves
  Result<void> o = open_link(tcp() ? "cannot connect" : "cannot open the serial device");
  if (o.ok()) o = check(read_blocks(), "connected, but the arm does not answer: reading the " + describe(read_blocks_));
  if (!o.ok()) ctx_.reset();
  link_broken_ = false;
  return o;
}

Result<void> ModbusArm::on_activate() {
  // The link may have gone while inactive (or on the way out of a fault): connect afresh.
  Result<void> o = link_broken_ || modbus_get_socket(ctx_.get()) < 0 ? reopen_link(tcp() ? "activate: cannot reconnect" : "activate: cannot reopen the serial device")
                                                               : Result<void>::success();
  if (need_flush_) flush_input();
  const arm::ModbusRegisterMap& m = bus_.registers;
  if (o.ok() && m.watchdog_timeout) {
    const arm::RegisterField& f = *m.watchdog_timeout;
    const double raw = std::nearbyint((bus_.drive_watchdog * 1e3 - f.bias) / f.scale);
    o = write_word(f, static_cast<std::uint32_t>(std::clamp(raw, 0.0, f.type == arm::FieldType::kU16 ? 65535.0 : 4294967295.0)),
                   "activate: cannot write the drive watchdog time");
  }
  if (o.ok()) o = write_zero_setpoints("activate: cannot zero the setpoints");
  if (o.ok()) o = enable_drives("activate", false);
  velocity_.reset();
  return o;
}

Result<void> ModbusArm::on_deactivate() {
  if (need_flush_) flush_input();
  drives_on_ = false;
  // Both, whatever the first one says: the drives must end at zero and disabled.
  enable_word_ = bus_.registers.enable_off;
  Result<void> zero = write_zero_setpoints("cannot zero the setpoints");
  Result<void> off = write_enable(bus_.registers.enable_off, "cannot switch the drives off");
  return zero.ok() ? off : zero;
}

Result<void> ModbusArm::on_rearm() {
  // A broken link needs a new connection; so does a TCP stream that stopped making sense.
  Result<void> o = Result<void>::success();
  const bool garbled = tcp() && fault_cause() == IoStatus::kProtocolError;
  if (link_broken_ || garbled || modbus_get_socket(ctx_.get()) < 0)
    o = reopen_link(tcp() ? "rearm: cannot reconnect" : "rearm: cannot reopen the serial device");
  if (need_flush_) flush_input();
  if (o.ok()) o = write_zero_setpoints("rearm: cannot zero the setpoints");
  if (o.ok()) o = enable_drives("rearm", true);
  velocity_.reset();
  return o;
}

Result<void> ModbusArm::on_reconnect() {
  // The drives stay off: zero setpoints, enable `off`, in every write from now until rearm().
  drives_on_ = false;
  enable_word_ = bus_.registers.enable_off;
  Result<void> o = reopen_link(tcp() ? "reconnect: cannot connect" : "reconnect: cannot reopen the serial device");
  if (o.ok()) o = write_zero_setpoints("reconnect: cannot zero the setpoints");
  if (o.ok()) o = write_enable(bus_.registers.enable_off, "reconnect: cannot keep the drives off");
  if (o.ok()) o = check(read_blocks(), "reconnect: reading the " + describe(read_blocks_));
  if (!o.ok()) link_broken_ = true;  // still lost: the next reconnect opens it again
  velocity_.reset();
  return o;
}

// ---------------------------------------------------------------------------------------------
// Transactions (real-time path)

IoStatus ModbusArm::error(IoStatus s, std::uint32_t code, const char* fmt, ...) noexcept {
  char text[112];
  const int n = std::snprintf(text, sizeof text, "%s: ", endpoint_.c_str());
  va_list ap;
  va_start(ap, fmt);
  if (n >= 0 && static_cast<std::size_t>(n) < sizeof text) std::vsnprintf(text + n, sizeof text - static_cast<std::size_t>(n), fmt, ap);
  va_end(ap);
  note_error(s, bus_.unit_id, code, text);
  if (s == IoStatus::kDisconnected) link_broken_ = true;
  return s;
}

IoStatus ModbusArm::link_error(int err, const char* what) noexcept {
  last_errno_ = err;
  const IoStatus s = modbus::io_status_from_errno(err);
  char reason[64];
  std::snprintf(reason, sizeof reason, "%s", what != nullptr ? what : modbus_strerror(err));
  if (reason[0] != '\0') reason[0] = static_cast<char>(std::tolower(static_cast<unsigned char>(reason[0])));
  if (s != IoStatus::kTimeout) need_flush_ = true;
  return error(s, static_cast<std::uint32_t>(err), "%s", reason);
}

void ModbusArm::flush_input() noexcept {
  need_flush_ = false;
  rx_len_ = 0;
  if (!tcp()) {
    (void)modbus_flush(ctx_.get());
    return;
  }
  const int fd = modbus_get_socket(ctx_.get());
  if (fd < 0) return;
  // Drop whatever has arrived; a frame still on its way is recognised by its id later.
  while (recv(fd, rx_.data(), rx_.size(), MSG_DONTWAIT) > 0) {
  }
}

IoStatus ModbusArm::transact(std::uint8_t function, std::uint16_t address, std::uint16_t count, const std::uint16_t* src,
                             std::uint16_t* dst, arm::RegisterTable table) noexcept {
  const std::int64_t deadline = monotonic_ns() + timeout_ns_;
  if (need_flush_) flush_input();
  function_ = function;
  address_ = address;
  count_ = count;
  table_ = table;
  dst_ = dst;
  // The PDU, after the MBAP header (TCP) or the unit id (RTU).
  std::uint8_t* pdu = tx_.data() + (tcp() ? kMbap : 1);
  pdu[0] = function;
  put_be16(pdu + 1, address);
  put_be16(pdu + 3, count);
  std::size_t len = 5;
  if (function == kWriteMultiple) {
    pdu[5] = static_cast<std::uint8_t>(2 * count);
    for (std::uint16_t i = 0; i < count; ++i) put_be16(pdu + 6 + 2 * i, src[i]);
    len = 6 + 2 * static_cast<std::size_t>(count);
  }
  return tcp() ? tcp_transact(len, deadline) : rtu_transact(len, deadline);
}

IoStatus ModbusArm::tcp_transact(std::size_t pdu_len, std::int64_t deadline_ns) noexcept {
  const int fd = modbus_get_socket(ctx_.get());
  if (fd < 0) return error(IoStatus::kDisconnected, 0, "not connected (the link was lost)");
  ++tid_;
  put_be16(tx_.data(), tid_);
  put_be16(tx_.data() + 2, 0);
  put_be16(tx_.data() + 4, static_cast<std::uint16_t>(pdu_len + 1));
  tx_[6] = static_cast<std::uint8_t>(bus_.unit_id);
  const std::size_t total_len = kMbap + pdu_len;
  std::size_t sent = 0;
  while (sent < total_len) {
    const ssize_t r = send(fd, tx_.data() + sent, total_len - sent, MSG_NOSIGNAL | MSG_DONTWAIT);
    if (r > 0) {
      sent += static_cast<std::size_t>(r);
      continue;
    }
    if (r < 0 && errno != EAGAIN && errno != EINTR) return link_error(errno, nullptr);
    const std::int64_t left = deadline_ns - monotonic_ns();
    if (left <= 0) {
      // Half a request on the wire: the stream cannot be trusted any more.
      link_broken_ = true;
      return error(IoStatus::kDisconnected, ETIMEDOUT, "the request could not be sent within %.3g ms", static_cast<double>(timeout_ns_) * 1e-6);
    }
    pollfd p{fd, POLLOUT, 0};
    const timespec ts = to_timespec(left);
    (void)ppoll(&p, 1, &ts, nullptr);
  }
  for (;;) {
    const IoStatus s = tcp_receive(fd, deadline_ns);
    if (s != IoStatus::kOk) return s;
    const std::size_t frame = rx_len_;
    rx_len_ = 0;  // consumed
    const std::uint16_t tid = be16(rx_.data());
    if (tid != tid_) {
      // The id of a request that timed out: its reply came late. Owed ones are found in whatever
      // order they come; one sent since the last answered request is late even when forgotten.
      std::size_t k = 0;
      while (k < late_count_ && late_at(k).tid != tid) ++k;
      const auto age = static_cast<std::uint16_t>(tid - tid_done_);
      const auto outstanding = static_cast<std::uint16_t>(tid_ - tid_done_);
      if (k < late_count_ || (age >= 1 && age < outstanding)) {
        erase_late(k);
        count_stale_reply();
        continue;
      }
      need_flush_ = true;
      last_errno_ = EMBBADDATA;
      return error(IoStatus::kProtocolError, tid, "reply with transaction id 0x%04X, expected 0x%04X", tid, tid_);
    }
    tid_done_ = tid_;
    if (rx_[6] != static_cast<std::uint8_t>(bus_.unit_id)) {
      last_errno_ = EMBBADSLAVE;
      return error(IoStatus::kProtocolError, rx_[6], "reply from unit %u, expected unit %d", rx_[6], bus_.unit_id);
    }
    return check_reply(rx_.data() + kMbap, frame - kMbap);
  }
}

IoStatus ModbusArm::tcp_receive(int fd, std::int64_t deadline_ns) noexcept {
  for (;;) {
    std::size_t need = kMbap;
    if (rx_len_ >= kMbap) {
      const std::uint16_t length = be16(rx_.data() + 4);  // unit id + PDU
      if (be16(rx_.data() + 2) != 0 || length < 3 || length > 254) {
        // Not a Modbus TCP frame: we lost the stream's framing.
        need_flush_ = true;
        rx_len_ = 0;
        last_errno_ = EMBBADDATA;
        return error(IoStatus::kProtocolError, length, "unframeable reply (protocol id 0x%04X, length %u)", be16(rx_.data() + 2), length);
      }
      need = 6 + static_cast<std::size_t>(length);
    }
    if (rx_len_ == need && need > kMbap) return IoStatus::kOk;
    if (rx_len_ < need) {
      const std::int64_t left = deadline_ns - monotonic_ns();
      if (left <= 0) {
        // What arrived of the reply stays in rx_: the next transaction finishes and drops it.
        push_late({true, function_, address_, count_, tid_});
        last_errno_ = ETIMEDOUT;
        char what[48];
        std::snprintf(what, sizeof what, "%s %s registers %u..%u", function_ == kWriteMultiple ? "write" : "read",
                      table_name(table_), address_, address_ + count_ - 1u);
        return error(IoStatus::kTimeout, ETIMEDOUT, "timed out, no reply within %.3g ms to %s", static_cast<double>(timeout_ns_) * 1e-6, what);
      }
      pollfd p{fd, POLLIN, 0};
      const timespec ts = to_timespec(left);
      const int pr = ppoll(&p, 1, &ts, nullptr);
      if (pr < 0 && errno != EINTR) return link_error(errno, nullptr);
      if (pr <= 0) continue;
      const ssize_t r = recv(fd, rx_.data() + rx_len_, need - rx_len_, MSG_DONTWAIT);
      if (r == 0) return link_error(ECONNRESET, "connection closed by the server");
      if (r < 0) {
        if (errno == EAGAIN || errno == EINTR) continue;
        return link_error(errno, nullptr);
      }
      rx_len_ += static_cast<std::size_t>(r);
    }
  }
}

bool ModbusArm::reply_matches(const Signature& s, const std::uint8_t* pdu, std::size_t len) const noexcept {
  if (!s.valid || len < 2) return false;
  if (pdu[0] == (s.function | 0x80)) return true;
  if (pdu[0] != s.function) return false;
  if (s.function == kWriteMultiple) return len == 5 && be16(pdu + 1) == s.address && be16(pdu + 3) == s.count;
  return pdu[1] == 2 * s.count && len == 2 + 2 * static_cast<std::size_t>(s.count);
}

void ModbusArm::push_late(const Signature& s) noexcept {
  if (late_count_ == kMaxLateRequests) pop_late(1);  // the oldest is forgotten (see kMaxLateRequests)
  late_[(late_first_ + late_count_) % kMaxLateRequests] = s;
  ++late_count_;
}

void ModbusArm::pop_late(std::size_t k) noexcept {
  k = std::min(k, late_count_);
  late_first_ = (late_first_ + k) % kMaxLateRequests;
  late_count_ -= k;
}

void ModbusArm::erase_late(std::size_t i) noexcept {
  if (i >= late_count_) return;
  for (std::size_t k = i; k + 1 < late_count_; ++k) late_[(late_first_ + k) % kMaxLateRequests] = late_at(k + 1);
  --late_count_;
}

IoStatus ModbusArm::rtu_transact(std::size_t pdu_len, std::int64_t deadline_ns) noexcept {
  ::_modbus* c = ctx_.get();
  tx_[0] = static_cast<std::uint8_t>(bus_.unit_id);
  if (modbus_send_raw_request(c, tx_.data(), static_cast<int>(pdu_len + 1)) == -1) return link_error(errno, nullptr);
  const Signature current{true, function_, address_, count_, 0};
  for (;;) {
    const std::int64_t left = deadline_ns - monotonic_ns();
    const std::int64_t us = std::max<std::int64_t>(1, left / 1000);
    (void)modbus_set_response_timeout(c, static_cast<std::uint32_t>(us / 1'000'000), static_cast<std::uint32_t>(us % 1'000'000));
    const int n = left > 0 ? modbus_receive_confirmation(c, rx_.data()) : -1;
    const int err = left > 0 ? errno : ETIMEDOUT;
    if (n < 0) {
      if (err == ETIMEDOUT) {
        push_late(current);  // its reply may still come, after those owed before it
        last_errno_ = err;
        char what[48];
        std::snprintf(what, sizeof what, "%s %s registers %u..%u", function_ == kWriteMultiple ? "write" : "read",
                      table_name(table_), address_, address_ + count_ - 1u);
        return error(IoStatus::kTimeout, ETIMEDOUT, "timed out, no reply within %.3g ms to %s", static_cast<double>(timeout_ns_) * 1e-6, what);
      }
      if (err == EMBBADCRC) {
        // The garbled frame answered the request owed a reply first: an earlier one if any is owed
        // (then this one's reply may still come), else this one.
        if (late_count_ > 0) {
          pop_late(1);
          push_late(current);
        }
        need_flush_ = true;
        last_errno_ = err;
        return error(IoStatus::kCrcError, 0, "CRC error in the reply to %s %s registers %u..%u", function_ == kWriteMultiple ? "write" : "read",
                     table_name(table_), address_, address_ + count_ - 1u);
      }
      return link_error(err, nullptr);
    }
    if (n < 4 || rx_[0] != static_cast<std::uint8_t>(bus_.unit_id)) {
      need_flush_ = true;
      last_errno_ = EMBBADSLAVE;
      return error(IoStatus::kProtocolError, rx_[0], "reply from unit %u, expected unit %d", rx_[0], bus_.unit_id);
    }
    const std::uint8_t* pdu = rx_.data() + 1;
    const auto len = static_cast<std::size_t>(n - 3);  // less the unit id and the CRC
    // The line keeps order: the reply answers the oldest owed request it fits, and the ones owed
    // before that went unanswered. Where an owed request and this one look alike, the owed one
    // wins: at worst this request times out, never is a stale reading taken for a fresh one.
    std::size_t k = 0;
    while (k < late_count_ && !reply_matches(late_at(k), pdu, len)) ++k;
    if (k < late_count_) {
      pop_late(k + 1);
      count_stale_reply();
      continue;
    }
    late_count_ = 0;  // this request's reply (or a wrong one): no earlier reply is still coming
    return check_reply(pdu, len);
  }
}

IoStatus ModbusArm::check_reply(const std::uint8_t* pdu, std::size_t len) noexcept {
  char what[48];
  std::snprintf(what, sizeof what, "%s %s registers %u..%u", function_ == kWriteMultiple ? "write" : "read", table_name(table_),
                address_, address_ + count_ - 1u);
  if (len >= 2 && pdu[0] == (function_ | 0x80)) {
    last_errno_ = MODBUS_ENOBASE + pdu[1];
    return error(IoStatus::kProtocolError, pdu[1], "exception 0x%02X (%s) to %s", pdu[1], modbus::exception_name(pdu[1]), what);
  }
  const auto bad = [&](const char* why) {
    need_flush_ = true;
    last_errno_ = EMBBADDATA;
    return error(IoStatus::kProtocolError, pdu[0], "malformed reply to %s (%s)", what, why);
  };
  if (len < 1 || pdu[0] != function_) return bad("another function code");
  if (function_ == kWriteMultiple) {
    if (len != 5 || be16(pdu + 1) != address_ || be16(pdu + 3) != count_) return bad("wrong echo");
    return IoStatus::kOk;
  }
  if (len != 2 + 2 * static_cast<std::size_t>(count_) || pdu[1] != 2 * count_) return bad("wrong length");
  for (std::uint16_t i = 0; i < count_; ++i) dst_[i] = be16(pdu + 2 + 2 * i);
  return IoStatus::kOk;
}

IoStatus ModbusArm::read_blocks() noexcept {
  for (const RegisterBlock& b : read_blocks_) {
    const std::uint8_t fc = b.table == arm::RegisterTable::kInput ? kReadInput : kReadHolding;
    const IoStatus s = transact(fc, b.address, b.count, nullptr, rbuf_.data() + b.offset, b.table);
    if (s != IoStatus::kOk) return s;
  }
  return IoStatus::kOk;
}

IoStatus ModbusArm::write_blocks() noexcept {
  for (const RegisterBlock& b : write_blocks_) {
    const IoStatus s = transact(kWriteMultiple, b.address, b.count, wbuf_.data() + b.offset, nullptr, b.table);
    if (s != IoStatus::kOk) return s;
  }
  return IoStatus::kOk;
}

IoStatus ModbusArm::on_read(JointState& out) noexcept {
  const IoStatus s = read_blocks();
  if (s != IoStatus::kOk) return s;
  const std::int64_t now = clock_ != nullptr ? clock_() : monotonic_ns();
  const arm::ModbusRegisterMap& m = bus_.registers;
  const std::span<const std::uint16_t> regs(rbuf_);
  out.n = n_;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const Slot& e = encoders_[uj];
    const double counts = m.encoder_counts.scale * modbus::decode_value(e.layout, regs.subspan(e.offset)) + m.encoder_counts.bias;
    const double c = std::isfinite(counts) ? std::clamp(counts, -9.0e15, 9.0e15) : 0.0;
    const auto whole = static_cast<std::int64_t>(std::llround(c));
    out.counts[uj] = whole;
    // Exact for whole counts; a scaled encoder keeps its fraction of a count.
    out.q[uj] = arm::joint_position_from_counts(config_.joints[uj], whole) + (c - static_cast<double>(whole)) * q_per_count_[uj];
  }
  velocity_.update(n_, out.q, now, out.qd);
  out.status = status_.present ? modbus::decode_word(status_.layout, regs.subspan(status_.offset)) : 0;
  out.buttons = buttons_.present ? pressed_buttons(config_.buttons, modbus::decode_word(buttons_.layout, regs.subspan(buttons_.offset))) : 0;
  // While the driver has the drives off, the status is reported, not judged: activate() resets a
  // latched fault or refuses with the bits named.
  if (status_.present && drives_on_) {
    char text[112];
    if (describe_status(m.status_bits, out.status, true, text, sizeof text) > 0) {
      note_error(IoStatus::kDeviceFault, bus_.unit_id, out.status, text);
      return IoStatus::kDeviceFault;
    }
  }
  return IoStatus::kOk;
}

void ModbusArm::encode_setpoints(const JointCommand& cmd) noexcept {
  const arm::ModbusRegisterMap& m = bus_.registers;
  const arm::RegisterField& f = m.setpoint;
  const bool torque = m.setpoint_kind == arm::SetpointKind::kTorque;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const arm::ActuatorConfig& act = config_.actuators[uj];
    const double tau = j < cmd.n && std::isfinite(cmd.tau[uj]) ? cmd.tau[uj] : 0.0;
    double amps = arm::motor_current_for_joint_torque(config_.joints[uj], act, tau);
    if (!std::isfinite(amps)) amps = 0;
    if (amps > act.peak_current || amps < -act.peak_current) {
      amps = std::clamp(amps, -act.peak_current, act.peak_current);
      ++current_clamps_;
    }
    const double physical = torque ? amps * act.torque_constant : amps;
    bool clamped = false;
    const double raw = modbus::encode_value(setpoints_[uj].layout, (physical - f.bias) / f.scale,
                                            std::span(wbuf_).subspan(setpoints_[uj].offset), &clamped);
    if (clamped) ++current_clamps_;
    const double sent = f.scale * raw + f.bias;
    sent_current_[uj] = torque ? sent / act.torque_constant : sent;
  }
}

IoStatus ModbusArm::on_write(const JointCommand& cmd) noexcept {
  encode_setpoints(cmd);
  if (heartbeat_.present) {
    // Counts up and wraps within the register (u16: 0..65535).
    ++heartbeat_count_;
    if (heartbeat_.layout.type == arm::FieldType::kU16) heartbeat_count_ &= 0xFFFFu;
    modbus::encode_word(heartbeat_.layout, heartbeat_count_, std::span(wbuf_).subspan(heartbeat_.offset));
  }
  put_enable_word();
  return write_blocks();
}

}  // namespace lancet::device
