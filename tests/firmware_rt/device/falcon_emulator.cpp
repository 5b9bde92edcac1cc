#include "falcon_emulator.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

namespace lancet::test {

namespace {

using Mode = FalconSnapshot::Mode;

constexpr std::uint8_t kIn = 0x81, kOut = 0x02;
constexpr std::uint8_t kChar0 = 'A';  // nibble n travels as 'A' + n

// The FT232BM divisor: wValue bits 0..13 the whole part, bits 14..15 and wIndex bit 0 the code of
// its fraction; 0 and 1 are the special 3 and 2 Mbaud.
double decode_baud(std::uint16_t value, std::uint16_t index) {
  static constexpr double kFraction[8] = {0.0, 0.5, 0.25, 0.125, 0.375, 0.625, 0.75, 0.875};
  const unsigned whole = value & 0x3FFFu;
  const unsigned code = (value >> 14) | ((index & 1u) << 2);
  if (code == 0 && whole == 0) return 3e6;
  if (code == 0 && whole == 1) return 2e6;
  return 3e6 / (whole + kFraction[code]);
}

// 3 × 3 solve of Jᵀ F = τ (Cramer's rule): the grip force that the thigh torques make.
Vec3 solve_transpose(const arm::Jacobian& j, const std::array<double, 3>& tau) {
  // Rows of Jᵀ are the Jacobian's columns.
  const Vec3 a = j.column[0], b = j.column[1], c = j.column[2];
  const double det = dot(a, cross(b, c));
  if (!(std::abs(det) > 1e-15)) return {};
  // Jᵀ F = τ: a·F = τ0, b·F = τ1, c·F = τ2 → F = (τ0 (b×c) + τ1 (c×a) + τ2 (a×b)) / det.
  return (1.0 / det) * (tau[0] * cross(b, c) + tau[1] * cross(c, a) + tau[2] * cross(a, b));
}

}  // namespace

FalconEmulator::FalconEmulator(const arm::ArmConfig& config, FalconEmulatorOptions options)
    : UsbdevfsDevice(UsbdevfsInterface{0, "ftdi_sio", {{kIn, UsbEndpoint::Type::kBulk}, {kOut, UsbEndpoint::Type::kBulk}}}),
      config_(config),
      kin_(arm::Kinematics::cartesian()),
      options_(std::move(options)) {
  auto k = arm::make_kinematics(config_);
  if (!k.ok()) {
    ADD_FAILURE() << k.error().message;
    return;
  }
  kin_ = k.value();
  auto p = device::ArmPhysics::create(config_);
  if (!p.ok()) {
    ADD_FAILURE() << p.error().message;
    return;
  }
  physics_ = std::move(p).value();
  physics_->reset(options_.start_q);
  for (int j = 0; j < 3; ++j) powerup_counts_[static_cast<std::size_t>(j)] = physics_->encoder_counts(j);
  last_q_ = options_.start_q;
  snap_.mode = options_.firmware_running ? Mode::kRunning : Mode::kLoader;
}

FalconEmulator::~FalconEmulator() = default;

// ---------------------------------------------------------------------------------------------
// Test controls

void FalconEmulator::drop_replies(int n) {
  auto lk = lock();
  drop_ = n;
}

void FalconEmulator::corrupt_replies(int n) {
  auto lk = lock();
  corrupt_ = n;
}

void FalconEmulator::set_grip(std::uint8_t buttons) {
  auto lk = lock();
  grip_ = buttons & 0x0F;
}

void FalconEmulator::power_cycle() {
  auto lk = lock();
  snap_.mode = Mode::kLoader;
  snap_.homed = 0;
  snap_.homing_mode = false;
  snap_.uploaded = 0;
  ++snap_.power_cycles;
  // Without power the motors give nothing.
  snap_.motor = {};
  snap_.tau = {};
  snap_.felt = snap_.meant = {};
  to_host_.clear();
  command_bytes_.clear();
  hello_bytes_.clear();
  dtr_rose_ = false;
  snap_.dtr = snap_.rts = false;
  for (int j = 0; j < 3; ++j) powerup_counts_[static_cast<std::size_t>(j)] = physics_->encoder_counts(j);
}

void FalconEmulator::with_physics(const std::function<void(device::ArmPhysics&)>& f) {
  auto lk = lock();
  f(*physics_);
}

FalconSnapshot FalconEmulator::snapshot() const {
  auto lk = lock();
  FalconSnapshot s = snap_;
  s.tool = physics_->tool_position();
  s.drops_left = drop_;
  s.corruptions_left = corrupt_;
  return s;
}

// ---------------------------------------------------------------------------------------------
// The chip

bool FalconEmulator::baud_near(double want) const { return std::abs(snap_.baud - want) <= 0.03 * want; }

UrbReply FalconEmulator::on_control(const ControlSetup& s, std::span<std::uint8_t>) {
  snap_.requests.push_back({s.request_type, s.request, s.value, s.index});
  const auto unexpected = [&] {
    ++snap_.unexpected_requests;
    return UrbReply::stall();
  };
  if (s.request_type != 0x40) return unexpected();
  switch (s.request) {
    case 0x00:  // reset: the port, the to-host buffer, the to-device buffer
      if (s.value == 0) {
        to_host_.clear();
        command_bytes_.clear();
      } else if (s.value == 1) {
        to_host_.clear();
      } else if (s.value == 2) {
        command_bytes_.clear();
        hello_bytes_.clear();
      } else {
        return unexpected();
      }
      break;
    case 0x01: {  // modem control: mask in the high byte
      const unsigned mask = s.value >> 8, level = s.value & 0xFFu;
      if ((mask & 1u) != 0) {
        const bool dtr = (level & 1u) != 0;
        // DTR rising resets the microcontroller into its loader (running firmware and all).
        if (dtr && !snap_.dtr && baud_near(9600)) {
          snap_.mode = Mode::kHello;
          hello_bytes_.clear();
        }
        snap_.dtr = dtr;
      }
      if ((mask & 2u) != 0) snap_.rts = (level & 2u) != 0;
      break;
    }
    case 0x02: snap_.flow_none = (s.index >> 8) == 0; break;
    case 0x03:
      snap_.baud = decode_baud(s.value, s.index);
      if (snap_.mode == Mode::kUploading && baud_near(1.5e6) && snap_.uploaded == options_.firmware.size()) {
        ++snap_.uploads_completed;
        if (options_.start_after_upload) snap_.mode = Mode::kRunning;
      }
      break;
    case 0x04: snap_.eight_n_one = s.value == 8; break;
    case 0x09:
      if (s.value < 1 || s.value > 255) return unexpected();
      snap_.latency_ms = s.value;
      break;
    case 0x0B:
      if (s.value != 0) return unexpected();  // a Falcon runs its UART, never a bit-bang mode
      break;
    default: return unexpected();
  }
  return UrbReply::done(0);
}

UrbReply FalconEmulator::on_out(std::uint8_t endpoint, std::span<const std::uint8_t> data) {
  if (endpoint != kOut) return UrbReply::stall();
  switch (snap_.mode) {
    case Mode::kLoader: snap_.ignored_bytes += data.size(); break;
    case Mode::kHello:
    case Mode::kUploadReady:
      for (const std::uint8_t b : data) loader_byte(b);
      break;
    case Mode::kUploading: firmware_bytes(data); break;
    case Mode::kRunning:
      if (!baud_near(1.5e6)) {
        snap_.ignored_bytes += data.size();
        break;
      }
      for (const std::uint8_t b : data) {
        if (command_bytes_.empty() && b != '<') {
          ++snap_.bad_commands;
          continue;
        }
        command_bytes_.push_back(b);
        if (command_bytes_.size() == 16) {
          command(command_bytes_.data());
          command_bytes_.clear();
        }
      }
      break;
  }
  complete_pending_in();
  return UrbReply::done(data.size());
}

UrbReply FalconEmulator::on_in(std::uint8_t endpoint, std::span<std::uint8_t> buffer) {
  if (endpoint != kIn || buffer.size() < 3) return UrbReply::stall();
  if (to_host_.empty()) return UrbReply::nothing_yet();
  buffer[0] = 0x31;  // modem status: CTS, DSR; line status: THRE, TEMT
  buffer[1] = 0x60;
  const std::size_t n = std::min({to_host_.size(), buffer.size() - 2, std::size_t{62}});
  std::copy_n(to_host_.begin(), n, buffer.begin() + 2);
  to_host_.erase(to_host_.begin(), to_host_.begin() + static_cast<std::ptrdiff_t>(n));
  return UrbReply::done(n + 2);
}

void FalconEmulator::queue(std::span<const std::uint8_t> bytes) { to_host_.insert(to_host_.end(), bytes.begin(), bytes.end()); }

// ---------------------------------------------------------------------------------------------
// The loader

void FalconEmulator::loader_byte(std::uint8_t b) {
  if (snap_.mode == Mode::kHello) {
    if (!baud_near(9600) || !snap_.eight_n_one || !snap_.flow_none) {
      ++snap_.ignored_bytes;
      return;
    }
    hello_bytes_.push_back(b);
    const std::size_t n = hello_bytes_.size();
    if (n >= 3 && hello_bytes_[n - 3] == 0x0A && hello_bytes_[n - 2] == 0x43 && hello_bytes_[n - 1] == 0x0D) {
      const std::uint8_t reply[] = {0x00, 0x0A, 0x44, 0x2C, 0x0D};
      queue(reply);
      snap_.mode = Mode::kUploadReady;
    }
    return;
  }
  // kUploadReady: 'A' at 140 kbaud with DTR low starts the upload.
  if (b == 'A' && !snap_.dtr && baud_near(140'000)) {
    const std::uint8_t ack[] = {'A'};
    queue(ack);
    snap_.mode = Mode::kUploading;
    snap_.uploaded = 0;
  } else {
    ++snap_.ignored_bytes;
  }
}

void FalconEmulator::firmware_bytes(std::span<const std::uint8_t> data) {
  if (!baud_near(140'000)) {
    snap_.ignored_bytes += data.size();
    return;
  }
  for (const std::uint8_t b : data) {
    if (snap_.uploaded >= options_.firmware.size()) {
      ++snap_.ignored_bytes;
      continue;
    }
    std::uint8_t echo = b;
    if (options_.corrupt_echo_at && *options_.corrupt_echo_at == snap_.uploaded) echo = static_cast<std::uint8_t>(b ^ 0x5A);
    queue(std::span<const std::uint8_t>(&echo, 1));
    ++snap_.uploaded;
  }
}

// ---------------------------------------------------------------------------------------------
// The firmware and the mechanism

std::int16_t FalconEmulator::wire_counts(int j) {
  const auto uj = static_cast<std::size_t>(j);
  const std::int64_t absolute = physics_->encoder_counts(j);
  const std::int64_t c = (snap_.homed & (1u << j)) != 0 ? absolute : absolute - powerup_counts_[uj];
  return static_cast<std::int16_t>(static_cast<std::uint16_t>(c & 0xFFFF));
}

Vec3 FalconEmulator::force_at(std::span<const double> q, const std::array<double, 3>& tau) const {
  return solve_transpose(kin_.jacobian(q), tau);
}

void FalconEmulator::command(const std::uint8_t* p) {
  bool ok = p[0] == '<' && p[15] == '>';
  for (int i = 1; i <= 14 && ok; ++i) ok = p[i] >= kChar0 && p[i] <= kChar0 + 15;
  if (!ok) {
    ++snap_.bad_commands;
    return;
  }
  ++snap_.commands;
  const auto nib = [&](int i) { return static_cast<unsigned>(p[i] - kChar0); };
  std::array<double, 3> tau{};
  device::JointCommand cmd{};
  cmd.n = 3;
  for (int m = 0; m < 3; ++m) {
    const auto um = static_cast<std::size_t>(m);
    const unsigned u = nib(1 + 4 * m) | nib(2 + 4 * m) << 4 | nib(3 + 4 * m) << 8 | nib(4 + 4 * m) << 12;
    snap_.motor[um] = static_cast<std::int16_t>(static_cast<std::uint16_t>(u));
    tau[um] = snap_.motor[um] / (config_.joints[um].direction * config_.falcon->motor_command_per_nm);
    cmd.tau[um] = tau[um];
  }
  const unsigned bits = nib(13);
  snap_.homing_mode = (bits & 1u) != 0;
  snap_.leds = static_cast<std::uint8_t>(bits & 0xEu);
  snap_.tau = tau;
  snap_.meant = force_at(q_read_, tau);
  physics_->step(cmd, 1e-3);
  snap_.felt = physics_->rendered_force();
  // Home switches: a thigh passing its switch while homing mode is on.
  for (int j = 0; j < 3; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double q = physics_->q(j), home = options_.home_angles[uj];
    if (snap_.homing_mode && (snap_.homed & (1u << j)) == 0 && (q - home) * (last_q_[uj] - home) <= 0) snap_.homed |= static_cast<std::uint8_t>(1u << j);
    last_q_[uj] = q;
  }
  if (drop_ > 0) {
    --drop_;
    return;
  }
  std::uint8_t r[16];
  r[0] = '<';
  for (int m = 0; m < 3; ++m) {
    const auto w = static_cast<std::uint16_t>(wire_counts(m));
    for (int k = 0; k < 4; ++k) r[1 + 4 * m + k] = static_cast<std::uint8_t>(kChar0 + ((w >> (4 * k)) & 0xF));
    q_read_[static_cast<std::size_t>(m)] = arm::joint_position_from_counts(config_.joints[static_cast<std::size_t>(m)], physics_->encoder_counts(m));
  }
  r[13] = static_cast<std::uint8_t>(kChar0 + ((snap_.homed << 4) | grip_));
  r[14] = kChar0;
  r[15] = '>';
  if (corrupt_ > 0) {
    --corrupt_;
    r[6] = '~';
  }
  queue(r);
  ++snap_.replies;
}

}  // namespace lancet::test
