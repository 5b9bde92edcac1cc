#include "device/modbus_arm.hpp"

#include "device/joint_signals.hpp"
#include "lancet/shared_model/units.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <modbus.h>
#include <time.h>

#include <algorithm>
#include <cassert>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <thread>

namespace lancet::device {

namespace modbus {

namespace {

struct Range {
  std::int64_t lo, hi;
};

Range range_of(arm::FieldType t) noexcept {
  switch (t) {
    case arm::FieldType::kU8: return {0, 0xFF};
    case arm::FieldType::kI8: return {-0x80, 0x7F};
    case arm::FieldType::kU16: return {0, 0xFFFF};
    case arm::FieldType::kI16: return {-0x8000, 0x7FFF};
    case arm::FieldType::kU32: return {0, 0xFFFF'FFFF};
    case arm::FieldType::kI32: return {-0x8000'0000LL, 0x7FFF'FFFF};
  }
  return {0, 0};
}

}  // namespace

int register_count(arm::FieldType type) noexcept {
  switch (type) {
    case arm::FieldType::kU16:
    case arm::FieldType::kI16: return 1;
    case arm::FieldType::kU32:
    case arm::FieldType::kI32: return 2;
    case arm::FieldType::kU8:
    case arm::FieldType::kI8: return 0;
  }
  return 0;
}

std::int64_t decode_registers(arm::FieldType type, bool high_word_first, std::span<const std::uint16_t> regs) noexcept {
  assert(regs.size() >= static_cast<std::size_t>(register_count(type)) && "modbus::decode_registers: span too short");
  switch (type) {
    case arm::FieldType::kU16: return regs[0];
    case arm::FieldType::kI16: return static_cast<std::int16_t>(regs[0]);
    case arm::FieldType::kU32:
    case arm::FieldType::kI32: {
      const std::uint32_t hi = high_word_first ? regs[0] : regs[1];
      const std::uint32_t lo = high_word_first ? regs[1] : regs[0];
      const std::uint32_t v = (hi << 16) | lo;
      return type == arm::FieldType::kU32 ? static_cast<std::int64_t>(v) : static_cast<std::int64_t>(static_cast<std::int32_t>(v));
    }
    case arm::FieldType::kU8:
    case arm::FieldType::kI8: return 0;
  }
  return 0;
}

bool encode_registers(arm::FieldType type, bool high_word_first, std::int64_t v, std::span<std::uint16_t> regs) noexcept {
  assert(regs.size() >= static_cast<std::size_t>(register_count(type)) && "modbus::encode_registers: span too short");
  const Range r = range_of(type);
  const std::int64_t c = std::clamp(v, r.lo, r.hi);
  // Two's complement bit pattern of the (clamped) value, low 32 bits.
  const auto bits = static_cast<std::uint32_t>(static_cast<std::uint64_t>(c) & 0xFFFF'FFFFu);
  switch (register_count(type)) {
    case 1: regs[0] = static_cast<std::uint16_t>(bits & 0xFFFFu); break;
    case 2: {
      const auto hi = static_cast<std::uint16_t>(bits >> 16);
      const auto lo = static_cast<std::uint16_t>(bits & 0xFFFFu);
      regs[0] = high_word_first ? hi : lo;
      regs[1] = high_word_first ? lo : hi;
      break;
    }
    default: break;
  }
  return c != v;
}

IoStatus io_status_from_errno(int err) noexcept {
  switch (err) {
    case 0: return IoStatus::kOk;
    case ETIMEDOUT:
    case EAGAIN:
    case EINTR: return IoStatus::kTimeout;  // no complete reply in time
    case EMBBADCRC: return IoStatus::kCrcError;
    case ECONNRESET:
    case EPIPE:
    case ECONNREFUSED:
    case ECONNABORTED:
    case EBADF:
    case ENOTCONN:
    case ENOTSOCK:
    case EIO:
    case ENXIO:
    case ENODEV:
    case ENETDOWN:
    case ENETUNREACH:
    case EHOSTUNREACH:
    case EHOSTDOWN:
    case ESHUTDOWN: return IoStatus::kDisconnected;
    default: return IoStatus::kProtocolError;  // EMBBADDATA, EMBBADEXC, EMBMDATA, EMBBADSLAVE, EMBX*, …
  }
}

std::vector<RegisterBlock> plan_blocks(std::vector<RegisterSpan> spans, int max_registers) {
  std::sort(spans.begin(), spans.end(), [](const RegisterSpan& a, const RegisterSpan& b) {
    return a.table != b.table ? a.table < b.table : a.address < b.address;
  });
  std::vector<RegisterBlock> blocks;
  int offset = 0;
  for (const RegisterSpan& s : spans) {
    if (s.count == 0) continue;
    if (!blocks.empty()) {
      RegisterBlock& b = blocks.back();
      const int end = b.address + b.count;
      const int new_end = std::max(end, s.address + s.count);
      if (b.table == s.table && s.address <= end && new_end - b.address <= max_registers) {
        offset += new_end - end;
        b.count = static_cast<std::uint16_t>(new_end - b.address);
        continue;
      }
    }
    blocks.push_back({s.table, s.address, s.count, static_cast<std::uint16_t>(offset)});
    offset += s.count;
  }
  return blocks;
}

}  // namespace modbus

namespace {

using modbus::RegisterBlock;
using modbus::RegisterSpan;

constexpr std::int64_t kRearmSettleNs = 100'000'000;  // how long rearm waits for a drive fault to clear

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

RegisterSpan span_of(const arm::RegisterField& f, int values) {
  return {f.table, f.address, static_cast<std::uint16_t>(modbus::register_count(f.type) * values)};
}

// Where a field landed in the planned blocks (its offset in the block buffer); false if absent.
bool locate(const std::vector<RegisterBlock>& blocks, const RegisterSpan& s, std::uint16_t& offset) {
  for (const RegisterBlock& b : blocks) {
    if (b.table == s.table && s.address >= b.address && s.address + s.count <= b.address + b.count) {
      offset = static_cast<std::uint16_t>(b.offset + (s.address - b.address));
      return true;
    }
  }
  return false;
}

bool touches(const RegisterSpan& a, const std::vector<RegisterBlock>& blocks) {
  for (const RegisterBlock& b : blocks)
    if (b.table == a.table && (a.address + a.count == b.address || b.address + b.count == a.address)) return true;
  return false;
}

int total(const std::vector<RegisterBlock>& blocks) {
  int n = 0;
  for (const RegisterBlock& b : blocks) n += b.count;
  return n;
}

std::string format_ms(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g ms", s * 1e3);
  return buf;
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
  const auto bad_type = [&](const char* entry, const arm::RegisterField& f, bool signed_only) {
    const bool ok = modbus::register_count(f.type) > 0 && (!signed_only || f.type == arm::FieldType::kI16 || f.type == arm::FieldType::kI32);
    return ok ? std::string{} : src + ": bus.modbus.registers." + entry + ": expected type " + (signed_only ? "i16 or i32" : "u16, i16, u32 or i32");
  };
  for (const std::string& e : {bad_type("encoder_counts", map.encoder_counts, false), bad_type("current_command", map.current_command, true),
                               map.status ? bad_type("status", *map.status, false) : std::string{},
                               map.buttons ? bad_type("buttons", *map.buttons, false) : std::string{},
                               map.control ? bad_type("control", *map.control, false) : std::string{},
                               map.heartbeat ? bad_type("heartbeat", *map.heartbeat, false) : std::string{}})
    if (!e.empty()) return Error{ErrorCode::kInvalid, e};
  if (map.current_command.table != arm::RegisterTable::kHolding || !(map.current_command.lsb > 0) ||
      (map.control && map.control->table != arm::RegisterTable::kHolding) || (map.heartbeat && map.heartbeat->table != arm::RegisterTable::kHolding))
    return Error{ErrorCode::kInvalid, src + ": bus.modbus.registers: current_command, control and heartbeat must be holding registers, and current_command needs lsb_ma > 0"};
  if (!(config.modbus->response_timeout > 0))
    return Error{ErrorCode::kInvalid, src + ": bus.modbus.response_timeout_ms: expected > 0"};

  std::unique_ptr<ModbusArm> a(new ModbusArm(config, policy));
  a->n_ = n;
  if (bus_is_tcp(config.modbus->transport)) {
    const bool ipv6 = config.modbus->host.find(':') != std::string::npos;
    a->endpoint_ = (ipv6 ? "[" + config.modbus->host + "]" : config.modbus->host) + ":" + std::to_string(config.modbus->port);
  } else {
    a->endpoint_ = config.modbus->device;
  }

  // Reads: encoders, status, buttons, merged where contiguous.
  std::vector<RegisterSpan> reads{span_of(map.encoder_counts, n)};
  if (map.status) reads.push_back(span_of(*map.status, 1));
  if (map.buttons) reads.push_back(span_of(*map.buttons, 1));
  a->read_blocks_ = modbus::plan_blocks(reads, MODBUS_MAX_READ_REGISTERS);
  const auto place = [](const std::vector<RegisterBlock>& blocks, const arm::RegisterField& f, int values, Slot& slot) {
    slot.present = locate(blocks, span_of(f, values), slot.offset);
    slot.type = f.type;
  };
  place(a->read_blocks_, map.encoder_counts, n, a->encoders_);
  if (map.status) place(a->read_blocks_, *map.status, 1, a->status_);
  if (map.buttons) place(a->read_blocks_, *map.buttons, 1, a->buttons_);
  a->rbuf_.assign(static_cast<std::size_t>(total(a->read_blocks_)), 0);

  // Writes every tick: currents and the heartbeat; the control word rides along (holding the
  // enable bit as a level) only where it costs no extra transaction.
  std::vector<RegisterSpan> writes{span_of(map.current_command, n)};
  if (map.heartbeat) writes.push_back(span_of(*map.heartbeat, 1));
  a->write_blocks_ = modbus::plan_blocks(writes, MODBUS_MAX_WRITE_REGISTERS);
  if (map.control && touches(span_of(*map.control, 1), a->write_blocks_)) {
    writes.push_back(span_of(*map.control, 1));
    auto merged = modbus::plan_blocks(writes, MODBUS_MAX_WRITE_REGISTERS);
    if (merged.size() <= a->write_blocks_.size()) a->write_blocks_ = std::move(merged);
  }
  place(a->write_blocks_, map.current_command, n, a->currents_);
  if (map.heartbeat) place(a->write_blocks_, *map.heartbeat, 1, a->heartbeat_);
  if (map.control) place(a->write_blocks_, *map.control, 1, a->control_);
  a->wbuf_.assign(static_cast<std::size_t>(total(a->write_blocks_)), 0);
  if (!a->encoders_.present || !a->currents_.present)
    return Error{ErrorCode::kInvalid, src + ": bus.modbus.registers: the encoder or current registers do not fit one Modbus transaction"};
  return a;
}

bool ModbusArm::bus_is_tcp(arm::ModbusTransport t) noexcept { return t == arm::ModbusTransport::kTcp; }

// ---------------------------------------------------------------------------------------------
// Configure-time steps

Outcome ModbusArm::fail(const std::string& what, int err) const {
  std::string where = bus_is_tcp(bus_.transport)
                          ? "tcp " + endpoint_ + ", unit " + std::to_string(bus_.unit_id)
                          : "rtu " + endpoint_ + " " + std::to_string(bus_.baud) + " baud, unit " + std::to_string(bus_.unit_id);
  std::string msg = name() + " (" + where + "): " + what;
  if (err != 0) {
    msg += ": ";
    msg += modbus_strerror(err);
    if (err == ETIMEDOUT) msg += " (no reply within " + format_ms(bus_.response_timeout) + ")";
  }
  // The link (refused, gone, silent) is a system failure; an arm that answers wrongly is invalid.
  const IoStatus s = modbus::io_status_from_errno(err);
  const bool link = s == IoStatus::kDisconnected || s == IoStatus::kTimeout || (err != 0 && err < MODBUS_ENOBASE);
  return Outcome::failure(link ? ErrorCode::kSystem : ErrorCode::kInvalid, msg);
}

Outcome ModbusArm::connect(const std::string& what) {
  ::_modbus* c = ctx_.get();
  // TCP's connect() waits the response timeout; give it a sensible minimum, then the config's.
  const double connect_s = std::max(bus_.response_timeout, 1.0);
  const auto set_timeout = [c](double s) {
    const auto us = std::max<std::int64_t>(1, std::llround(s * 1e6));
    return modbus_set_response_timeout(c, static_cast<std::uint32_t>(us / 1'000'000), static_cast<std::uint32_t>(us % 1'000'000));
  };
  if (set_timeout(connect_s) == -1) return fail("cannot set the response timeout", errno);
  if (modbus_connect(c) == -1) {
    const int err = errno;
    return fail(what, err);
  }
  // The whole reply must arrive within the response timeout: no separate byte timeout.
  if (set_timeout(bus_.response_timeout) == -1 || modbus_set_byte_timeout(c, 0, 0) == -1) {
    const int err = errno;
    modbus_close(c);
    return fail("cannot set the response timeout", err);
  }
  return Outcome::success();
}

Outcome ModbusArm::check_read(const std::string& what) {
  const IoStatus s = read_blocks();
  if (s != IoStatus::kOk) return fail(what + " (" + describe(read_blocks_) + ") failed", last_errno_);
  return Outcome::success();
}

Outcome ModbusArm::write_control(std::uint32_t word, const std::string& what) {
  if (!bus_.registers.control) return Outcome::success();
  const arm::RegisterField& f = *bus_.registers.control;
  std::array<std::uint16_t, 2> regs{};
  (void)modbus::encode_registers(f.type, bus_.registers.high_word_first, word, regs);
  const int count = modbus::register_count(f.type);
  if (modbus_write_registers(ctx_.get(), f.address, count, regs.data()) != count) {
    const int err = errno;
    (void)io_error(err);
    return fail(what + " (holding register " + std::to_string(f.address) + ")", err);
  }
  if (control_.present)
    (void)modbus::encode_registers(f.type, bus_.registers.high_word_first, word, std::span(wbuf_).subspan(control_.offset));
  return Outcome::success();
}

Outcome ModbusArm::write_zero_current(const std::string& what) {
  const arm::RegisterField& f = bus_.registers.current_command;
  const int rc = modbus::register_count(f.type);
  for (int j = 0; j < n_; ++j) {
    (void)modbus::encode_registers(f.type, bus_.registers.high_word_first, 0,
                                   std::span(wbuf_).subspan(static_cast<std::size_t>(currents_.offset + j * rc)));
    sent_current_[static_cast<std::size_t>(j)] = 0;
  }
  const int count = rc * n_;
  if (modbus_write_registers(ctx_.get(), f.address, count, wbuf_.data() + currents_.offset) != count) {
    const int err = errno;
    (void)io_error(err);
    return fail(what + " (holding registers " + std::to_string(f.address) + ".." + std::to_string(f.address + count - 1) + ")", err);
  }
  return Outcome::success();
}

void ModbusArm::reset_velocity() noexcept { velocity_.reset(); }

Outcome ModbusArm::on_configure() {
  ctx_.reset();
  link_broken_ = need_flush_ = false;
  ::_modbus* c = nullptr;
  if (bus_is_tcp(bus_.transport)) {
    in_addr probe{};
    if (inet_pton(AF_INET, bus_.host.c_str(), &probe) == 1)
      c = modbus_new_tcp(bus_.host.c_str(), bus_.port);
    else  // a name or an IPv6 address
      c = modbus_new_tcp_pi(bus_.host.c_str(), std::to_string(bus_.port).c_str());
  } else {
    const char parity = bus_.parity == arm::Parity::kNone ? 'N' : bus_.parity == arm::Parity::kEven ? 'E' : 'O';
    c = modbus_new_rtu(bus_.device.c_str(), bus_.baud, parity, bus_.data_bits, bus_.stop_bits);
  }
  if (c == nullptr) return fail("cannot create the libmodbus context", errno);
  ctx_.reset(c);
  if (modbus_set_slave(c, bus_.unit_id) == -1) {
    const int err = errno;
    ctx_.reset();
    return fail("cannot set unit id " + std::to_string(bus_.unit_id), err);
  }
  (void)modbus_set_error_recovery(c, MODBUS_ERROR_RECOVERY_NONE);  // we flush and reconnect ourselves
  Outcome o = connect(bus_is_tcp(bus_.transport) ? "cannot connect" : "cannot open the serial device");
  if (o.ok()) o = check_read("connected, but the arm does not answer: reading the encoder registers");
  if (!o.ok()) ctx_.reset();
  link_broken_ = need_flush_ = false;
  return o;
}

Outcome ModbusArm::reconnect_if_needed(const std::string& step) {
  ::_modbus* c = ctx_.get();
  if (link_broken_ || modbus_get_socket(c) < 0) {
    modbus_close(c);
    Outcome o = connect(step + (bus_is_tcp(bus_.transport) ? ": cannot reconnect" : ": cannot reopen the serial device"));
    if (!o.ok()) return o;
  } else if (need_flush_) {
    (void)modbus_flush(c);
  }
  link_broken_ = need_flush_ = false;
  return Outcome::success();
}

Outcome ModbusArm::on_activate() {
  // The link may have gone while inactive (or on the way out of a fault): connect afresh.
  Outcome o = reconnect_if_needed("activate");
  if (o.ok()) o = write_zero_current("cannot zero the current commands");
  if (o.ok()) {
    control_word_ = modbus::kControlEnable;
    o = write_control(control_word_, "cannot set the enable bit of the control register");
    if (!o.ok()) control_word_ = 0;
  }
  reset_velocity();
  return o;
}

Outcome ModbusArm::on_deactivate() {
  if (need_flush_) (void)modbus_flush(ctx_.get());
  need_flush_ = false;
  // Both, whatever the first one says: the drives must end at zero and disabled.
  Outcome zero = write_zero_current("cannot zero the current commands");
  control_word_ = 0;
  Outcome off = write_control(0, "cannot clear the enable bit of the control register");
  return zero.ok() ? off : zero;
}

Outcome ModbusArm::on_rearm() {
  // A broken link needs a new connection; over TCP so do timeouts and garbled replies, whose late
  // or leftover bytes would otherwise poison the next transactions on the old stream.
  const IoStatus cause = fault_cause();
  if (bus_is_tcp(bus_.transport) && (cause == IoStatus::kTimeout || cause == IoStatus::kProtocolError || cause == IoStatus::kCrcError))
    link_broken_ = true;
  need_flush_ = true;
  Outcome o = reconnect_if_needed("rearm");
  if (o.ok()) o = write_zero_current("rearm: cannot zero the current commands");
  if (o.ok()) o = write_control(modbus::kControlFaultReset, "rearm: cannot write the fault-reset bit of the control register");
  if (o.ok()) {
    control_word_ = modbus::kControlEnable;
    o = write_control(control_word_, "rearm: cannot set the enable bit of the control register");
  }
  // A drive may take a moment to leave its fault state: give it kRearmSettle before giving up.
  std::uint32_t status = 0;
  const std::int64_t give_up = monotonic_ns() + kRearmSettleNs;
  while (o.ok()) {
    o = check_read("rearm: reading the encoder registers");
    if (!o.ok() || !status_.present) break;
    status = static_cast<std::uint32_t>(
        modbus::decode_registers(status_.type, bus_.registers.high_word_first, std::span<const std::uint16_t>(rbuf_).subspan(status_.offset)));
    if ((status & modbus::kStatusDriveFault) == 0) break;
    if (monotonic_ns() >= give_up) {
      char hex[16];
      std::snprintf(hex, sizeof hex, "0x%X", status);
      o = fail(std::string("rearm: the drive still reports a fault after the fault reset (status ") + hex + ", bit 0 set)", 0);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (!o.ok() && control_word_ != 0) {
    control_word_ = 0;
    (void)write_control(0, "rearm: cannot clear the enable bit again");  // best effort: stay disabled
  }
  reset_velocity();
  return o;
}

// ---------------------------------------------------------------------------------------------
// Real-time path

IoStatus ModbusArm::io_error(int err) noexcept {
  last_errno_ = err;
  need_flush_ = true;  // a late or partial reply may follow: drop it before the next request
  const IoStatus s = modbus::io_status_from_errno(err);
  if (s == IoStatus::kDisconnected) link_broken_ = true;
  return s;
}

IoStatus ModbusArm::read_blocks() noexcept {
  ::_modbus* c = ctx_.get();
  if (need_flush_) {
    (void)modbus_flush(c);
    need_flush_ = false;
  }
  for (const RegisterBlock& b : read_blocks_) {
    std::uint16_t* dst = rbuf_.data() + b.offset;
    const int rc = b.table == arm::RegisterTable::kInput ? modbus_read_input_registers(c, b.address, b.count, dst)
                                                         : modbus_read_registers(c, b.address, b.count, dst);
    if (rc != b.count) return io_error(rc < 0 ? errno : EMBBADDATA);
  }
  return IoStatus::kOk;
}

IoStatus ModbusArm::write_blocks() noexcept {
  ::_modbus* c = ctx_.get();
  if (need_flush_) {
    (void)modbus_flush(c);
    need_flush_ = false;
  }
  for (const RegisterBlock& b : write_blocks_) {
    const int rc = modbus_write_registers(c, b.address, b.count, wbuf_.data() + b.offset);
    if (rc != b.count) return io_error(rc < 0 ? errno : EMBBADDATA);
  }
  return IoStatus::kOk;
}

IoStatus ModbusArm::on_read(JointState& out) noexcept {
  const IoStatus s = read_blocks();
  if (s != IoStatus::kOk) return s;
  const std::int64_t now = monotonic_ns();
  const bool hwf = bus_.registers.high_word_first;
  const std::span<const std::uint16_t> regs(rbuf_);
  const int rc = modbus::register_count(encoders_.type);
  out.n = n_;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const std::int64_t counts = modbus::decode_registers(encoders_.type, hwf, regs.subspan(static_cast<std::size_t>(encoders_.offset + j * rc)));
    out.counts[uj] = counts;
    out.q[uj] = arm::joint_position_from_counts(config_.joints[uj], counts);
  }
  velocity_.update(n_, out.q, now, out.qd);
  out.status = status_.present ? static_cast<std::uint32_t>(modbus::decode_registers(status_.type, hwf, regs.subspan(status_.offset))) : 0;
  out.buttons = buttons_.present
                    ? pressed_buttons(config_.buttons, static_cast<std::uint32_t>(modbus::decode_registers(buttons_.type, hwf, regs.subspan(buttons_.offset))))
                    : 0;
  if ((out.status & modbus::kStatusDriveFault) != 0) return IoStatus::kDeviceFault;
  return IoStatus::kOk;
}

void ModbusArm::encode_currents(const JointCommand& cmd) noexcept {
  const arm::RegisterField& f = bus_.registers.current_command;
  const int rc = modbus::register_count(f.type);
  const double lo = f.type == arm::FieldType::kI16 ? -32768.0 : -2147483648.0;
  const double hi = f.type == arm::FieldType::kI16 ? 32767.0 : 2147483647.0;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double tau = j < cmd.n && std::isfinite(cmd.tau[uj]) ? cmd.tau[uj] : 0.0;
    const double peak = config_.actuators[uj].peak_current;
    double amps = arm::motor_current_for_joint_torque(config_.joints[uj], config_.actuators[uj], tau);
    if (!std::isfinite(amps)) amps = 0;
    if (amps > peak || amps < -peak) {
      amps = std::clamp(amps, -peak, peak);
      ++current_clamps_;
    }
    double counts = std::nearbyint(amps / f.lsb);
    if (counts < lo || counts > hi) {
      counts = std::clamp(counts, lo, hi);
      ++current_clamps_;
    }
    (void)modbus::encode_registers(f.type, bus_.registers.high_word_first, static_cast<std::int64_t>(counts),
                                   std::span(wbuf_).subspan(static_cast<std::size_t>(currents_.offset + j * rc)));
    sent_current_[uj] = counts * f.lsb;
  }
}

IoStatus ModbusArm::on_write(const JointCommand& cmd) noexcept {
  encode_currents(cmd);
  const bool hwf = bus_.registers.high_word_first;
  if (heartbeat_.present) {
    ++heartbeat_count_;
    // Counts up and wraps within the register's type (u16: 0..65535).
    std::uint32_t wrap = 0xFFFF'FFFFu;
    if (heartbeat_.type == arm::FieldType::kU16) wrap = 0xFFFFu;
    if (heartbeat_.type == arm::FieldType::kI16) wrap = 0x7FFFu;
    if (heartbeat_.type == arm::FieldType::kI32) wrap = 0x7FFF'FFFFu;
    (void)modbus::encode_registers(heartbeat_.type, hwf, heartbeat_count_ & wrap, std::span(wbuf_).subspan(heartbeat_.offset));
  }
  if (control_.present) (void)modbus::encode_registers(control_.type, hwf, control_word_, std::span(wbuf_).subspan(control_.offset));
  return write_blocks();
}

}  // namespace lancet::device
