// lancet-armsim: a simulated haptic arm behind Modbus, for bring-up and tests without hardware.
// Emulates the arm of a config (hw_configs/*.toml with a [bus.modbus] register map) and serves the
// map over Modbus TCP on 127.0.0.1, or Modbus RTU on an inherited descriptor (a pty master):
//
//   lancet-armsim hw_configs/modbus_tcp_arm.toml --port 0 --hand script
//
// Once listening it prints one line, `lancet-armsim: serving '<name>' on 127.0.0.1:<port>`, and
// flushes stdout, so a parent can find the port. Runs until SIGINT / SIGTERM or --duration.
//
// --control PATH: faults at run time. lancet-armsim makes a FIFO at PATH (or takes the FIFO that
// is there) and reads one command per line from it (`echo "late 5" > PATH`; the commands are
// ArmServer::control()'s: fault, drop S, late S [US], garbage S, glitch [COUNTS], clear), without
// ever blocking on it; each applied command is acknowledged on stdout, flushed, as
// `armsim: control: <command>` once it has taken effect (`armsim: control: error: ...` for one
// it refuses), so a driver can wait for that line. The FIFO it made is removed when it exits.

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

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

// The --control FIFO: opened for reading without blocking, with a writer of our own kept open so
// that the reader never sees end-of-file between the driver's writes.
class ControlFifo {
 public:
  ~ControlFifo() {
    if (read_fd_ >= 0) close(read_fd_);
    if (keep_fd_ >= 0) close(keep_fd_);
    if (made_) unlink(path_.c_str());
  }
  /// Makes (or takes) the FIFO at path; an error message, empty on success.
  std::string open(const std::string& path) {
    path_ = path;
    struct stat st {};
    if (stat(path.c_str(), &st) == 0) {
      if (!S_ISFIFO(st.st_mode)) return "--control " + path + ": exists and is not a FIFO";
    } else if (mkfifo(path.c_str(), 0600) != 0) {
      return "--control " + path + ": cannot make a FIFO: " + std::strerror(errno);
    } else {
      made_ = true;
    }
    read_fd_ = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (read_fd_ < 0) return "--control " + path + ": cannot open it: " + std::strerror(errno);
    keep_fd_ = ::open(path.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC);
    return {};
  }
  [[nodiscard]] int fd() const { return read_fd_; }
  /// The complete lines that have arrived (without waiting).
  std::vector<std::string> lines() {
    char buf[512];
    for (;;) {
      const ssize_t n = read(read_fd_, buf, sizeof buf);
      if (n <= 0) break;
      pending_.append(buf, static_cast<std::size_t>(n));
    }
    std::vector<std::string> out;
    for (std::size_t eol = pending_.find('\n'); eol != std::string::npos; eol = pending_.find('\n')) {
      std::string line = pending_.substr(0, eol);
      pending_.erase(0, eol + 1);
      if (line.find_first_not_of(" \t\r") != std::string::npos) out.push_back(std::move(line));
    }
    if (pending_.size() > 4096) pending_.clear();  // no line that long is a command
    return out;
  }

 private:
  std::string path_, pending_;
  int read_fd_ = -1, keep_fd_ = -1;
  bool made_ = false;
};

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
  cli.add_option("--disconnect-after", o.disconnect_after,
                 "Modbus TCP: close the clients' sockets this many seconds after a client first wrote with the drives enabled; "
                 "CAN: silence the nodes this many seconds after start (0: never)")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--reconnect-after", o.reconnect_after, "after the disconnect, refuse connections for this many seconds more")
      ->check(CLI::NonNegativeNumber);
  cli.add_option("--encoder-glitch", o.faults.encoder_glitch, "probability that a reply puts a big jump on one encoder")
      ->check(CLI::Range(0.0, 1.0));
  cli.add_option("--glitch-counts", o.faults.glitch_counts, "size of an encoder glitch in counts (default: one motor revolution)")
      ->check(CLI::Range(std::int64_t{1}, std::int64_t{1'000'000'000}));
  std::string control_path;
  cli.add_option("--control", control_path,
                 "Modbus: make a FIFO at this path and take fault commands from it at run time (fault, drop S, late S [US], "
                 "garbage S, glitch [COUNTS], clear); each acknowledged on stdout as 'armsim: control: <command>'");
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
  if (config.value().backend == lancet::arm::Backend::kCanopen) {
    if (!control_path.empty()) {
      std::fprintf(stderr, "lancet-armsim: --control: Modbus only (this config is CANopen)\n");
      return 2;
    }
    return serve_can(config.value(), can, o, duration);
  }
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
  // Ready before the serving line: a driver that saw it may write commands at once.
  ControlFifo control;
  if (!control_path.empty()) {
    const std::string err = control.open(control_path);
    if (!err.empty()) {
      std::fprintf(stderr, "lancet-armsim: %s\n", err.c_str());
      return 2;
    }
  }
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
    if (control.fd() >= 0) {
      pollfd p{control.fd(), POLLIN, 0};
      (void)poll(&p, 1, 20);
      for (const std::string& line : control.lines()) {
        auto applied = s.control(line);
        if (applied.ok())
          std::printf("armsim: control: %s\n", applied.value().c_str());
        else
          std::printf("armsim: control: error: %s\n", applied.error().message.c_str());
        std::fflush(stdout);
      }
    }
    const timespec poll_interval{0, control.fd() >= 0 ? 0 : 20'000'000};
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
