// lancet-rt driving an arm over a real bus: lancet-armsim serves the Modbus TCP arm of
// hw_configs/modbus_tcp_arm.toml (its hand scripted into the tissue), lancet-rt runs that config,
// lancet-viz (headless) publishes the tissue. The arm is read and written over libmodbus every
// tick and the servo renders forces on it.

#include <gtest/gtest.h>
#include <sys/mman.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>

#include "lancet/shared_model/shared_state.hpp"
#include "process.hpp"

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
                   "--duration", "20"},
                  path("armsim.log"));
  std::string port;
  for (int i = 0; i < 300 && port.empty(); ++i) {
    std::smatch m;
    const std::string log = test::read_file(path("armsim.log"));
    if (std::regex_search(log, m, std::regex("127\\.0\\.0\\.1:([0-9]+)"))) port = m[1].str();
    std::this_thread::sleep_for(10ms);
  }
  ASSERT_FALSE(port.empty()) << test::read_file(path("armsim.log"));
  // The shipped config, pointed at this armsim's port, with a timeout that tolerates a busy VM.
  std::string cfg = test::read_file(kSrc + "/hw_configs/modbus_tcp_arm.toml");
  cfg = std::regex_replace(cfg, std::regex("\nport = [0-9]+"), "\nport = " + port);
  cfg = std::regex_replace(cfg, std::regex("\nresponse_timeout_ms = [0-9.]+"), "\nresponse_timeout_ms = 5");
  std::ofstream(path("arm.toml")) << cfg;

  test::Child rt({kBin + "/firmware_rt/lancet-rt", "--config", path("arm.toml"), "--shm", shm, "--duration", "4", "--no-rt", "-q",
                  "--stats", path("rt.json")},
                 path("rt.log"));
  for (int i = 0; i < 500 && !SharedChannel::open(shm); ++i) std::this_thread::sleep_for(10ms);
  test::Child viz({kBin + "/host_viz/lancet-viz", "--headless", "--shm", shm, "--duration", "3.5", "--width", "320", "--height", "200"},
                  path("viz.log"), {"ASAN_OPTIONS=detect_leaks=0"});
  const auto rt_code = rt.wait_exit(30s);
  (void)viz.wait_exit(30s);
  shm_unlink(shm.c_str());
  const std::string rt_log = test::read_file(path("rt.log"));
  ASSERT_TRUE(rt_code.has_value() && WIFEXITED(*rt_code) && WEXITSTATUS(*rt_code) == 0) << rt_log;
  EXPECT_NE(rt_log.find("arm 'modbus-bench-3dof' (modbus arm"), std::string::npos) << rt_log;
  const std::string stats = test::read_file(path("rt.json"));
  const auto max_force = test::json_number(stats, "max_force_n");
  const auto contact = test::json_number(stats, "contact_ticks");
  ASSERT_TRUE(max_force && contact) << stats;
  EXPECT_GT(*max_force, 0.2) << rt_log;
  EXPECT_GT(*contact, 10) << rt_log;
  // Every tick read the arm over the bus.
  std::smatch m;
  ASSERT_TRUE(std::regex_search(rt_log, m, std::regex("([0-9]+) reads, ([0-9]+) writes"))) << rt_log;
  EXPECT_GT(std::stoi(m[1].str()), 2000) << rt_log;
  sim.signal(SIGTERM);
  const auto sim_code = sim.wait_exit(10s);
  EXPECT_TRUE(sim_code.has_value() && WIFEXITED(*sim_code) && WEXITSTATUS(*sim_code) == 0) << test::read_file(path("armsim.log"));
  if (!HasFailure()) std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace lancet
