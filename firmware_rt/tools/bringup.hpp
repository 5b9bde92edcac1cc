#pragma once
// lancetctl's bring-up commands for hardware integrators (not real-time; they talk to the arm at
// a leisurely rate from an ordinary thread):
//   list       USB devices, CAN interfaces and serial ports this machine has
//   probe      configure the arm from its config and read it once: encoders, joints, tool, status
//   monitor    read it continuously: joints, tool pose, buttons, bus statistics (never moves it)
//   calibrate  the arm held in its home pose: encoder offsets that make the joints read that pose,
//              written to the calibration file next to the config (never into the config)
//   jog        a small bounded torque on one joint for a short time, after explicit confirmation
// Exit codes: 0 done, 1 the arm did not answer or a check failed, 2 bad arguments or config.

#include <cstdio>
#include <optional>
#include <span>
#include <string>

namespace lancet::tools {

int run_list(std::FILE* out);
int run_probe(const std::string& config_path, std::FILE* out);
int run_monitor(const std::string& config_path, double duration_s, double rate_hz, std::FILE* out);
/// While lancet-rt drives the arms (it owns the buses): its live status from shared memory: a line
/// for the loop (tick, viz, wake-up p99, watchdog), then a line per hand ("right:", "left:"): tool
/// position, commanded force and fade, contact, tool, the arm's state and error count.
int run_monitor_rt(const std::string& shm, double duration_s, double rate_hz, std::FILE* out, bool json = false);
/// Re-arms a running lancet-rt's faulted arms and tripped watchdog: shows the faults of the hands
/// meant (`hand`: right, left or both; both means every hand lancet-rt drives), asks for "yes" on
/// `in` unless `confirmed`, sends the request (SharedState::operator_request, its hands those
/// meant) and waits up to timeout_s for the outcome. 0: re-armed or nothing to do; 1: refused,
/// failed or no answer; 2: bad arguments (a hand lancet-rt does not drive).
int run_rearm_rt(const std::string& shm, bool confirmed, double timeout_s, std::FILE* in, std::FILE* out,
                 const std::string& hand = "both");
/// home_deg: the joint angles of the home pose (deg, or mm for prismatic joints); empty: all zero.
int run_calibrate(const std::string& config_path, std::span<const double> home, bool write, std::FILE* out);
int run_jog(const std::string& config_path, int joint, double torque, double seconds, bool confirmed, std::FILE* out);

}  // namespace lancet::tools
