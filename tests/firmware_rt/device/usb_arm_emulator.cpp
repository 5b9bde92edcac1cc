#include "usb_arm_emulator.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <utility>

namespace lancet::device {
namespace {

using arm::ByteOrder;
using arm::FieldType;

// ---------------------------------------------------------------------------------------------
// Field codecs of the emulated firmware (written apart from UsbArm's on purpose)

std::int64_t get_field(const std::uint8_t* p, FieldType t, ByteOrder o) {
  const int size = arm::field_size(t);
  std::uint64_t u = 0;
  for (int i = 0; i < size; ++i) u |= static_cast<std::uint64_t>(p[o == ByteOrder::kLittle ? i : size - 1 - i]) << (8 * i);
  const bool is_signed = t == FieldType::kI8 || t == FieldType::kI16 || t == FieldType::kI32;
  const int bits = 8 * size;
  if (is_signed && (u >> (bits - 1)) != 0) return static_cast<std::int64_t>(u) - (std::int64_t{1} << bits);
  return static_cast<std::int64_t>(u);
}

void put_field(std::uint8_t* p, FieldType t, ByteOrder o, std::int64_t v) {
  const int size = arm::field_size(t);
  const auto u = static_cast<std::uint64_t>(v);  // modulo 2^bits: a counter wraps like hardware
  for (int i = 0; i < size; ++i) p[o == ByteOrder::kLittle ? i : size - 1 - i] = static_cast<std::uint8_t>((u >> (8 * i)) & 0xFF);
}

// A field's value in physical units (scale · raw + bias), f32 included.
double get_value(const std::uint8_t* p, const arm::ReportField& f) {
  if (f.type == FieldType::kF32) {
    const auto bits = static_cast<std::uint32_t>(get_field(p, FieldType::kU32, f.byte_order));
    float v = 0;
    std::memcpy(&v, &bits, sizeof v);
    return f.scale * v + f.bias;
  }
  return f.scale * static_cast<double>(get_field(p, f.type, f.byte_order)) + f.bias;
}

void put_value(std::uint8_t* p, const arm::ReportField& f, double physical) {
  const double raw = (physical - f.bias) / f.scale;
  if (f.type == FieldType::kF32) {
    const auto v = static_cast<float>(raw);
    std::uint32_t bits = 0;
    std::memcpy(&bits, &v, sizeof bits);
    put_field(p, FieldType::kU32, f.byte_order, bits);
    return;
  }
  put_field(p, f.type, f.byte_order, std::llround(raw));
}

std::uint32_t with_bit(std::uint32_t word, const arm::StatusBit& b, bool active) {
  if (!b.mapped()) return word;
  const std::uint32_t m = 1u << b.bit;
  return active != b.active_low ? word | m : word & ~m;
}

lancet::test::UsbdevfsInterface arm_interface(const arm::UsbBusConfig& usb) {
  using lancet::test::UsbEndpoint;
  return {usb.interface_number, "usbhid",  // usbhid binds a freshly enumerated HID device
          {{usb.endpoint_in, UsbEndpoint::Type::kInterrupt}, {usb.endpoint_out, UsbEndpoint::Type::kInterrupt}}};
}

}  // namespace

ArmEmulator::ArmEmulator(const arm::ArmConfig& cfg) : UsbdevfsDevice(arm_interface(*cfg.usb)), cfg_(cfg), usb_(*cfg.usb) {
  auto p = ArmPhysics::create(cfg);
  if (!p.ok()) {
    ADD_FAILURE() << p.error().message;
    return;
  }
  physics_ = std::move(p).value();
}

EmulatorSnapshot ArmEmulator::snapshot() {
  auto lk = lock();
  poll_watchdog();
  EmulatorSnapshot s = snap_;
  const lancet::test::UsbdevfsState usb = state();
  s.claimed = usb.claimed;
  s.driver_bound = usb.driver_bound;
  s.driver_detaches = usb.driver_detaches;
  s.discards = usb.discards;
  return s;
}

lancet::test::UrbReply ArmEmulator::on_out(std::uint8_t, std::span<const std::uint8_t> data) {
  consume_out(data.data(), data.size());
  return lancet::test::UrbReply::done(data.size());
}

lancet::test::UrbReply ArmEmulator::on_in(std::uint8_t, std::span<std::uint8_t> buffer) {
  return lancet::test::UrbReply::done(fill_in(buffer.data(), buffer.size()));
}

// The firmware's keep-alive: once the heartbeat changed while enabled it must keep changing;
// silent for longer than the watchdog time, the arm goes torque-free and latches a fault
// (comm_lost) until a fault reset. Checked on every report, snapshot and clock advance, against
// the test's clock.
void ArmEmulator::poll_watchdog() {
  if (!armed_ || !(watchdog_s_ > 0) || !snap_.enabled) return;
  if (static_cast<double>(clock_ns_ - heartbeat_at_ns_) <= watchdog_s_ * 1e9) return;
  armed_ = false;
  snap_.tripped = true;
  snap_.enabled = false;
  ++snap_.trips;
}

// The firmware's side of an OUT report: setpoints → joint torques → 1 ms of physics.
void ArmEmulator::consume_out(const std::uint8_t* b, std::size_t len) {
  ++snap_.out_reports;
  poll_watchdog();
  if (len < usb_.out_size || (usb_.out_report_id && b[0] != *usb_.out_report_id)) {
    ++snap_.bad_out_reports;
    return;
  }
  const auto field = [&](const std::optional<arm::ReportField>& f) {
    return f ? static_cast<std::uint32_t>(get_field(b + f->offset, f->type, f->byte_order)) : 0u;
  };
  if (usb_.fault_reset && field(usb_.fault_reset) == usb_.fault_reset_value) {
    snap_.tripped = false;
    ++snap_.resets;
  }
  snap_.enable_raw = field(usb_.enable);
  const bool enabled = (!usb_.enable || snap_.enable_raw == usb_.enable_on) && !snap_.tripped;
  if (usb_.heartbeat) {
    const std::uint32_t hb = field(usb_.heartbeat);
    if (hb != snap_.heartbeat || !enabled) {
      heartbeat_at_ns_ = clock_ns_;
      armed_ = enabled && hb != snap_.heartbeat;
    }
    snap_.heartbeat = hb;
  }
  const auto& f = usb_.setpoint;
  JointCommand cmd{};
  cmd.n = physics_->joint_count();
  for (int j = 0; j < cmd.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const std::uint8_t* p = b + f.offset + uj * static_cast<std::size_t>(arm::field_size(f.type));
    const double physical = get_value(p, f);
    snap_.setpoint[uj] = physical;
    snap_.current_counts[uj] = std::llround((physical - f.bias) / f.scale);
    const double amps = usb_.setpoint_kind == arm::SetpointKind::kTorque ? physical / cfg_.actuators[uj].torque_constant : physical;
    const double amps_per_nm = arm::motor_current_for_joint_torque(cfg_.joints[uj], cfg_.actuators[uj], 1.0);
    cmd.tau[uj] = enabled ? amps / amps_per_nm : 0.0;
  }
  snap_.enabled = enabled;
  physics_->step(cmd, 1e-3);
}

// An IN report from the physics' encoders; returns the bytes sent.
std::size_t ArmEmulator::fill_in(std::uint8_t* b, std::size_t len) {
  ++snap_.in_reports;
  poll_watchdog();
  std::fill(b, b + len, std::uint8_t{0});
  const std::size_t n = std::min<std::size_t>(len, usb_.in_size);
  if (usb_.in_report_id) b[0] = corrupt_ == Corruption::kWrongId ? static_cast<std::uint8_t>(*usb_.in_report_id + 1) : *usb_.in_report_id;
  const auto& f = usb_.encoder_counts;
  for (int j = 0; j < physics_->joint_count(); ++j)
    put_value(b + f.offset + static_cast<std::size_t>(j * arm::field_size(f.type)), f, static_cast<double>(physics_->encoder_counts(j)));
  if (usb_.buttons) put_field(b + usb_.buttons->offset, usb_.buttons->type, usb_.buttons->byte_order, buttons_);
  if (usb_.status) {
    // What the test set, with the watchdog's latched fault on top.
    std::uint32_t word = status_;
    if (snap_.tripped) word = with_bit(with_bit(word, usb_.status_bits.fault, true), usb_.status_bits.comm_lost, true);
    put_field(b + usb_.status->offset, usb_.status->type, usb_.status->byte_order, word);
  }
  const Corruption c = corrupt_;
  corrupt_ = Corruption::kNone;
  return c == Corruption::kShort ? n / 2 : n;
}

}  // namespace lancet::device
