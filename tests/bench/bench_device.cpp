// lancet-bench-device: the I/O time of one device tick (read() + write()) on each backend we can
// run without hardware: the in-process sim, Modbus TCP on loopback against the in-process arm
// server (its physics thread running at 1 kHz), two such arms on two servers in one tick (read
// both, then write both, as lancet-rt's tick does with two hands), and Modbus RTU over a pty pair.
// Prints one JSON object: p50, p99, max in ns per tick, and the ticks that did not come back ok.
//   lancet-bench-device [--ticks N] [--timeout-ms T] [--rate HZ]
// --timeout-ms sets the Modbus response timeout (default: the config's); --rate paces the ticks
// (default 0: back to back).

#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "arm/arm_config.hpp"
#include "armsim/modbus_server.hpp"
#include "device/modbus_arm.hpp"
#include "device/sim_arm.hpp"
#include "lancet/shared_model/units.hpp"
#include "latency_stats.hpp"

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace {

using namespace lancet;

struct Stats {
  double p50 = 0, p99 = 0, max = 0;
  std::uint64_t errors = 0;
  device::IoCounters counters{};
  bool ran = false;
  std::string note;
};

// One tick's I/O on every device, as lancet-rt's tick does it: read them all, then write them all.
Stats measure(std::span<device::Device* const> devs, int ticks, double rate) {
  Stats st;
  std::vector<double> ns(static_cast<std::size_t>(ticks));
  device::JointState s;
  device::JointCommand cmd;
  const std::int64_t period = rate > 0 ? static_cast<std::int64_t>(1e9 / rate) : 0;
  std::int64_t next = monotonic_ns();
  for (int i = -1000; i < ticks; ++i) {  // 1000 warm-up ticks
    const std::int64_t t0 = monotonic_ns();
    bool ok = true;
    for (device::Device* dev : devs) ok = dev->read(s) == device::IoStatus::kOk && ok;
    for (std::size_t d = 0; d < devs.size(); ++d) {
      // A small torque that changes every tick, as the servo's would (each arm its own).
      cmd.n = devs[d]->joint_count();
      for (int j = 0; j < cmd.n; ++j) cmd.tau[static_cast<std::size_t>(j)] = 0.01 * ((i + j + static_cast<int>(d)) % 7 - 3);
      ok = devs[d]->write(cmd) == device::IoStatus::kOk && ok;
    }
    const std::int64_t t1 = monotonic_ns();
    if (i >= 0) {
      ns[static_cast<std::size_t>(i)] = static_cast<double>(t1 - t0);
      if (!ok) ++st.errors;
    }
    if (period > 0) {
      next += period;
      while (monotonic_ns() < next) std::this_thread::yield();
    }
  }
  const bench::Latency l = bench::latency_of(ns);
  st.p50 = l.p50, st.p99 = l.p99, st.max = l.max;
  for (device::Device* dev : devs) {
    const device::IoCounters c = dev->counters();
    st.counters.timeouts += c.timeouts;
    st.counters.crc_errors += c.crc_errors;
    st.counters.protocol_errors += c.protocol_errors;
  }
  st.ran = true;
  return st;
}

// Configure and activate; a loaded machine can miss a tight response timeout once, so each step
// gets three tries.
bool bring_up(device::Device& dev, std::string& why) {
  for (auto step : {&device::Device::configure, &device::Device::activate}) {
    Result<void> o = (dev.*step)();
    for (int attempt = 1; attempt < 3 && !o.ok(); ++attempt) o = (dev.*step)();
    if (!o.ok()) {
      why = o.error().message;
      return false;
    }
  }
  return true;
}

Stats bench_sim(int ticks, double rate) {
  Stats st;
  auto config = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/sim_3dof.toml");
  if (!config.ok()) return {.note = config.error().message};
  auto dev = device::SimArm::create(config.value());
  if (!dev.ok()) return {.note = dev.error().message};
  if (!bring_up(*dev.value(), st.note)) return st;
  device::Device* const devs[] = {dev.value().get()};
  return measure(devs, ticks, rate);
}

// One Modbus arm: the in-process arm server (its physics thread at 1 kHz) and the device on it.
struct ModbusRig {
  std::unique_ptr<armsim::ArmServer> server;
  std::unique_ptr<device::ModbusArm> dev;
  int master = -1, slave = -1;  // the pty pair (RTU)
  std::string note;             // why there is no device ("" when there is)
  ModbusRig() = default;
  ModbusRig(const ModbusRig&) = delete;
  ModbusRig& operator=(const ModbusRig&) = delete;
  ~ModbusRig() {
    dev.reset();
    if (server) server->stop();
    if (master >= 0) close(master);
    if (slave >= 0) close(slave);
  }
};

// Serves `config`'s arm over TCP on an ephemeral port (or RTU on a pty pair) and brings a
// ModbusArm up on it; rig.note says what failed.
void start_modbus(arm::ArmConfig config, bool rtu, double timeout, ModbusRig& rig) {
  armsim::ServerOptions o;
  o.hand = armsim::HandMode::kHold;
  auto server = armsim::ArmServer::create(config, o);
  if (!server.ok()) {
    rig.note = server.error().message;
    return;
  }
  rig.server = std::move(server).value();
  if (rtu) {
    char name[256] = {};
    if (openpty(&rig.master, &rig.slave, name, nullptr, nullptr) != 0) {
      rig.note = std::string("openpty: ") + std::strerror(errno);
      return;
    }
    termios t{};
    tcgetattr(rig.slave, &t);
    cfmakeraw(&t);
    tcsetattr(rig.slave, TCSANOW, &t);
    config.modbus->transport = arm::ModbusTransport::kRtu;
    config.modbus->host.clear();
    config.modbus->device = name;
    config.modbus->baud = 115200;
    const Result<void> started = rig.server->start_rtu(rig.master);
    if (!started.ok()) rig.note = started.error().message;
  } else {
    auto port = rig.server->start_tcp(0);
    if (port.ok())
      config.modbus->port = port.value();
    else
      rig.note = port.error().message;
  }
  if (!rig.note.empty()) return;
  if (timeout > 0) config.modbus->response_timeout = timeout;
  config.modbus->drive_watchdog = 0;  // measures transactions; a slow --rate would trip the arm's watchdog
  auto dev = device::ModbusArm::create(config, {.max_consecutive_errors = 1'000'000});
  if (!dev.ok()) {
    rig.note = dev.error().message;
    return;
  }
  rig.dev = std::move(dev).value();
  if (!bring_up(*rig.dev, rig.note)) rig.dev.reset();
}

// `arms` Modbus arms, each behind its own server (TCP: two ports, as two drive boxes), read and
// written in one tick.
Stats bench_modbus(const arm::ArmConfig& config, bool rtu, int arms, int ticks, double rate, double timeout) {
  std::vector<std::unique_ptr<ModbusRig>> rigs;
  std::vector<device::Device*> devs;
  for (int a = 0; a < arms; ++a) {
    rigs.push_back(std::make_unique<ModbusRig>());
    start_modbus(config, rtu, timeout, *rigs.back());
    if (!rigs.back()->dev) return {.note = rigs.back()->note};
    devs.push_back(rigs.back()->dev.get());
  }
  return measure(devs, ticks, rate);
}

std::string json_string(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c == '\n' ? ' ' : c;
  }
  return out + "\"";
}

}  // namespace

int main(int argc, char** argv) {
  int ticks = 20'000;
  double timeout_ms = 0, rate = 0;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--ticks") == 0 && i + 1 < argc) {
      ticks = std::max(100, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--timeout-ms") == 0 && i + 1 < argc) {
      timeout_ms = std::atof(argv[++i]);
    } else if (std::strcmp(argv[i], "--rate") == 0 && i + 1 < argc) {
      rate = std::atof(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: lancet-bench-device [--ticks N] [--timeout-ms T] [--rate HZ]\n");
      return 2;
    }
  }
  auto modbus = arm::load_arm_config(std::string(LANCET_SOURCE_DIR) + "/hw_configs/modbus_tcp_arm.toml");
  if (!modbus.ok()) {
    std::fprintf(stderr, "lancet-bench-device: %s\n", modbus.error().message.c_str());
    return 2;
  }
  const double timeout = timeout_ms > 0 ? timeout_ms * 1e-3 : modbus.value().modbus->response_timeout;
  struct Row {
    const char* backend;
    Stats s;
  };
  const Row rows[] = {
      {"sim (in process)", bench_sim(ticks, rate)},
      {"modbus tcp (loopback, in-process server)", bench_modbus(modbus.value(), false, 1, ticks, rate, timeout)},
      {"modbus tcp, two arms (two in-process servers; read both, then write both)", bench_modbus(modbus.value(), false, 2, ticks, rate, timeout)},
      {"modbus rtu (pty pair, in-process server)", bench_modbus(modbus.value(), true, 1, ticks, rate, timeout)},
  };
  std::printf("{\n  \"ticks\": %d,\n  \"rate_hz\": %g,\n  \"modbus_response_timeout_ms\": %g,\n  \"results\": [\n", ticks, rate, timeout * 1e3);
  bool first = true;
  for (const Row& r : rows) {
    if (r.s.ran)
      std::printf("%s    {\"backend\": \"%s\", \"p50_ns\": %.0f, \"p99_ns\": %.0f, \"max_ns\": %.0f, \"ticks_with_errors\": %llu, "
                  "\"timeouts\": %llu, \"crc_errors\": %llu, \"protocol_errors\": %llu}",
                  first ? "" : ",\n", r.backend, r.s.p50, r.s.p99, r.s.max, static_cast<unsigned long long>(r.s.errors),
                  static_cast<unsigned long long>(r.s.counters.timeouts), static_cast<unsigned long long>(r.s.counters.crc_errors),
                  static_cast<unsigned long long>(r.s.counters.protocol_errors));
    else
      std::printf("%s    {\"backend\": \"%s\", \"error\": %s}", first ? "" : ",\n", r.backend, json_string(r.s.note).c_str());
    first = false;
  }
  std::printf("\n  ]\n}\n");
  return 0;
}
