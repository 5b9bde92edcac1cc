// lancet-rt on an emulated Novint Falcon, end to end with the real programs: this test process
// holds the umockdev testbed and the emulated Falcon (falcon_emulator.hpp); lancet-rt, started
// from here, inherits umockdev's preload and reaches the Falcon's node through it; lancet-viz
// (headless) publishes the phantom tissue; lancetctl re-arms. The emulated hand first takes the
// grip through the home switches, then follows lancet-rt's scripted hand (device::scripted_target:
// down into the tissue, a hold, then strokes).
//   - lancet-rt uploads the firmware, homes, and renders the tissue: while the hand holds still in
//     the tissue, the force the emulated mechanism gets (J⁻ᵀ τ at the pose lancet-rt read) is the
//     force lancet-rt says it commands;
//   - a burst of dropped replies and one of malformed replies each fault the arm with its cause
//     named, the Falcon gets zero torque, and `lancetctl rearm` brings the forces back;
//   - an unplug faults it (disconnected); plugged back at another address, lancet-rt reconnects by
//     itself (uploading the firmware again: the Falcon lost it with its power), and after homing
//     again `lancetctl rearm` brings the forces back.
// Nothing depends on the machine's speed: the exchange timeout (100 ms) is far above what a busy
// machine does to umockdev's thread, and every wait is for an event (a value in lancet-rt's status
// or the emulator's state) with a deadline that only catches hangs.

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <fstream>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "arm/arm_config.hpp"
#include "device/sim_stylus.hpp"
#include "falcon_emulator.hpp"
#include "lancet/shared_model/shared_state.hpp"
#include "lancet/shared_model/validate.hpp"
#include "process_test.hpp"
#include "usb_testbed.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using namespace std::chrono_literals;
using device::ArmPhysics;
using test::FalconEmulator;
using test::FalconSnapshot;

const std::string kBin = std::string(LANCET_BINARY_DIR);
const std::string kSrc = std::string(LANCET_SOURCE_DIR);
constexpr const char* kSysPath = "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-1";
constexpr Vec3 kStroke{0, -0.03, 0};  // where the home switches are passed: 30 mm towards the user

// Thigh angles at a device-frame point (the model's closed-form inverse).
std::array<double, 3> angles_at(const arm::Kinematics& k, Vec3 p) {
  const auto q = k.delta()->inverse(p);
  EXPECT_TRUE(q.has_value());
  return q.value_or(std::array<double, 3>{});
}

class FalconRt : public test::ProcessTest {
 protected:
  FalconRt() : ProcessTest("falcon") {}

  void SetUp() override {
    ProcessTest::SetUp();
    if (!test::in_umockdev()) GTEST_SKIP() << test::not_in_umockdev_reason();
    std::vector<std::uint8_t> fw(600);
    for (std::size_t i = 0; i < fw.size(); ++i) fw[i] = static_cast<std::uint8_t>(i * 37 + 11);
    std::ofstream(path("falcon.bin"), std::ios::binary).write(reinterpret_cast<const char*>(fw.data()), static_cast<std::streamsize>(fw.size()));
    // The shipped config with this firmware file and a timeout a busy machine never reaches.
    std::string cfg = test::read_file(kSrc + "/hw_configs/novint_falcon.toml");
    cfg = std::regex_replace(cfg, std::regex("\nfirmware = \"[^\"]*\""), "\nfirmware = \"" + path("falcon.bin") + "\"");
    cfg = std::regex_replace(cfg, std::regex("\ntimeout_ms = [0-9.]+"), "\ntimeout_ms = 100");
    cfg = std::regex_replace(cfg, std::regex("\nhoming_timeout_s = [0-9.]+"), "\nhoming_timeout_s = 120");
    std::ofstream(path("falcon.toml")) << cfg;
    auto c = arm::load_arm_config(path("falcon.toml"));
    ASSERT_TRUE(c.ok()) << c.error().message;
    config_ = std::move(c).value();
    auto k = arm::make_kinematics(config_);
    ASSERT_TRUE(k.ok());
    test::FalconEmulatorOptions o;
    o.firmware = fw;
    o.start_q = angles_at(k.value(), {0, 0, 0});
    const auto stroke = angles_at(k.value(), kStroke);
    for (std::size_t m = 0; m < 3; ++m) o.home_angles[m] = 0.5 * (o.start_q[m] + stroke[m]);
    emu_ = std::make_unique<FalconEmulator>(config_, o);
    bed_ = std::make_unique<test::UsbTestbed>(*emu_, kSrc + "/tests/firmware_rt/device/data/novint_falcon.umockdev", kSysPath);
    ASSERT_TRUE(bed_->plug(2));
    hand_ = std::thread([this] { run_hand(); });
  }
  void TearDown() override {
    stop_ = true;
    if (hand_.joinable()) hand_.join();
    bed_.reset();
    emu_.reset();
    ProcessTest::TearDown();
  }

  // The emulated hand: through the home switches while the Falcon is not homed, then the script.
  void run_hand() {
    const auto t0 = std::chrono::steady_clock::now();
    auto script_t0 = t0;
    bool was_homed = false;
    while (!stop_) {
      const FalconSnapshot s = emu_->snapshot();
      const auto now = std::chrono::steady_clock::now();
      const bool homed = s.homed == 0x7;
      if (homed && !was_homed) script_t0 = now;
      was_homed = homed;
      Vec3 target{};
      if (!homed) {
        const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now - t0).count();
        target = (ms / 600) % 2 == 0 ? kStroke : Vec3{};
      } else {
        const double t = std::chrono::duration<double>(now - script_t0).count();
        target = hold_ ? device::scripted_target(std::min(t, 1.0), 0.004) : device::scripted_target(t, 0.004);
      }
      emu_->with_physics([&](ArmPhysics& p) { p.set_hand_target(target); });
      std::this_thread::sleep_for(2ms);
    }
  }

  std::optional<RtStatus> status() {
    RtStatus st{};
    if (!ch_ || ch_->state().rt_status.try_read(st) != ReadStatus::kOk || wire::check(st) != nullptr) return std::nullopt;
    return st;
  }
  bool pushing() {
    const auto st = status();
    return st && st->hand[0].device_state == DeviceLifecycle::kActive && st->hand[0].contact != 0 &&
           norm(st->hand[0].force) > 0.2 && norm(emu_->snapshot().meant) > 0.2;
  }
  /// Waits for the fault, then checks its cause, its words and the Falcon's zero torque.
  void expect_fault(IoStatus cause, const std::string& words) {
    std::optional<RtStatus> st;
    ASSERT_TRUE(test::eventually([&] {
      st = status();
      return st && st->hand[0].device_state == DeviceLifecycle::kFault;
    })) << test::read_file(path("rt.log"));
    EXPECT_EQ(st->hand[0].device_fault_cause, cause);
    EXPECT_NE(std::string(st->hand[0].fault_text).find(words), std::string::npos) << st->hand[0].fault_text;
    EXPECT_TRUE(test::eventually([&] { return emu_->snapshot().motor == std::array<std::int16_t, 3>{0, 0, 0}; }))
        << "the Falcon still gets torque after the fault";
  }
  void rearm() {
    test::Child ctl({kBin + "/firmware_rt/lancetctl", "rearm", "--rt", shm_, "--yes", "--timeout", "60"}, path("rearm.log"));
    const auto code = ctl.wait_exit(2 * test::kHangTimeout + 60s);
    ASSERT_TRUE(code && WIFEXITED(*code) && WEXITSTATUS(*code) == 0) << test::read_file(path("rearm.log")) << test::read_file(path("rt.log"));
  }

  arm::ArmConfig config_;
  std::unique_ptr<FalconEmulator> emu_;
  std::unique_ptr<test::UsbTestbed> bed_;
  std::optional<SharedChannel> ch_;
  std::thread hand_;
  std::atomic<bool> stop_{false}, hold_{true};
};

TEST_F(FalconRt, LancetRtDrivesTheEmulatedFalconAndSurvivesDroppedMalformedAndUnpluggedLinks) {
  test::Child rt({kBin + "/firmware_rt/lancet-rt", "--config", path("falcon.toml"), "--hands", "1", "--shm", shm_, "--duration", "600",
                  "--no-rt", "-q", "--stats", path("rt.json")},
                 path("rt.log"));
  ASSERT_TRUE(test::eventually([&] {
    if (auto opened = SharedChannel::open(shm_)) ch_.emplace(std::move(opened).value());
    return ch_.has_value() || !rt.running();
  }, 2 * test::kHangTimeout) && ch_) << test::read_file(path("rt.log"));
  test::Child viz({kBin + "/host_viz/lancet-viz", "--headless", "--shm", shm_, "--duration", "600", "--width", "320", "--height", "200"},
                  path("viz.log"), {"ASAN_OPTIONS=detect_leaks=0"});
  const auto run_start = std::chrono::steady_clock::now();

  // Up, homed, and pushing back on the hand held still in the tissue.
  ASSERT_TRUE(test::eventually([&] { return pushing(); }, 4 * test::kHangTimeout, 1ms))
      << test::read_file(path("rt.log")) << test::read_file(path("viz.log"));
  const FalconSnapshot up = emu_->snapshot();
  EXPECT_EQ(up.uploads_completed, 1u);
  EXPECT_EQ(up.unexpected_requests, 0u);
  // The force the mechanism is given is the force lancet-rt commands: medians over a hold.
  std::vector<double> rt_f[3], emu_f[3];
  for (int i = 0; i < 300; ++i) {
    if (const auto st = status()) {
      rt_f[0].push_back(st->hand[0].force.x), rt_f[1].push_back(st->hand[0].force.y), rt_f[2].push_back(st->hand[0].force.z);
    }
    const Vec3 m = emu_->snapshot().meant;
    emu_f[0].push_back(m.x), emu_f[1].push_back(m.y), emu_f[2].push_back(m.z);
    std::this_thread::sleep_for(3ms);
  }
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  ASSERT_FALSE(rt_f[2].empty());
  const Vec3 rt_force{median(rt_f[0]), median(rt_f[1]), median(rt_f[2])};
  const Vec3 emu_force{median(emu_f[0]), median(emu_f[1]), median(emu_f[2])};
  EXPECT_GT(norm(rt_force), 0.2);
  EXPECT_LT(norm(rt_force - emu_force), 0.05 + 0.05 * norm(rt_force))
      << "lancet-rt " << rt_force.x << " " << rt_force.y << " " << rt_force.z << ", the Falcon " << emu_force.x << " " << emu_force.y
      << " " << emu_force.z;
  hold_ = false;  // strokes from now on

  // Dropped replies: timeouts, the fault, zero torque; re-armed, the forces return.
  emu_->drop_replies(8);
  expect_fault(IoStatus::kTimeout, "no reply");
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_TRUE(test::eventually([&] { return emu_->snapshot().drops_left == 0; })) << "the burst is over";
  rearm();
  ASSERT_TRUE(test::eventually([&] { return pushing(); }, 2 * test::kHangTimeout, 1ms)) << test::read_file(path("rt.log"));

  // Malformed replies: the same, with their own cause.
  emu_->corrupt_replies(8);
  expect_fault(IoStatus::kProtocolError, "malformed");
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_TRUE(test::eventually([&] { return emu_->snapshot().corruptions_left == 0; })) << "the burst is over";
  rearm();
  ASSERT_TRUE(test::eventually([&] { return pushing(); }, 2 * test::kHangTimeout, 1ms)) << test::read_file(path("rt.log"));

  // Unplugged: disconnected; plugged back elsewhere, lancet-rt reconnects by itself.
  bed_->unplug();
  emu_->power_cycle();
  expect_fault(IoStatus::kDisconnected, "gone");
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_TRUE(bed_->plug(3));
  ASSERT_TRUE(test::eventually([&] {
    const auto st = status();
    return st && st->hand[0].link_lost == 0 && st->hand[0].bus.reconnects >= 1;
  }, 2 * test::kHangTimeout)) << test::read_file(path("rt.log"));
  EXPECT_EQ(emu_->snapshot().uploads_completed, 2u);  // the firmware again
  rearm();  // waits for the hand to home it again
  ASSERT_TRUE(test::eventually([&] { return pushing(); }, 2 * test::kHangTimeout, 1ms)) << test::read_file(path("rt.log"));

  // At least 10 s on the Falcon, then a clean exit.
  while (std::chrono::steady_clock::now() - run_start < 10s) std::this_thread::sleep_for(50ms);
  rt.signal(SIGTERM);
  const auto code = rt.wait_exit(test::kHangTimeout);
  viz.signal(SIGTERM);
  (void)viz.wait_exit(test::kHangTimeout);
  ch_.reset();
  const std::string log = test::read_file(path("rt.log"));
  ASSERT_TRUE(code && WIFEXITED(*code) && WEXITSTATUS(*code) == 0) << log;
  EXPECT_NE(log.find("novint-falcon"), std::string::npos) << log;
  const std::string stats = test::read_file(path("rt.json"));
  const auto max_force = test::json_number(stats, "max_force_n");
  ASSERT_TRUE(max_force) << stats;
  EXPECT_LE(*max_force, config_.safety.max_force + 1e-9);
  EXPECT_EQ(emu_->snapshot().unexpected_requests, 0u);
}

}  // namespace
}  // namespace lancet
