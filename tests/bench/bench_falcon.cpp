// lancet-bench-falcon: the I/O time of one device tick (read() + write()) on the Novint Falcon
// backend against the emulated Falcon (tests/firmware_rt/device/falcon_emulator.hpp under a
// umockdev testbed in this process), and, in the same run, the yardstick: the same exchange (one
// 16-byte command out, its 16-byte reply in) with plain synchronous libusb calls on the same
// emulated chip. The emulator's transport (umockdev's socket and handler thread) is in both; the
// difference is what FalconArm and the FTDI layer add. Prints one JSON object: p50, p99, max in ns
// per tick, the ticks that failed, and the share of a 1 ms tick the p99 takes.
//   lancet-bench-falcon [--ticks N] [--rate HZ]     (--rate 0: back to back, the default)
// Runs itself under umockdev-wrapper (Debian package umockdev) when it is not already.

#include <libusb.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/falcon_arm.hpp"
#include "falcon_emulator.hpp"
#include "latency_stats.hpp"
#include "lancet/shared_model/units.hpp"
#include "usb_testbed.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace {

using namespace lancet;

struct Stats {
  double p50 = 0, p99 = 0, max = 0;
  std::uint64_t errors = 0;
};

Stats summarise(std::vector<double> ns, std::uint64_t errors) {
  const bench::Latency l = bench::latency_of(ns);
  return {l.p50, l.p99, l.max, errors};
}

void pace(std::int64_t& next, std::int64_t period) {
  if (period <= 0) return;
  next += period;
  while (monotonic_ns() < next) std::this_thread::sleep_for(std::chrono::microseconds(50));
}

// FalconArm's tick: read (the reply to the last command), then write (the next command).
Stats measure_falcon(device::FalconArm& arm, int ticks, double rate) {
  std::vector<double> ns;
  ns.reserve(static_cast<std::size_t>(ticks));
  std::uint64_t errors = 0;
  device::JointState s;
  device::JointCommand cmd{3, {}};
  const std::int64_t period = rate > 0 ? static_cast<std::int64_t>(1e9 / rate) : 0;
  std::int64_t next = monotonic_ns();
  for (int i = -500; i < ticks; ++i) {
    const std::int64_t t0 = monotonic_ns();
    const bool ok = arm.read(s) == device::IoStatus::kOk;
    cmd.tau[0] = 0.01 * std::sin(i * 0.01);
    const bool wrote = arm.write(cmd) == device::IoStatus::kOk;
    const std::int64_t t1 = monotonic_ns();
    if (i >= 0) {
      ns.push_back(static_cast<double>(t1 - t0));
      if (!ok || !wrote) ++errors;
    }
    pace(next, period);
  }
  return summarise(std::move(ns), errors);
}

// Plain libusb: the command out, then bulk IN until its 16-byte reply (after the status bytes).
Stats measure_plain(int ticks, double rate) {
  std::vector<double> ns;
  std::uint64_t errors = 0;
  libusb_context* ctx = nullptr;
  if (libusb_init(&ctx) != 0) return {0, 0, 0, 1};
  libusb_device_handle* h = libusb_open_device_with_vid_pid(ctx, 0x0403, 0xcb48);
  if (h != nullptr) libusb_set_auto_detach_kernel_driver(h, 1);  // ftdi_sio is bound again after FalconArm
  if (h == nullptr || libusb_claim_interface(h, 0) != 0) {
    if (h != nullptr) libusb_close(h);
    libusb_exit(ctx);
    return {0, 0, 0, 1};
  }
  // A zero command with homing off and the green LED: "<AAAAAAAAAAAACA>".
  std::uint8_t out[16];
  std::memcpy(out, "<AAAAAAAAAAAACA>", 16);
  const std::int64_t period = rate > 0 ? static_cast<std::int64_t>(1e9 / rate) : 0;
  std::int64_t next = monotonic_ns();
  for (int i = -500; i < ticks; ++i) {
    const std::int64_t t0 = monotonic_ns();
    int done = 0;
    bool ok = libusb_bulk_transfer(h, 0x02, out, 16, &done, 1000) == 0 && done == 16;
    int got = 0;
    while (ok && got < 16) {
      std::uint8_t in[64];
      int n = 0;
      ok = libusb_bulk_transfer(h, 0x81, in, 64, &n, 1000) == 0;
      got += std::max(0, n - 2);
    }
    const std::int64_t t1 = monotonic_ns();
    if (i >= 0) {
      ns.push_back(static_cast<double>(t1 - t0));
      if (!ok) ++errors;
    }
    pace(next, period);
  }
  libusb_release_interface(h, 0);
  libusb_close(h);
  libusb_exit(ctx);
  return summarise(std::move(ns), errors);
}

void print(const char* name, const Stats& s, bool last) {
  std::printf("    \"%s\": {\"p50_ns\": %.0f, \"p99_ns\": %.0f, \"max_ns\": %.0f, \"errors\": %llu, \"p99_share_of_1ms_tick\": %.3f}%s\n", name,
              s.p50, s.p99, s.max, static_cast<unsigned long long>(s.errors), s.p99 / 1e6, last ? "" : ",");
}

}  // namespace

int main(int argc, char** argv) {
  test::reexec_under_umockdev_if_needed(argv);
  if (!test::in_umockdev()) {
    std::fprintf(stderr, "lancet-bench-falcon: %s\n", test::not_in_umockdev_reason());
    return 2;
  }
  int ticks = 5000;
  double rate = 0;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (std::strcmp(argv[i], "--ticks") == 0) ticks = std::max(1, std::atoi(argv[i + 1]));
    if (std::strcmp(argv[i], "--rate") == 0) rate = std::atof(argv[i + 1]);
  }
  auto loaded = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/novint_falcon.toml");
  if (!loaded.ok()) {
    std::fprintf(stderr, "%s\n", loaded.error().message.c_str());
    return 2;
  }
  arm::ArmConfig cfg = std::move(loaded).value();
  cfg.falcon->timeout = 1.0;  // the emulator answers; a long wait only catches a hang
  test::FalconEmulatorOptions o;
  o.firmware_running = true;
  auto kin = arm::make_kinematics(cfg);
  if (const auto q = kin.value().delta()->inverse({0, 0, 0})) o.start_q = *q;
  o.home_angles = o.start_q;  // the switches where it rests: homed at the first command
  test::FalconEmulator emu(cfg, o);
  test::UsbTestbed bed(emu, std::string(LANCET_SOURCE_DIR) + "/tests/firmware_rt/device/data/novint_falcon.umockdev",
                       "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-1");
  if (!bed.plug(2)) return 2;

  Stats falcon, plain;
  {
    auto made = device::FalconArm::create(cfg);
    if (!made.ok()) return 2;
    auto arm = std::move(made).value();
    if (const auto r = arm->configure(); !r.ok()) {
      std::fprintf(stderr, "%s\n", r.error().message.c_str());
      return 2;
    }
    if (const auto r = arm->activate(); !r.ok()) {
      std::fprintf(stderr, "%s\n", r.error().message.c_str());
      return 2;
    }
    falcon = measure_falcon(*arm, ticks, rate);
  }
  plain = measure_plain(ticks, rate);
  std::printf("{\n  \"bench\": \"falcon\",\n  \"ticks\": %d,\n  \"rate_hz\": %.0f,\n  \"results\": {\n", ticks, rate);
  print("falcon_read_write", falcon, false);
  print("plain_libusb_round_trip", plain, true);
  std::printf("  }\n}\n");
  return 0;
}
