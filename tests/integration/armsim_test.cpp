// lancet-rt driving an arm over a real bus: lancet-armsim serves the Modbus TCP arm of
// hw_configs/modbus_tcp_arm.toml (its hand scripted into the tissue), lancet-rt runs that config,
// lancet-viz (headless) publishes the tissue. The arm is read and written over libmodbus every
// tick and the servo renders forces on it.
// Nothing here depends on the machine's speed: lancet-rt runs with a bus timeout and a drive
// watchdog that no tick held back by a loaded VM reaches, and the test waits for the events (the
// tissue published, the tool in contact with force), with a deadline that only catches hangs.

#include <gtest/gtest.h>
#include <sys/mman.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <string>
#include <thread>

#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "process.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using namespace std::chrono_literals;

const std::string kBin = std::string(LANCET_BINARY_DIR);
const std::string kSrc = std::string(LANCET_SOURCE_DIR);

TEST(ArmsimModbus, LancetRtRendersForcesOnTheSimulatedArmOverModbusTcp) {
  // lancet-viz renders headless through EGL: no X server, and none may be assumed.
  unsetenv("DISPLAY");
  const auto dir = std::filesystem::temp_directory_path() / ("lancet-armsim-it-" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const std::string shm = "/lancet-armsim-it-" + std::to_string(getpid());
  const auto path = [&](const char* f) { return (dir / f).string(); };

  test::Child sim({kBin + "/firmware_rt/lancet-armsim", kSrc + "/hw_configs/modbus_tcp_arm.toml", "--port", "0", "--hand", "script",
                   "--duration", "600"},
                  path("armsim.log"));
  std::string port;
  (void)test::eventually([&] {
    std::smatch m;
    const std::string log = test::read_file(path("armsim.log"));
    if (std::regex_search(log, m, std::regex("127\\.0\\.0\\.1:([0-9]+)"))) port = m[1].str();
    return !port.empty() || !sim.running();
  });
  ASSERT_FALSE(port.empty()) << test::read_file(path("armsim.log"));
  // The shipped config, pointed at this armsim's port, with a bus timeout and a drive watchdog (at
  // least four bus timeouts, as the loader demands) that tolerate a busy VM.
  std::string cfg = test::read_file(kSrc + "/hw_configs/modbus_tcp_arm.toml");
  cfg = std::regex_replace(cfg, std::regex("\nport = [0-9]+"), "\nport = " + port);
  cfg = std::regex_replace(cfg, std::regex("\nresponse_timeout_ms = [0-9.]+"), "\nresponse_timeout_ms = 250");
  cfg = std::regex_replace(cfg, std::regex("\ndrive_watchdog_ms = [0-9]+"), "\ndrive_watchdog_ms = 2000");
  std::ofstream(path("arm.toml")) << cfg;

  test::Child rt({kBin + "/firmware_rt/lancet-rt", "--config", path("arm.toml"), "--shm", shm, "--duration", "600", "--no-rt", "-q",
                  "--stats", path("rt.json")},
                 path("rt.log"));
  std::optional<SharedChannel> ch;
  ASSERT_TRUE(test::eventually([&] {
    if (auto opened = SharedChannel::open(shm)) ch.emplace(std::move(opened).value());
    return ch.has_value() || !rt.running();
  }) && ch) << test::read_file(path("rt.log"));
  test::Child viz({kBin + "/host_viz/lancet-viz", "--headless", "--shm", shm, "--duration", "600", "--width", "320", "--height", "200"},
                  path("viz.log"), {"ASAN_OPTIONS=detect_leaks=0"});
  // The scripted hand strokes into the tissue over and over: wait until lancet-rt has the tissue
  // and pushes back on the tool through the drives.
  RtStatus st{};
  const auto pushing = [&] {
    if (ch->state().rt_status.try_read(st) != ReadStatus::kOk || wire::check(st) != nullptr) return false;
    return st.hand[0].patch_version > 0 && st.hand[0].contact != 0 && std::hypot(st.hand[0].force.x, st.hand[0].force.y, st.hand[0].force.z) > 0.2;
  };
  const bool pushed = test::eventually(pushing, 2 * test::kHangTimeout, std::chrono::milliseconds(1));
  rt.signal(SIGTERM);
  const auto rt_code = rt.wait_exit(test::kHangTimeout);
  viz.signal(SIGTERM);
  (void)viz.wait_exit(test::kHangTimeout);
  ch.reset();
  shm_unlink(shm.c_str());
  const std::string rt_log = test::read_file(path("rt.log"));
  ASSERT_TRUE(pushed) << "lancet-rt never pushed on the tool\n" << rt_log << test::read_file(path("viz.log"));
  ASSERT_TRUE(rt_code.has_value() && WIFEXITED(*rt_code) && WEXITSTATUS(*rt_code) == 0) << rt_log;
  EXPECT_NE(rt_log.find("arm 'modbus-bench-3dof' (modbus arm"), std::string::npos) << rt_log;
  EXPECT_EQ(rt_log.find("FAULT"), std::string::npos) << rt_log;
  const std::string stats = test::read_file(path("rt.json"));
  const auto max_force = test::json_number(stats, "max_force_n");
  const auto contact = test::json_number(stats, "contact_ticks");
  const auto ticks = test::json_number(stats, "ticks");
  const auto reads = test::json_number(stats, "reads");
  const auto writes = test::json_number(stats, "writes");
  ASSERT_TRUE(max_force && contact && ticks && reads && writes) << stats;
  EXPECT_GT(*max_force, 0.2) << rt_log;
  EXPECT_GT(*contact, 0) << rt_log;
  // Every tick read and wrote the arm over the bus.
  EXPECT_GT(*ticks, 0) << stats;
  EXPECT_GE(*reads, *ticks) << stats;
  EXPECT_GE(*writes, *ticks) << stats;
  sim.signal(SIGTERM);
  const auto sim_code = sim.wait_exit(test::kHangTimeout);
  EXPECT_TRUE(sim_code.has_value() && WIFEXITED(*sim_code) && WEXITSTATUS(*sim_code) == 0) << test::read_file(path("armsim.log"));
  if (!HasFailure()) std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace lancet
