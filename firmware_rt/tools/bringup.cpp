#include "tools/bringup.hpp"

#include "text/text.hpp"

#include <libusb.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <optional>
#include <string_view>
#include <thread>
#include <vector>

#include "app/device_factory.hpp"
#include "arm/arm_config.hpp"
#include "arm/kinematics.hpp"
#include "app/supervisor.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "rt/watchdog.hpp"

namespace lancet::tools {

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct OpenArm {
  arm::ArmConfig config;
  std::optional<arm::Kinematics> kin;
  app::MadeDevice dev;
  bool calibrated = false;
};

// Loads the config (and its calibration file), builds kinematics and the device, configures it.
// Prints what went wrong and returns nothing on failure; `code` then holds the exit code.
std::optional<OpenArm> open_arm(const std::string& path, std::FILE* out, int& code) {
  auto cfg = arm::load_arm_config(path);
  if (!cfg.ok()) {
    std::fprintf(out, "%s", cfg.error().message.c_str());
    if (!cfg.error().message.empty() && cfg.error().message.back() != '\n') std::fputc('\n', out);
    code = 2;
    return std::nullopt;
  }
  OpenArm a;
  a.config = std::move(cfg).value();
  auto cal = arm::apply_calibration_file(a.config, arm::calibration_path(path));
  if (!cal.ok()) {
    std::fprintf(out, "%s\n", cal.error().message.c_str());
    code = 2;
    return std::nullopt;
  }
  a.calibrated = cal.value();
  auto kin = arm::make_kinematics(a.config);
  if (!kin.ok()) {
    std::fprintf(out, "%s\n", kin.error().message.c_str());
    code = 2;
    return std::nullopt;
  }
  a.kin = kin.value();
  auto dev = app::make_device(a.config);
  if (!dev.ok()) {
    std::fprintf(out, "%s\n", dev.error().message.c_str());
    code = 2;
    return std::nullopt;
  }
  a.dev = std::move(dev).value();
  const Result<void> o = a.dev.device->configure();
  if (!o.ok()) {
    std::fprintf(out, "%s: %s\n", a.dev.device->name().c_str(), o.error().message.c_str());
    code = 1;
    return std::nullopt;
  }
  return a;
}

bool is_revolute(const arm::ArmConfig& c, int j) { return c.joints[static_cast<std::size_t>(j)].type == arm::JointType::kRevolute; }
double shown(const arm::ArmConfig& c, int j, double q) { return is_revolute(c, j) ? q * 180.0 / std::numbers::pi : q * 1e3; }
const char* unit(const arm::ArmConfig& c, int j) { return is_revolute(c, j) ? "deg" : "mm"; }

void print_state(const OpenArm& a, const device::JointState& s, std::FILE* out) {
  for (int j = 0; j < s.n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    std::fprintf(out, "  joint %d %-10s counts %12lld  q %10.4f %s  qd %9.4f %s/s\n", j, a.config.joints[uj].name.c_str(),
                 static_cast<long long>(s.counts[uj]), shown(a.config, j, s.q[uj]), unit(a.config, j), shown(a.config, j, s.qd[uj]),
                 unit(a.config, j));
  }
  const Vec3 p = a.kin->position(std::span<const double>(s.q.data(), static_cast<std::size_t>(s.n)));
  std::fprintf(out, "  tool %.2f %.2f %.2f mm (device frame)  buttons 0x%x  status 0x%x\n", p.x * 1e3, p.y * 1e3, p.z * 1e3, s.buttons,
               s.status);
}

/// USB devices lancetctl recognises, and the shipped config that drives each.
struct KnownUsbDevice {
  std::uint16_t vid, pid;
  const char* what;
};
constexpr KnownUsbDevice kKnownUsb[] = {
    {0x0403, 0xCB48, "Novint Falcon: hw_configs/novint_falcon.toml (backend falcon; set its firmware file)"},
    {0x0403, 0x6001, "FTDI FT232 serial adapter (a Falcon whose EEPROM was rewritten shows as this: set pid = 0x6001 in [bus.falcon])"},
    {0x1209, 0x0001, "Touch-class USB arm: hw_configs/usb_arm.toml (backend usb)"},
};

const char* known_usb(std::uint16_t vid, std::uint16_t pid) {
  for (const KnownUsbDevice& k : kKnownUsb)
    if (k.vid == vid && k.pid == pid) return k.what;
  return nullptr;
}

/// lancetctl calibrate on a Falcon: its encoders are made absolute by home switches, not by
/// offsets; this runs the homing and shows which motors are done.
int run_falcon_homing(OpenArm& a, std::FILE* out) {
  device::Device& dev = *a.dev.device;
  const double limit = a.config.falcon->homing_timeout;
  std::fprintf(out, "homing: move the grip slowly all the way in and out until each motor has passed its home switch "
                    "(the LED turns from red to blue; at most %.0f s)\n", limit);
  std::fflush(out);
  const auto start = Clock::now();
  std::uint32_t shown_bits = 0xFFFF;
  device::JointState s{};
  while (std::chrono::duration<double>(Clock::now() - start).count() < limit) {
    if (dev.read(s) != device::IoStatus::kOk) {
      std::fprintf(out, "homing: read failed: %s\n", dev.last_error().c_str());
      return 1;
    }
    const std::uint32_t homed = s.status & 0x7u;
    if (homed != shown_bits) {
      std::fprintf(out, "  homed: motor 1 %s, motor 2 %s, motor 3 %s\n", (homed & 1u) ? "yes" : "no", (homed & 2u) ? "yes" : "no",
                   (homed & 4u) ? "yes" : "no");
      std::fflush(out);
      shown_bits = homed;
    }
    if (homed == 0x7u) {
      const Vec3 p = a.kin->position(std::span<const double>(s.q.data(), 3));
      std::fprintf(out, "homed: the encoders are absolute now (the home switches set them); tool at %.2f %.2f %.2f mm. "
                        "Nothing to write: a Falcon keeps no offsets. Homing is lost when it is unplugged.\n",
                   p.x * 1e3, p.y * 1e3, p.z * 1e3);
      return 0;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  std::fprintf(out, "homing: not done within %.0f s\n", limit);
  return 1;
}

}  // namespace

int run_list(std::FILE* out) {
  // USB: everything libusb sees, with the strings when the device lets us read them.
  std::fprintf(out, "USB devices:\n");
  libusb_context* ctx = nullptr;
  if (libusb_init(&ctx) != 0) {
    std::fprintf(out, "  (libusb could not start: no USB support here)\n");
  } else {
    libusb_device** list = nullptr;
    const ssize_t n = libusb_get_device_list(ctx, &list);
    if (n <= 0) std::fprintf(out, "  none (no USB bus on this machine, or no permission to read /dev/bus/usb)\n");
    for (ssize_t i = 0; i < n; ++i) {
      libusb_device_descriptor d{};
      if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
      const char* known = known_usb(d.idVendor, d.idProduct);
      std::fprintf(out, "  %04x:%04x  bus %03u address %03u  class 0x%02x%s%s\n", d.idVendor, d.idProduct, libusb_get_bus_number(list[i]),
                   libusb_get_device_address(list[i]), d.bDeviceClass, known != nullptr ? "  " : "", known != nullptr ? known : "");
    }
    if (list != nullptr) libusb_free_device_list(list, 1);
    libusb_exit(ctx);
  }
  // CAN: network interfaces of type ARPHRD_CAN (280).
  std::fprintf(out, "CAN interfaces:\n");
  int can = 0;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/sys/class/net", ec)) {
    std::ifstream type(e.path() / "type");
    int t = 0;
    if (type >> t && t == 280) {
      std::ifstream state(e.path() / "operstate");
      std::string st;
      state >> st;
      std::fprintf(out, "  %s  (%s)\n", e.path().filename().c_str(), st.c_str());
      ++can;
    }
  }
  if (can == 0) std::fprintf(out, "  none (no CAN hardware, or the kernel has no CAN support)\n");
  // Serial ports a Modbus RTU arm could be on.
  std::fprintf(out, "Serial ports (Modbus RTU):\n");
  int serial = 0;
  for (const auto& e : fs::directory_iterator("/dev", ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("ttyUSB", 0) == 0 || name.rfind("ttyACM", 0) == 0 || name.rfind("ttyAMA", 0) == 0) {
      std::fprintf(out, "  %s\n", e.path().c_str());
      ++serial;
    }
  }
  if (serial == 0) std::fprintf(out, "  none (no USB serial adapters plugged in)\n");
  return 0;
}

namespace {
const char* kinematics_label(arm::KinematicModel m) {
  switch (m) {
    case arm::KinematicModel::kPhantom: return "PHANToM";
    case arm::KinematicModel::kDh: return "DH";
    case arm::KinematicModel::kCartesian: return "Cartesian";
    case arm::KinematicModel::kDelta: return "delta";
  }
  return "unknown";
}
}  // namespace

int run_probe(const std::string& path, std::FILE* out) {
  int code = 0;
  auto a = open_arm(path, out, code);
  if (!a) return code;
  device::Device& dev = *a->dev.device;
  std::fprintf(out, "arm '%s' (%s): %s, %d joints, %s kinematics%s\n", a->config.name.c_str(), path.c_str(), dev.name().c_str(),
               dev.joint_count(), kinematics_label(a->config.kinematics.model),
               a->config.falcon ? "" : a->calibrated ? ", calibrated" : ", not calibrated (run lancetctl calibrate)");
  device::JointState s{};
  const device::IoStatus st = dev.read(s);
  if (st != device::IoStatus::kOk) {
    const device::FaultDetail& why = dev.last_error();
    std::fprintf(out, "read failed: %s%s%s\n", device::to_string(st), why.status != device::IoStatus::kOk ? ": " : "",
                 why.status != device::IoStatus::kOk ? why.c_str() : "");
    return 1;
  }
  print_state(*a, s, out);
  if (a->config.falcon) {
    std::fprintf(out, (s.status & 0x7u) == 0x7u ? "  homed: the counts are absolute\n"
                                                : "  not homed (status bits 0..2): the counts are relative to where it powered up and the "
                                                  "tool point means nothing yet; run lancetctl calibrate to home it\n");
  }
  std::fprintf(out, "read took %.0f us\n", static_cast<double>(dev.counters().last_io_ns) / 1e3);
  return 0;
}

int run_monitor(const std::string& path, double duration_s, double rate_hz, std::FILE* out) {
  if (!(rate_hz > 0) || !(duration_s >= 0)) {
    std::fprintf(out, "monitor: --rate must be > 0 and --duration >= 0\n");
    return 2;
  }
  int code = 0;
  auto a = open_arm(path, out, code);
  if (!a) return code;
  device::Device& dev = *a->dev.device;
  const auto start = Clock::now();
  const auto period = std::chrono::duration<double>(1.0 / rate_hz);
  auto next = start;
  device::JointState s{};
  int failures = 0;
  while (duration_s == 0 || std::chrono::duration<double>(Clock::now() - start).count() < duration_s) {
    const device::IoStatus st = dev.read(s);
    const double t = std::chrono::duration<double>(Clock::now() - start).count();
    if (st != device::IoStatus::kOk) {
      ++failures;
      const device::FaultDetail& why = dev.last_error();
      std::fprintf(out, "%8.3f s  read: %s%s%s\n", t, device::to_string(st), why.status != device::IoStatus::kOk ? ": " : "",
                   why.status != device::IoStatus::kOk ? why.c_str() : "");
    } else {
      const Vec3 p = a->kin->position(std::span<const double>(s.q.data(), static_cast<std::size_t>(s.n)));
      std::fprintf(out, "%8.3f s  q", t);
      for (int j = 0; j < s.n; ++j) std::fprintf(out, " %9.3f", shown(a->config, j, s.q[static_cast<std::size_t>(j)]));
      const auto& c = dev.counters();
      std::fprintf(out, "  tool %7.2f %7.2f %7.2f mm  buttons 0x%x  bus ok %llu timeouts %llu errors %llu  io %.0f us\n", p.x * 1e3,
                   p.y * 1e3, p.z * 1e3, s.buttons, static_cast<unsigned long long>(c.ok), static_cast<unsigned long long>(c.timeouts),
                   static_cast<unsigned long long>(c.crc_errors + c.protocol_errors + c.disconnects),
                   static_cast<double>(c.last_io_ns) / 1e3);
    }
    std::fflush(out);
    next += std::chrono::duration_cast<Clock::duration>(period);
    std::this_thread::sleep_until(next);
  }
  return failures == 0 ? 0 : 1;
}

namespace {

/// The newest valid RtStatus of a running lancet-rt, trying for up to `wait_s`. Empty (and `why`
/// set) when there is none or what is there fails the checks.
std::optional<RtStatus> read_rt_status(const SharedState& shared, double wait_s, std::string& why) {
  const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(wait_s));
  RtStatus st{};
  for (;;) {
    const ReadStatus r = shared.rt_status.try_read(st);
    if (r == ReadStatus::kOk) {
      if (const char* bad = wire::check(st)) {
        why = std::string("its status is corrupt (") + bad + ")";
      } else {
        return st;
      }
    } else {
      why = r == ReadStatus::kEmpty ? "it has not published a status yet" : "its status is being rewritten too fast to read";
    }
    if (Clock::now() >= until) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

}  // namespace

namespace {
// One status as a JSON object on one line (lancetctl monitor --rt --json): what a test rig or a
// soak reads; every text was checked (wire::check) and is printed escaped.
// A hand's fields, the same keys at the top level (the right hand's, as before there were two)
// and in each entry of "hands".
std::string hand_status_json(const HandStatus& st) {
  const auto num = [](double v) { return std::isfinite(v) ? text::format("%.9g", v) : std::string("null"); };
  const auto u = [](std::uint64_t v) { return std::to_string(v); };
  std::string j = "\"force_n\": [" + num(st.force.x) + ", " + num(st.force.y) + ", " + num(st.force.z) + "], \"force_scale\": " + num(st.force_scale);
  j += ", \"contact\": " + std::string(st.contact ? "true" : "false") + ", \"tool_mm\": [" + num(st.tool.x * 1e3) + ", " + num(st.tool.y * 1e3) + ", " + num(st.tool.z * 1e3) + "]";
  j += ", \"tool\": " + text::json_string(tool_name(st.mode)) + ", \"patch_version\": " + u(st.patch_version);
  j += ", \"clamped_ticks\": " + u(st.clamped_ticks);
  j += ", \"has_arm\": " + std::string(st.has_arm ? "true" : "false");
  j += ", \"device_state\": " + text::json_string(device::to_string(st.device_state));
  j += ", \"fault_cause\": " + text::json_string(st.device_state == device::Lifecycle::kFault
                                                 ? device::to_string(st.device_fault_cause)
                                                 : "");
  j += ", \"fault_text\": " + text::json_string(st.fault_text) + ", \"link_lost\": " + std::string(st.link_lost ? "true" : "false");
  j += ", \"rearm_failures\": " + u(st.rearm_failures) + ", \"rearm_pending\": " + std::string(st.rearm_pending ? "true" : "false");
  j += ", \"device_errors\": " + u(st.device_errors) + ", \"bus_glitches\": " + u(st.bus.glitches) +
       ", \"bus_timeouts\": " + u(st.bus.timeouts) + ", \"bus_protocol_errors\": " + u(st.bus.protocol_errors) +
       ", \"bus_disconnects\": " + u(st.bus.disconnects) + ", \"bus_device_faults\": " + u(st.bus.device_faults) +
       ", \"bus_reconnects\": " + u(st.bus.reconnects);
  return j;
}

// One status as a JSON object on one line (lancetctl monitor --rt --json): what a test rig or a
// soak reads; every text was checked (wire::check) and is printed escaped. The hand's keys at the
// top level are the right hand's; "hands" holds each hand's (right first).
void print_status_json(std::FILE* out, double t, int pid, const RtStatus& st) {
  const auto num = [](double v) { return std::isfinite(v) ? text::format("%.9g", v) : std::string("null"); };
  const auto u = [](std::uint64_t v) { return std::to_string(v); };
  const SegmentHealth& h = st.health;
  std::string j = "{\"t_s\": " + text::format("%.3f", t) + ", \"pid\": " + std::to_string(pid) + ", \"alive\": true, \"tick\": " + u(st.tick);
  j += ", \"t_ns\": " + std::to_string(st.t_ns);
  j += ", " + hand_status_json(st.hand[0]);
  j += ", \"viz_alive\": " + std::string(st.viz_alive ? "true" : "false");
  j += ", \"rearms\": " + u(st.rearms) + ", \"operator_requests\": " + u(st.operator_requests);
  j += ", \"watchdog_tripped\": " + std::string(st.watchdog_tripped ? "true" : "false");
  j += ", \"missed\": " + u(st.missed) + ", \"wake_p99_us\": " + num(static_cast<double>(st.wake_p99_ns) / 1e3);
  j += ", \"samples_pushed\": " + u(st.samples_pushed) + ", \"samples_dropped\": " + u(st.samples_dropped);
  j += ", \"segment\": {\"ring_resets\": " + u(h.ring_resets) + ", \"commands_rejected\": " + u(h.commands_rejected) +
       ", \"patches_rejected\": " + u(h.patches_rejected) + ", \"patches_unreadable\": " + u(h.patches_unreadable) +
       ", \"targets_rejected\": " + u(h.targets_rejected) + ", \"sample_ring_resets\": " + u(h.sample_ring_resets) + "}";
  j += ", \"hand_count\": " + u(st.hands) + ", \"hands\": [";
  for (std::uint32_t k = 0; k < st.hands && k < kHandCount; ++k) {
    j += std::string(k == 0 ? "" : ", ") + "{\"hand\": " + text::json_string(hand_name(static_cast<Hand>(k))) + ", " +
         hand_status_json(st.hand[k]) + "}";
  }
  j += "]}";
  std::fprintf(out, "%s\n", j.c_str());
}

/// Bits of OperatorRequest::hands for `which` (right, left, both) on a loop that drives `hands`;
/// 0 when it names a hand the loop does not drive.
std::uint8_t hand_mask(const std::string& which, std::uint32_t hands) {
  const std::uint8_t driven = static_cast<std::uint8_t>((1u << std::min<std::uint32_t>(hands, kHandCount)) - 1);
  if (which == "both") return driven;
  Hand h{};
  if (!hand_from_name(which, h)) return 0;
  const auto bit = static_cast<std::uint8_t>(1u << hand_index(h));
  return (bit & driven) != 0 ? bit : 0;
}
}  // namespace

int run_monitor_rt(const std::string& shm, double duration_s, double rate_hz, std::FILE* out, bool json) {
  if (!(rate_hz > 0) || !(duration_s >= 0)) {
    std::fprintf(out, "monitor: --rate must be > 0 and --duration >= 0\n");
    return 2;
  }
  auto ch = SharedChannel::open(shm);
  if (!ch) {
    std::fprintf(out, "monitor: %s (is lancet-rt running?)\n", ch.error().message.c_str());
    return 1;
  }
  const SharedState& shared = ch.value().state();
  const auto start = Clock::now();
  auto next = start;
  std::uint64_t rejected = 0;
  while (duration_s == 0 || std::chrono::duration<double>(Clock::now() - start).count() < duration_s) {
    const double t = std::chrono::duration<double>(Clock::now() - start).count();
    RtStatus st{};
    const ReadStatus r = shared.rt_status.try_read(st);
    const std::int64_t now_ns = monotonic_ns();
    if (shared.rt_heartbeat.count() > 0 && !shared.rt_heartbeat.fresh(now_ns, 200'000'000)) {
      // A status that stopped changing says nothing about the arm now: say that instead.
      const std::int64_t last = shared.rt_heartbeat.last_ns();
      if (last == 0 || !ch.value().segment().creator_alive()) {
        if (json) {
          std::fprintf(out, "{\"t_s\": %.3f, \"pid\": %d, \"alive\": false, \"stopped\": true}\n", t, ch.value().segment().creator_pid());
        } else {
          std::fprintf(out, "%8.3f s  lancet-rt has stopped (pid %d)\n", t, ch.value().segment().creator_pid());
        }
        std::fflush(out);
        return 1;
      }
      if (json) {
        std::fprintf(out, "{\"t_s\": %.3f, \"pid\": %d, \"alive\": false, \"heartbeat_age_ms\": %.1f}\n", t,
                     ch.value().segment().creator_pid(), static_cast<double>(now_ns - last) / 1e6);
      } else {
        std::fprintf(out, "%8.3f s  lancet-rt is NOT TICKING: last heartbeat %.0f ms ago; its last status is not the arm's state\n", t,
                     static_cast<double>(now_ns - last) / 1e6);
      }
    } else if (r == ReadStatus::kOk) {
      // What lancet-rt wrote is checked before any of it is printed.
      if (const char* bad = wire::check(st)) {
        ++rejected;
        if (json) {
          std::fprintf(out, "{\"t_s\": %.3f, \"rejected\": %s, \"rejected_count\": %llu}\n", t, text::json_string(bad).c_str(),
                       static_cast<unsigned long long>(rejected));
        } else {
          std::fprintf(out, "%8.3f s  status rejected (%s); %llu so far\n", t, bad, static_cast<unsigned long long>(rejected));
        }
      } else if (json) {
        print_status_json(out, t, ch.value().segment().creator_pid(), st);
      } else {
        // One line for the loop, then one for each hand.
        std::fprintf(out, "%8.3f s  tick %llu  viz %s  wake p99 %.0f us%s\n", t, static_cast<unsigned long long>(st.tick),
                     st.viz_alive ? "alive" : "absent", static_cast<double>(st.wake_p99_ns) / 1e3,
                     st.watchdog_tripped ? "  WATCHDOG TRIPPED" : "");
        for (std::uint32_t k = 0; k < st.hands && k < kHandCount; ++k) {
          const HandStatus& hs = st.hand[k];
          std::fprintf(out, "%8.3f s  %-6s tool %7.2f %7.2f %7.2f mm  force %6.2f %6.2f %6.2f N (x%.2f)%s  %s  arm %s  errors %llu\n", t,
                       (std::string(hand_name(static_cast<Hand>(k))) + ":").c_str(), hs.tool.x * 1e3, hs.tool.y * 1e3, hs.tool.z * 1e3,
                       hs.force.x, hs.force.y, hs.force.z, hs.force_scale, hs.contact ? " contact" : "", tool_name(hs.mode),
                       app::describe_arm(hs).c_str(), static_cast<unsigned long long>(hs.device_errors));
        }
      }
      std::fflush(out);
    }
    next += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / rate_hz));
    std::this_thread::sleep_until(next);
  }
  return 0;
}

int run_rearm_rt(const std::string& shm, bool confirmed, double timeout_s, std::FILE* in, std::FILE* out, const std::string& which) {
  if (!(timeout_s > 0)) {
    std::fprintf(out, "rearm: --timeout must be > 0\n");
    return 2;
  }
  auto ch = SharedChannel::open(shm);
  if (!ch) {
    std::fprintf(out, "rearm: %s (is lancet-rt running?)\n", ch.error().message.c_str());
    return 1;
  }
  SharedState& shared = ch.value().state();
  std::string why;
  auto st = read_rt_status(shared, 1.0, why);
  if (!st) {
    std::fprintf(out, "rearm: lancet-rt on %s: %s\n", shm.c_str(), why.c_str());
    return 1;
  }
  const std::uint8_t mask = hand_mask(which, st->hands);
  if (mask == 0) {
    std::fprintf(out, "rearm: --hand %s: lancet-rt on %s drives %u hand%s (right%s)\n", which.c_str(), shm.c_str(), st->hands,
                 st->hands == 1 ? "" : "s", st->hands == 1 ? "" : ", left");
    return 2;
  }
  const auto meant = [mask](std::size_t h) { return (mask >> h & 1u) != 0; };
  std::fprintf(out, "lancet-rt (pid %d) on %s, tick %llu\n", ch.value().segment().creator_pid(), shm.c_str(),
               static_cast<unsigned long long>(st->tick));
  bool arm_faulted = false, link_lost = false;
  for (std::size_t h = 0; h < kHandCount; ++h) {
    if (!meant(h)) continue;
    const HandStatus& hs = st->hand[h];
    const char* const hand = hand_name(static_cast<Hand>(h));
    std::fprintf(out, "  %s arm: %s\n", hand, app::describe_arm(hs).c_str());
    if (hs.has_arm != 0) {
      std::fprintf(out, "  %s bus: %s\n", hand, app::describe_bus(hs.bus).c_str());
      if (hs.error_text[0] != '\0') std::fprintf(out, "  %s last error: %s\n", hand, hs.error_text);
    }
    arm_faulted = arm_faulted || (hs.has_arm != 0 && hs.device_state == device::Lifecycle::kFault);
    link_lost = link_lost || hs.link_lost != 0;
  }
  std::fprintf(out, "  watchdog: %s\n", st->watchdog_tripped ? rt::to_string(st->watchdog_reason) : "armed");
  if (!arm_faulted && st->watchdog_tripped == 0) {
    std::fprintf(out, "rearm: nothing to re-arm: the arms and the watchdog are armed\n");
    return 0;
  }
  if (link_lost) {
    std::fprintf(out, "rearm: an arm's bus link is down; lancet-rt reconnects on its own, re-arm once it says the link is back\n");
  }
  if (!confirmed) {
    std::fprintf(out, "Re-arm? Forces return as soon as the arm is active. Type 'yes' to re-arm: ");
    std::fflush(out);
    char line[64] = {};
    if (in == nullptr || std::fgets(line, sizeof line, in) == nullptr || std::string_view(line).substr(0, 3) != "yes") {
      std::fprintf(out, "\nrearm: not re-armed\n");
      return 1;
    }
  }
  OperatorRequest req{};
  req.seq = static_cast<std::uint64_t>(monotonic_ns());
  req.t_ns = monotonic_ns();
  req.kind = kOperatorRearm;
  req.pid = static_cast<std::int32_t>(getpid());
  req.hands = mask;
  wire::seal(req);
  shared.operator_request.write(req);
  std::array<std::uint64_t, kHandCount> failures_before{};
  for (std::size_t h = 0; h < kHandCount; ++h) failures_before[h] = st->hand[h].rearm_failures;
  const std::uint64_t taken_before = st->operator_requests;
  const auto until = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s));
  bool taken = false;
  while (Clock::now() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    auto now = read_rt_status(shared, 0.2, why);
    if (!now) continue;
    taken = taken || now->operator_requests > taken_before;
    if (!taken) continue;
    bool done = now->watchdog_tripped == 0;
    std::string arms;
    for (std::size_t h = 0; h < kHandCount; ++h) {
      if (!meant(h)) continue;
      const HandStatus& hs = now->hand[h];
      if (hs.rearm_failures > failures_before[h]) {
        std::fprintf(out, "rearm: %s arm: failed: %s\n", hand_name(static_cast<Hand>(h)), hs.rearm_text);
        return 1;
      }
      done = done && hs.rearm_pending == 0 && (hs.has_arm == 0 || hs.device_state == device::Lifecycle::kActive);
      arms += std::string(hand_name(static_cast<Hand>(h))) + " arm " + app::describe_arm(hs) + ", ";
    }
    if (done) {
      std::fprintf(out, "rearm: re-armed: %swatchdog armed\n", arms.c_str());
      return 0;
    }
  }
  std::fprintf(out, "rearm: %s within %.1f s\n", taken ? "lancet-rt took the request but an arm is not active" : "lancet-rt did not take the request",
               timeout_s);
  return 1;
}

int run_calibrate(const std::string& path, std::span<const double> home, bool write, std::FILE* out) {
  int code = 0;
  auto a = open_arm(path, out, code);
  if (!a) return code;
  if (a->config.falcon) return run_falcon_homing(*a, out);
  const int n = a->dev.device->joint_count();
  if (!home.empty() && static_cast<int>(home.size()) != n) {
    std::fprintf(out, "calibrate: --home gives %zu values, the arm has %d joints\n", home.size(), n);
    return 2;
  }
  // Average a short burst of readings: encoder noise should not end up in the offsets.
  constexpr int kSamples = 50;
  std::vector<double> mean(static_cast<std::size_t>(n), 0.0);
  device::JointState s{};
  for (int i = 0; i < kSamples; ++i) {
    if (const device::IoStatus st = a->dev.device->read(s); st != device::IoStatus::kOk) {
      std::fprintf(out, "calibrate: read failed: %s\n", device::to_string(st));
      return 1;
    }
    for (int j = 0; j < n; ++j) mean[static_cast<std::size_t>(j)] += s.q[static_cast<std::size_t>(j)] / kSamples;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  // New offset: the old one moved so that the pose read now becomes the home pose.
  std::vector<double> offsets(static_cast<std::size_t>(n));
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const double want = home.empty() ? 0.0 : (is_revolute(a->config, j) ? home[uj] * std::numbers::pi / 180.0 : home[uj] * 1e-3);
    offsets[uj] = a->config.joints[uj].offset + (want - mean[uj]);
    std::fprintf(out, "  joint %d %-10s reads %10.4f %s, home %10.4f %s: offset %+.4f %s\n", j, a->config.joints[uj].name.c_str(),
                 shown(a->config, j, mean[uj]), unit(a->config, j), shown(a->config, j, want), unit(a->config, j),
                 shown(a->config, j, offsets[uj]), unit(a->config, j));
  }
  const std::string cal = arm::calibration_path(path);
  if (!write) {
    std::fprintf(out, "dry run: add --write to save %s\n", cal.c_str());
    return 0;
  }
  const std::time_t now = std::time(nullptr);
  char stamp[64];
  std::strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
  std::ofstream f(cal);
  f << arm::calibration_text(a->config, offsets, std::string("measured ") + stamp + " from " + std::to_string(kSamples) + " readings");
  f.close();
  if (!f) {
    std::fprintf(out, "calibrate: cannot write %s\n", cal.c_str());
    return 2;
  }
  std::fprintf(out, "wrote %s\n", cal.c_str());
  return 0;
}

int run_jog(const std::string& path, int joint, double torque, double seconds, bool confirmed, std::FILE* out) {
  int code = 0;
  auto a = open_arm(path, out, code);
  if (!a) return code;
  device::Device& dev = *a->dev.device;
  const int n = dev.joint_count();
  if (joint < 0 || joint >= n) {
    std::fprintf(out, "jog: --joint must be 0..%d\n", n - 1);
    return 2;
  }
  const auto uj = static_cast<std::size_t>(joint);
  const double limit = uj < a->config.safety.max_joint_torque.size() ? 0.1 * a->config.safety.max_joint_torque[uj] : 0.0;
  if (!std::isfinite(torque) || std::abs(torque) > limit) {
    std::fprintf(out, "jog: |torque| must be at most %.4g (10%% of joint %d's max_joint_torque), found %g\n", limit, joint, torque);
    return 2;
  }
  if (!(seconds > 0 && seconds <= 2)) {
    std::fprintf(out, "jog: --seconds must be in (0, 2], found %g\n", seconds);
    return 2;
  }
  if (!confirmed) {
    std::fprintf(out, "jog moves joint %d (%s) with %g for %g s: clear the workspace, hold the stylus, and add --yes\n", joint,
                 a->config.joints[uj].name.c_str(), torque, seconds);
    return 2;
  }
  const Result<void> on = dev.activate();
  if (!on.ok()) {
    std::fprintf(out, "jog: %s\n", on.error().message.c_str());
    return 1;
  }
  device::JointState s{};
  device::JointCommand cmd{};
  cmd.n = n;
  (void)dev.read(s);
  const double q0 = s.q[uj];
  const auto start = Clock::now();
  auto next = start;
  int failures = 0;
  while (std::chrono::duration<double>(Clock::now() - start).count() < seconds) {
    if (dev.read(s) != device::IoStatus::kOk) ++failures;
    cmd.tau.fill(0.0);
    cmd.tau[uj] = torque;
    if (dev.write(cmd) != device::IoStatus::kOk) ++failures;
    next += std::chrono::milliseconds(1);
    std::this_thread::sleep_until(next);
  }
  (void)dev.deactivate();
  (void)dev.read(s);
  std::fprintf(out, "joint %d %s moved %+.4f %s (from %.4f to %.4f) under %g for %g s; %d I/O failures; torque off\n", joint,
               a->config.joints[uj].name.c_str(), shown(a->config, joint, s.q[uj] - q0), unit(a->config, joint),
               shown(a->config, joint, q0), shown(a->config, joint, s.q[uj]), torque, seconds, failures);
  return failures == 0 ? 0 : 1;
}

}  // namespace lancet::tools
