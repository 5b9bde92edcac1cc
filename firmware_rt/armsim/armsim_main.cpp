// lancet-armsim: a simulated haptic arm behind Modbus, for bring-up and tests without hardware.
// Emulates the arm of a config (hw_configs/*.toml with a [bus.modbus] register map) and serves the
// map over Modbus TCP on 127.0.0.1, or Modbus RTU on an inherited descriptor (a pty master):
//
//   lancet-armsim hw_configs/modbus_tcp_arm.toml --port 0 --hand script
//
// Once listening it prints one line, `lancet-armsim: serving '<name>' on 127.0.0.1:<port>`, and
// flushes stdout, so a parent can find the port. Runs until SIGINT / SIGTERM or --duration.

#include <signal.h>
#include <time.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <string>

#include "arm/arm_config.hpp"
#include "armsim/canopen_nodes.hpp"
#include "armsim/modbus_server.hpp"
#include "device/sim_stylus.hpp"

namespace {

using lancet::armsim::ArmServer;
using lancet::armsim::HandMode;
using lancet::armsim::ServerOptions;

std::int64_t mono_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// SIGINT and SIGTERM blocked in this thread and in the threads it starts; the main loop takes
// them with sigtimedwait.
sigset_t block_stop_signals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
  return set;
}

// The CAN options: the interface and what the nodes get wrong on purpose.
struct CanOptions {
  std::string iface;               ///< --can: instead of the config's interface
  std::int64_t tpdo_delay_us = 0;  ///< --tpdo-delay-us: every TPDO this long after its SYNC
  std::string refuse_mode;         ///< --refuse-mode NODE:MODE: the node keeps its mode when 0x6060 asks for MODE
};

// CANopen: the arm's CiA 402 nodes on a SocketCAN interface (vcan where the kernel has CAN). The
// hand follows the script, holds or lets go; --disconnect-after silences every node (an unplugged
// bus). What the nodes do on their own (a lost master heartbeat) is said on stderr as it happens,
// and each node's state and counts when it ends.
int serve_can(lancet::arm::ArmConfig config, const CanOptions& can, const ServerOptions& o, double duration) {
  if (!can.iface.empty()) config.canopen->interface_name = can.iface;
  int refuse_node = 0, refuse_mode = 0;
  if (!can.refuse_mode.empty() && (std::sscanf(can.refuse_mode.c_str(), "%d:%d", &refuse_node, &refuse_mode) != 2 ||
                                   refuse_mode < -128 || refuse_mode > 127)) {
    std::fprintf(stderr, "lancet-armsim: --refuse-mode: expected NODE:MODE (e.g. 2:10), found '%s'\n", can.refuse_mode.c_str());
    return 2;
  }
  // Blocked before the nodes' thread starts, so that it inherits the mask.
  const sigset_t stop_signals = block_stop_signals();
  lancet::armsim::CanopenNodeSet::Options node_options;
  node_options.tpdo_delay_us = can.tpdo_delay_us;
  node_options.on_event = [](const std::string& line) {
    std::fprintf(stderr, "lancet-armsim: %s\n", line.c_str());
    std::fflush(stderr);
  };
  auto nodes = lancet::armsim::CanopenNodeSet::start(config, node_options);
  if (!nodes.ok()) {
    std::fprintf(stderr, "lancet-armsim: %s\n", nodes.error().message.c_str());
    return 2;
  }
  if (refuse_node != 0) nodes.value()->set_refused_mode(refuse_node, static_cast<std::int8_t>(refuse_mode));
  std::printf("lancet-armsim: serving '%s' on CAN %s (%zu nodes)\n", config.name.c_str(), config.canopen->interface_name.c_str(),
              config.canopen->node_ids.size());
  std::fflush(stdout);
  const auto& ws = config.safety;
  const lancet::Vec3 centre = 0.5 * (ws.workspace_min + ws.workspace_max);
  const std::int64_t start = mono_ns();
  const std::int64_t end = duration > 0 ? start + static_cast<std::int64_t>(duration * 1e9) : 0;
  bool silenced = false;
  int sig = 0;
  nodes.value()->with_physics([&](lancet::device::ArmPhysics& p) {
    p.set_hand_holding(o.hand != HandMode::kFree);
    return 0;
  });
  while (end == 0 || mono_ns() < end) {
    const double t = static_cast<double>(mono_ns() - start) * 1e-9;
    if (o.hand == HandMode::kScript)
      nodes.value()->with_physics([&](lancet::device::ArmPhysics& p) {
        p.set_hand_target(centre + lancet::device::scripted_target(t, 0.004));
        return 0;
      });
    if (!silenced && o.disconnect_after > 0 && t >= o.disconnect_after) {
      for (int id : config.canopen->node_ids) nodes.value()->set_silent(id, true);
      silenced = true;
    }
    const timespec poll_interval{0, 10'000'000};
    sig = sigtimedwait(&stop_signals, nullptr, &poll_interval);
    if (sig == SIGINT || sig == SIGTERM) break;
  }
  std::fprintf(stderr, "lancet-armsim: %s\n", sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "done");
  for (int id : config.canopen->node_ids) {
    const auto v = nodes.value()->node(id);
    std::fprintf(stderr,
                 "lancet-armsim: node %d: NMT 0x%02X, statusword 0x%04X, mode %d, %llu SDO requests (%llu downloads), %llu NMT "
                 "commands, %llu SYNCs, %llu master heartbeats heard, %llu lost, last EMCY 0x%04X\n",
                 id, v.nmt, v.statusword, v.mode, static_cast<unsigned long long>(v.sdo_requests),
                 static_cast<unsigned long long>(v.sdo_downloads), static_cast<unsigned long long>(v.nmt_commands),
                 static_cast<unsigned long long>(v.syncs), static_cast<unsigned long long>(v.master_heartbeats),
                 static_cast<unsigned long long>(v.heartbeat_losses), v.last_emcy);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App cli{"lancet-armsim: a simulated haptic arm served over Modbus TCP (or RTU on a descriptor) from its config"};
  std::string config_path;
  int port = -1;
  int rtu_fd = -1;
  std::string hand = "script";
  double duration = 0;
  ServerOptions o;
  cli.add_option("config", config_path, "the arm's TOML file: a [bus.modbus] register map (served over TCP or RTU) or a [bus.canopen] node set (served on SocketCAN)")->required();
  cli.add_option("--port", port, "TCP port on 127.0.0.1; 0: an ephemeral port (default: the config's port)")->check(CLI::Range(0, 65535));
  cli.add_option("--rtu-fd", rtu_fd, "serve Modbus RTU on this inherited, open descriptor (a pty master) instead of TCP")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--hand", hand, "the simulated hand: script (scripted strokes around the workspace centre), hold (holds the start "
                                 "pose), free (no hand)")
      ->check(CLI::IsMember({"script", "hold", "free"}))
      ->capture_default_str();
  cli.add_option("--drop-replies", o.faults.drop_replies, "probability of leaving a request unanswered")->check(CLI::Range(0.0, 1.0));
  cli.add_option("--delay-us", o.faults.delay_us, "send every reply this many microseconds late")->check(CLI::Range(0, 60'000'000));
  cli.add_option("--delay-probability", o.faults.delay_probability,
                 "Modbus: delay only this fraction of the replies by --delay-us (now and then, as a loaded host would)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  cli.add_option("--corrupt", o.faults.corrupt, "probability of flipping a byte of a reply (TCP: a framing byte; RTU: caught by the CRC)")
      ->check(CLI::Range(0.0, 1.0));
  cli.add_option("--disconnect-after", o.disconnect_after, "close the clients' sockets after this many seconds (TCP; 0: never)")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--reconnect-after", o.reconnect_after, "after the disconnect, refuse connections for this many seconds more")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--encoder-glitch", o.faults.encoder_glitch, "probability that a reply puts a big jump on one encoder")
      ->check(CLI::Range(0.0, 1.0));
  cli.add_option("--seed", o.seed, "seed of the fault injection")->capture_default_str();
  cli.add_option("--duration", duration, "seconds to run; 0: until SIGINT or SIGTERM")->check(CLI::NonNegativeNumber);
  CanOptions can;
  cli.add_option("--can", can.iface, "for a canopen config: emulate its CiA 402 nodes on this SocketCAN interface (default: the config's)");
  cli.add_option("--tpdo-delay-us", can.tpdo_delay_us, "CAN: every node sends its TPDOs this many microseconds after the SYNC")
      ->check(CLI::Range(0, 1'000'000));
  cli.add_option("--refuse-mode", can.refuse_mode,
                 "CAN: NODE:MODE, that node takes a write of MODE to 0x6060 but stays in its mode (0x6061 tells)");
  CLI11_PARSE(cli, argc, argv);

  auto mode = lancet::armsim::parse_hand_mode(hand);
  if (!mode.ok()) {
    std::fprintf(stderr, "lancet-armsim: %s\n", mode.error().message.c_str());
    return 2;
  }
  o.hand = mode.value();
  auto config = lancet::arm::load_arm_config(config_path);
  if (!config.ok()) {
    std::fprintf(stderr, "lancet-armsim: %s\n", config.error().message.c_str());
    return 2;
  }
  if (config.value().backend == lancet::arm::Backend::kCanopen) return serve_can(config.value(), can, o, duration);
  auto server = ArmServer::create(config.value(), o);
  if (!server.ok()) {
    std::fprintf(stderr, "%s\n", server.error().message.c_str());
    return 2;
  }

  // The threads the server starts inherit this mask; the main thread takes the signals itself.
  const sigset_t stop_signals = block_stop_signals();
  signal(SIGPIPE, SIG_IGN);

  ArmServer& s = *server.value();
  const std::string& name = config.value().name;
  if (rtu_fd >= 0) {
    const auto started = s.start_rtu(rtu_fd);
    if (!started.ok()) {
      std::fprintf(stderr, "%s\n", started.error().message.c_str());
      return 2;
    }
    std::printf("lancet-armsim: serving '%s' on fd %d (rtu, unit %d)\n", name.c_str(), rtu_fd, config.value().modbus->unit_id);
  } else {
    if (port < 0) port = config.value().modbus->transport == lancet::arm::ModbusTransport::kTcp ? config.value().modbus->port : 1502;
    auto bound = s.start_tcp(port);
    if (!bound.ok()) {
      std::fprintf(stderr, "%s\n", bound.error().message.c_str());
      return 2;
    }
    std::printf("lancet-armsim: serving '%s' on 127.0.0.1:%d\n", name.c_str(), bound.value());
  }
  std::fflush(stdout);

  const std::int64_t end = duration > 0 ? mono_ns() + static_cast<std::int64_t>(duration * 1e9) : 0;
  int sig = 0;
  std::uint64_t trips = 0;
  while (end == 0 || mono_ns() < end) {
    const timespec poll_interval{0, 20'000'000};
    sig = sigtimedwait(&stop_signals, nullptr, &poll_interval);
    if (sig == SIGINT || sig == SIGTERM) break;
    // Say it when the drive-side watchdog acts: the host stopped writing the heartbeat.
    const auto now = s.snapshot();
    if (now.stats.watchdog_trips > trips) {
      trips = now.stats.watchdog_trips;
      std::fprintf(stderr, "lancet-armsim: watchdog: heartbeat lost after %.1f ms (limit %g ms), drives torque-free; status 0x%04X until a fault reset\n",
                   now.stats.last_trip_silence_ms, now.watchdog_ms, now.status);
    }
  }
  s.stop();
  const auto snap = s.snapshot();
  std::fprintf(stderr,
               "lancet-armsim: %s after %llu physics steps; %llu requests, %llu replies (%llu dropped, %llu delayed, %llu corrupted, "
               "%llu glitches), %llu connections, %llu forced disconnects, %llu watchdog trips\n",
               sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "done", static_cast<unsigned long long>(snap.steps),
               static_cast<unsigned long long>(snap.stats.requests), static_cast<unsigned long long>(snap.stats.replies),
               static_cast<unsigned long long>(snap.stats.dropped), static_cast<unsigned long long>(snap.stats.delayed),
               static_cast<unsigned long long>(snap.stats.corrupted), static_cast<unsigned long long>(snap.stats.glitches),
               static_cast<unsigned long long>(snap.stats.connections), static_cast<unsigned long long>(snap.stats.forced_disconnects),
               static_cast<unsigned long long>(snap.stats.watchdog_trips));
  return 0;
}
