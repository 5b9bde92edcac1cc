#include "device/falcon_arm.hpp"

#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

#include "device/ftdi.hpp"

namespace lancet::device {

namespace {

constexpr std::int64_t kNsPerS = 1'000'000'000;
constexpr std::size_t kMaxFirmwareBytes = 1u << 20;
constexpr double kFoundRunningWindowS = 0.1;  // a running firmware answers a command within this
constexpr double kAfterUploadWindowS = 0.5;   // a freshly started firmware answers within this
constexpr double kEchoTimeoutS = 1.0;         // one chunk's echo (62 bytes at 140 kbaud take 4.4 ms)
constexpr double kLoaderTimeoutS = 0.2;
constexpr int kLoaderAttempts = 5;

std::int64_t now_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * kNsPerS + ts.tv_nsec;
}

std::string hex_bytes(std::span<const std::uint8_t> b) {
  std::string s;
  char x[4];
  for (std::size_t i = 0; i < b.size(); ++i) {
    std::snprintf(x, sizeof x, "%s%02X", i == 0 ? "" : " ", b[i]);
    s += x;
  }
  return s.empty() ? "nothing" : s;
}

std::string motors_not_homed(std::uint8_t homed) {
  std::string s;
  for (int m = 0; m < 3; ++m)
    if ((homed & (1u << m)) == 0) s += (s.empty() ? "" : ", ") + std::to_string(m + 1);
  return s;
}

}  // namespace

FalconArm::FalconArm(const arm::ArmConfig& config, FaultPolicy policy)
    : Device("falcon arm '" + config.name + "'", policy), config_(config), bus_(*config.falcon) {
  namespace fs = std::filesystem;
  fs::path fw(bus_.firmware);
  if (fw.is_relative() && !config.source.empty()) fw = fs::path(config.source).parent_path() / fw;
  firmware_path_ = fw.lexically_normal().string();
  set_timeout(bus_.timeout);
}

Result<std::unique_ptr<FalconArm>> FalconArm::create(const arm::ArmConfig& config, FaultPolicy policy) {
  const std::string where = config.source.empty() ? "falcon arm '" + config.name + "'" : config.source;
  if (!config.falcon)
    return Error{ErrorCode::kInvalid, where + ": the falcon backend needs a [bus.falcon] section"};
  if (config.joint_count() != 3 || config.joints.size() != 3 || config.actuators.size() != 3)
    return Error{ErrorCode::kInvalid, where + ": the Falcon has three motors: the config needs a three-joint model with three [[joints]] and "
                                              "three [[actuators]] (found " + std::to_string(config.joints.size()) + " joints, " +
                                              std::to_string(config.actuators.size()) + " actuators)"};
  if (config.falcon->firmware.empty())
    return Error{ErrorCode::kInvalid, where + ": bus.falcon.firmware: the path of the Falcon's firmware file is required"};
  return std::unique_ptr<FalconArm>(new FalconArm(config, policy));
}

FalconArm::~FalconArm() {
  if (port_ && !port_->lost()) {
    falcon::Command off{};  // no torque, LEDs off
    (void)send(off);
    (void)await_reply(now_ns() + timeout_ns_);
  }
  port_.reset();
}

std::string FalconArm::device_location() const { return port_ ? port_->location() : std::string(); }

void FalconArm::set_timeout(double seconds) noexcept {
  if (seconds > 0 && std::isfinite(seconds)) timeout_ns_ = static_cast<std::int64_t>(std::ceil(seconds * 1e9));
}

std::string FalconArm::error_prefix() const {
  return "Novint Falcon" + (port_ ? " at " + port_->location() : std::string());
}

falcon::Command FalconArm::zero_command() const noexcept {
  falcon::Command c;
  c.leds = leds_;
  c.homing = last_.homed != falcon::kAllHomed;
  return c;
}

// --------------------------------------------------------------------------------------------
// Bringing the Falcon up

Result<void> FalconArm::bring_up() {
  port_.reset();
  ftdi::PortId id;
  id.vid = bus_.vid;
  id.pid = bus_.pid;
  id.index = bus_.index;
  id.what = "Novint Falcon";
  auto opened = ftdi::Port::open(id);
  if (!opened.ok()) return opened.error();
  port_ = std::move(opened).value();
  have_reply_ = have_sample_ = written_since_read_ = false;
  last_ = {};
  homed_seen_ = 0;
  if (auto r = port_->reset(); !r.ok()) return r;
  if (auto r = port_->set_uart_mode(); !r.ok()) return r;
  if (auto r = port_->set_8n1_no_flow_control(); !r.ok()) return r;
  if (auto r = port_->start_streaming(); !r.ok()) return r;
  if (bus_.upload == arm::FirmwareUpload::kWhenNeeded) {
    if (auto r = normal_mode(); !r.ok()) return r;
    auto running = firmware_answers(kFoundRunningWindowS);
    if (!running.ok()) return running.error();
    if (running.value()) {
      ++stats_.found_running;
      return {};
    }
  }
  return upload_firmware();
}

Result<void> FalconArm::normal_mode() {
  if (auto r = port_->set_latency_ms(falcon::kNormalLatencyMs); !r.ok()) return r;
  if (auto r = port_->set_baud(falcon::kNormalBaud); !r.ok()) return r;
  return port_->purge();
}

Result<bool> FalconArm::firmware_answers(double window_s) {
  const std::uint64_t before = stats_.replies;
  auto r = exchange_until(window_s, [&] { return stats_.replies > before; }, "no answer in normal mode");
  if (r.ok()) return true;
  if (r.error().code == ErrorCode::kNotReady) return false;  // the window passed without an answer
  return r.error();
}

Result<void> FalconArm::loader_handshake() {
  // 9600 baud, latency 16 ms, RTS low, DTR pulsed high: the loader listens.
  if (auto r = port_->purge(); !r.ok()) return r;
  if (auto r = port_->set_latency_ms(falcon::kLoaderLatencyMs); !r.ok()) return r;
  if (auto r = port_->set_baud(falcon::kLoaderBaud); !r.ok()) return r;
  if (auto r = port_->set_8n1_no_flow_control(); !r.ok()) return r;
  if (auto r = port_->set_rts(false); !r.ok()) return r;
  if (auto r = port_->set_dtr(false); !r.ok()) return r;
  if (auto r = port_->set_dtr(true); !r.ok()) return r;
  std::array<std::uint8_t, 5> got{};
  std::size_t n = 0;
  bool answered = false;
  for (int attempt = 0; attempt < kLoaderAttempts && !answered; ++attempt) {
    port_->clear_rx();
    if (auto r = port_->write_all(falcon::kLoaderHello, 1.0, "the loader's hello"); !r.ok()) return r;
    n = 0;
    if (!port_->read_exact(std::span(got).first(4), kLoaderTimeoutS, "the loader's answer").ok()) {
      n = port_->rx().size();  // what came, for the message
      std::copy_n(port_->rx().begin(), std::min(n, got.size()), got.begin());
      continue;
    }
    n = 4;
    if (got[0] == 0x00 && port_->read_exact(std::span(got).subspan(4, 1), kLoaderTimeoutS, "the loader's answer").ok()) n = 5;
    answered = falcon::is_loader_hello_reply(std::span(got).first(n));
  }
  if (!answered)
    return Error{ErrorCode::kMismatch, error_prefix() + ": the loader did not answer its handshake (sent " + hex_bytes(falcon::kLoaderHello) +
                                           ", expected " + hex_bytes(falcon::kLoaderHelloReply) + ", got " +
                                           hex_bytes(std::span(got).first(std::min(n, got.size()))) + "); unplug the Falcon's power and USB, plug "
                                           "them back, and try again"};
  // DTR low, 140 kbaud; 'A' is answered with 'A' when the loader is ready for the firmware.
  if (auto r = port_->set_dtr(false); !r.ok()) return r;
  if (auto r = port_->set_baud(falcon::kUploadBaud); !r.ok()) return r;
  port_->clear_rx();
  const std::array<std::uint8_t, 1> ready{falcon::kUploadReady};
  if (auto r = port_->write_all(ready, 1.0, "the upload request"); !r.ok()) return r;
  std::array<std::uint8_t, 1> ack{};
  const bool acked = port_->read_exact(ack, kLoaderTimeoutS, "the loader's upload acknowledgement").ok();
  if (!acked || ack[0] != falcon::kUploadReady)
    return Error{ErrorCode::kMismatch, error_prefix() + ": the loader did not accept the upload (sent 41, got " +
                                           (acked ? hex_bytes(ack) : std::string("nothing")) + ")"};
  return {};
}

Result<void> FalconArm::upload_firmware() {
  std::ifstream f(firmware_path_, std::ios::binary);
  if (!f) return Error{ErrorCode::kNotFound, "bus.falcon.firmware: cannot read " + firmware_path_ + " (the Falcon's firmware file, which we do not ship)"};
  std::vector<std::uint8_t> fw((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  if (fw.empty() || fw.size() > kMaxFirmwareBytes)
    return Error{ErrorCode::kInvalid, "bus.falcon.firmware: " + firmware_path_ + " holds " + std::to_string(fw.size()) +
                                          " bytes (expected a firmware image of 1 byte .. 1 MiB)"};
  if (auto r = loader_handshake(); !r.ok()) return r;
  std::array<std::uint8_t, falcon::kUploadChunk> echo{};
  for (std::size_t at = 0; at < fw.size(); at += falcon::kUploadChunk) {
    const std::size_t n = std::min(falcon::kUploadChunk, fw.size() - at);
    const std::span<const std::uint8_t> chunk(fw.data() + at, n);
    if (auto r = port_->write_all(chunk, kEchoTimeoutS, "the firmware"); !r.ok()) return r;
    if (auto r = port_->read_exact(std::span(echo).first(n), kEchoTimeoutS, "the firmware's echo"); !r.ok())
      return Error{ErrorCode::kMismatch, error_prefix() + ": firmware upload: the echo of bytes " + std::to_string(at) + ".." +
                                             std::to_string(at + n - 1) + " of " + std::to_string(fw.size()) + " stopped: " + r.error().message};
    for (std::size_t i = 0; i < n; ++i) {
      if (echo[i] == chunk[i]) continue;
      char b[160];
      std::snprintf(b, sizeof b, ": firmware upload: echo mismatch at byte %zu of %zu (sent 0x%02X, the loader echoed 0x%02X)", at + i,
                    fw.size(), chunk[i], echo[i]);
      return Error{ErrorCode::kMismatch, error_prefix() + b + "; the upload is not trusted (cable, hub, or not a Falcon firmware file)"};
    }
  }
  ++stats_.uploads;
  if (auto r = normal_mode(); !r.ok()) return r;
  auto answered = firmware_answers(kAfterUploadWindowS);
  if (!answered.ok()) return answered.error();
  if (!answered.value())
    return Error{ErrorCode::kNotReady, error_prefix() + ": no reply after the firmware upload (" + std::to_string(fw.size()) + " bytes from " +
                                           firmware_path_ + " went in and were echoed, but no command was answered within " +
                                           std::to_string(static_cast<int>(kAfterUploadWindowS * 1e3)) + " ms: is it the Falcon's firmware?)"};
  return {};
}

// --------------------------------------------------------------------------------------------
// Lifecycle

Result<void> FalconArm::on_configure() {
  leds_ = falcon::kLedRed;
  torque_on_ = false;
  return bring_up();
}

Result<void> FalconArm::exchange_until(double window_s, const std::function<bool()>& done, const char* what) {
  const std::int64_t deadline = now_ns() + static_cast<std::int64_t>(window_s * 1e9);
  while (!done()) {
    if (now_ns() >= deadline) return Error{ErrorCode::kNotReady, std::string(what)};
    const IoStatus s = send(zero_command());
    if (s == IoStatus::kOk) (void)await_reply(std::min(deadline, now_ns() + std::max<std::int64_t>(timeout_ns_, 20'000'000)));
    if (port_->lost()) return Error{ErrorCode::kSystem, error_prefix() + ": gone (" + port_->detail() + ")"};
  }
  return {};
}

Result<void> FalconArm::on_activate() {
  if (!port_ || port_->lost()) return Error{ErrorCode::kNotReady, "the Falcon is not open (configure first)"};
  leds_ = falcon::kLedRed;
  auto homed = exchange_until(bus_.homing_timeout, [this] { return have_reply_ && last_.homed == falcon::kAllHomed; }, "homing");
  if (!homed.ok()) {
    char b[200];
    std::snprintf(b, sizeof b, ": not homed within %.0f s: motor %s has not passed its home switch. Move the grip slowly all the way "
                               "in and out (`lancetctl calibrate` shows which are done)", bus_.homing_timeout,
                  motors_not_homed(last_.homed).c_str());
    return Error{ErrorCode::kNotReady, error_prefix() + b};
  }
  leds_ = falcon::kLedGreen;
  torque_on_ = true;
  return {};
}

Result<void> FalconArm::on_deactivate() {
  torque_on_ = false;
  leds_ = last_.homed == falcon::kAllHomed ? falcon::kLedBlue : falcon::kLedRed;
  if (!port_ || port_->lost()) return {};
  (void)send(zero_command());
  (void)await_reply(now_ns() + timeout_ns_);
  return {};
}

Result<void> FalconArm::on_reconnect() {
  torque_on_ = false;
  leds_ = falcon::kLedRed;
  auto r = bring_up();
  if (!r.ok()) port_.reset();
  return r;
}

Result<void> FalconArm::on_rearm() {
  if (!port_ || port_->lost()) {
    if (auto r = on_reconnect(); !r.ok()) return r;
  }
  return on_activate();
}

// --------------------------------------------------------------------------------------------
// The exchange

IoStatus FalconArm::send(const falcon::Command& c) noexcept {
  if (!port_) return IoStatus::kDisconnected;
  const auto packet = falcon::encode(c);
  const IoStatus s = port_->submit_write(packet, now_ns() + timeout_ns_);
  if (s == IoStatus::kOk) {
    sent_ = c;
    ++stats_.commands;
  }
  return s;
}

IoStatus FalconArm::await_reply(std::int64_t deadline_ns) noexcept {
  if (!port_) return IoStatus::kDisconnected;
  for (;;) {
    const falcon::Scan scan = falcon::scan_replies(port_->rx());
    port_->take(scan.consumed);
    stats_.malformed += scan.malformed;
    if (scan.newest) {
      stats_.replies += scan.replies;
      if (scan.replies > 1) {
        stats_.stale_replies += scan.replies - 1;
        for (std::size_t i = 1; i < scan.replies; ++i) count_stale_reply();
      }
      last_ = *scan.newest;
      have_reply_ = true;
      reply_ns_ = now_ns();
    }
    // A malformed packet fails this exchange even when a good one followed it.
    if (scan.malformed > 0) return IoStatus::kProtocolError;
    if (scan.newest) return IoStatus::kOk;
    const IoStatus s = port_->wait_for(port_->rx().size() + 1, deadline_ns);
    if (s != IoStatus::kOk) return s;
  }
}

void FalconArm::decode(JointState& out) noexcept {
  // Homing makes a motor's counts absolute: the jump is not motion.
  const std::uint8_t newly_homed = static_cast<std::uint8_t>(last_.homed & ~homed_seen_);
  if (newly_homed != 0) {
    homed_seen_ |= last_.homed;
    have_sample_ = false;
    velocity_.reset();
    restart_plausibility();
  }
  out.n = 3;
  for (std::size_t j = 0; j < 3; ++j) {
    const std::int16_t w = last_.encoder[j];
    raw_[j] = have_sample_ ? raw_[j] + static_cast<std::int16_t>(static_cast<std::uint16_t>(w) - static_cast<std::uint16_t>(last_wire_[j])) : w;
    last_wire_[j] = w;
    out.counts[j] = raw_[j];
    out.q[j] = arm::joint_position_from_counts(config_.joints[j], raw_[j]);
  }
  have_sample_ = true;
  out.t_ns = reply_ns_;
  velocity_.update(3, out.q, out.t_ns, out.qd);
  out.buttons = pressed_buttons(config_.buttons, last_.grip);
  out.status = last_.homed | (sent_.homing ? 0x8u : 0u);
}

IoStatus FalconArm::on_read(JointState& out) noexcept {
  if (!port_ || port_->lost()) {
    note_error(IoStatus::kDisconnected, -1, 0, port_ ? port_->detail() : "the Falcon is not open");
    return IoStatus::kDisconnected;
  }
  if (!written_since_read_) {
    const IoStatus s = send(zero_command());
    if (s != IoStatus::kOk) {
      note_error(s, -1, 0, s == IoStatus::kDisconnected ? "the Falcon is gone (USB: no device)" : "the command could not go out");
      return s;
    }
  }
  written_since_read_ = false;
  const IoStatus s = await_reply(now_ns() + timeout_ns_);
  switch (s) {
    case IoStatus::kOk: decode(out); return IoStatus::kOk;
    case IoStatus::kTimeout: note_error(s, -1, 0, "no reply to the last command within the timeout (a dropped packet)"); break;
    case IoStatus::kProtocolError: note_error(s, -1, 0, "a malformed reply packet (framing or nibble out of range), skipped"); break;
    case IoStatus::kDisconnected: note_error(s, -1, 0, "the Falcon is gone (USB: no device)"); break;
    default: note_error(s, -1, 0, "the exchange failed"); break;
  }
  return s;
}

void FalconArm::on_fault() noexcept {
  torque_on_ = false;
  leds_ = falcon::kLedRed;
}

IoStatus FalconArm::on_write(const JointCommand& cmd) noexcept {
  falcon::Command c = zero_command();
  if (torque_on_) {
    for (std::size_t j = 0; j < 3; ++j) {
      const double tau = static_cast<int>(j) < cmd.n && std::isfinite(cmd.tau[j]) ? cmd.tau[j] : 0.0;
      const double raw = static_cast<double>(config_.joints[j].direction) * bus_.motor_command_per_nm * tau;
      c.motor[j] = static_cast<std::int16_t>(std::clamp(std::nearbyint(raw), -32767.0, 32767.0));
    }
  }
  const IoStatus s = send(c);
  if (s == IoStatus::kOk) {
    written_since_read_ = true;
    return s;
  }
  note_error(s, -1, 0, s == IoStatus::kDisconnected ? "the Falcon is gone (USB: no device)" : "the command could not go out in time");
  return s;
}

}  // namespace lancet::device
