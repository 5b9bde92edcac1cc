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

// CANopen: the arm's CiA 402 nodes on a SocketCAN interface (vcan where the kernel has CAN). The
// hand follows the script, holds or lets go; --disconnect-after silences every node (an unplugged
// bus).
int serve_can(lancet::arm::ArmConfig config, const std::string& iface, const ServerOptions& o, double duration) {
  if (!iface.empty()) config.canopen->interface_name = iface;
  auto nodes = lancet::armsim::CanopenNodeSet::start(config);
  if (!nodes.ok()) {
    std::fprintf(stderr, "lancet-armsim: %s\n", nodes.error().message.c_str());
    return 2;
  }
  const sigset_t stop_signals = block_stop_signals();
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
  std::string can_iface;
  cli.add_option("--can", can_iface, "for a canopen config: emulate its CiA 402 nodes on this SocketCAN interface (default: the config's)");
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
  if (config.value().backend == lancet::arm::Backend::kCanopen) return serve_can(config.value(), can_iface, o, duration);
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
      std::fprintf(stderr, "%s\n", started.error->message.c_str());
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
  while (end == 0 || mono_ns() < end) {
    const timespec poll_interval{0, 100'000'000};
    sig = sigtimedwait(&stop_signals, nullptr, &poll_interval);
    if (sig == SIGINT || sig == SIGTERM) break;
  }
  s.stop();
  const auto snap = s.snapshot();
  std::fprintf(stderr,
               "lancet-armsim: %s after %llu physics steps; %llu requests, %llu replies (%llu dropped, %llu delayed, %llu corrupted, "
               "%llu glitches), %llu connections, %llu forced disconnects\n",
               sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "done", static_cast<unsigned long long>(snap.steps),
               static_cast<unsigned long long>(snap.stats.requests), static_cast<unsigned long long>(snap.stats.replies),
               static_cast<unsigned long long>(snap.stats.dropped), static_cast<unsigned long long>(snap.stats.delayed),
               static_cast<unsigned long long>(snap.stats.corrupted), static_cast<unsigned long long>(snap.stats.glitches),
               static_cast<unsigned long long>(snap.stats.connections), static_cast<unsigned long long>(snap.stats.forced_disconnects));
  return 0;
}
