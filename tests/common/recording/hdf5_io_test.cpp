// A recording through HDF5 and back: every field bit-identical; what a broken file says; h5py
// (another HDF5 reader) sees the same rows and the units.
#include "recording/hdf5_io.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <span>
#include <string>
#include <vector>

#include "../../host_viz/score/synthetic_recording.hpp"
#include "wait.hpp"  // tests/support

namespace lancet::record {
namespace {

std::string temp_path(const char* name) {
  return (std::filesystem::temp_directory_path() / (std::string("lancet_hdf5_") + std::to_string(getpid()) + "_" + name)).string();
}

Recording sample_recording() {
  Recording r = test::make_recording(2500, [](std::size_t i, double t, ToolSample& s) {
    s.tool.position = {0.01 * t, -0.012, -0.003};
    s.force = {0, 0, 0.5 + t};
    s.events = i % 100 == 0 ? event::kCutProgress : 0u;
    s.n_joints = 3;
    s.q[0] = t, s.q[1] = 2 * t, s.q[2] = -t;
    s.n_commands = i == 0 ? 2 : 0;
    s.commands[0] = 0x30, s.commands[1] = 0x11;
    s.state_hash = i % 100 == 99 ? 0x1234567890abcdefull + i : 0;
    s.woke_ns = s.t_ns + 20'000;
  });
  r.scenario_toml = test::incision_toml();
  r.scenario_file = "host_viz/scenarios/x.toml";
  r.tissue = "phantom";
  r.patch_radius = 0.025;
  r.layout_hash = 0xfeedull;
  r.recorded_layout_hash = 0xbeefull;
  r.protocol = 7;
  r.servo_hash_every = 100;
  r.scene_hash_every = 30;
  r.servo_model[0].layout = 42, r.servo_model[0].size = 3, r.servo_model[0].bytes[2] = 9;
  r.first_patches.resize(2);
  r.first_patches[0].n_triangles = 5;
  r.first_patches[0].triangles[4].v[1].y = 0.25f;
  r.first_patches[1].n_triangles = 7;
  r.first_patches[1].triangles[6].v[2].z = -0.5f;
  r.first_patch_versions = {10, 11};
  for (std::uint64_t k = 0; k < 150; ++k) {
    FrameRecord f;
    f.frame = k;
    f.t_ns = test::kT0Ns + static_cast<std::int64_t>(k) * 16'000'000;
    f.last_seq = std::min<std::uint64_t>(2500, (k + 1) * 16);
    f.ticks = f.last_seq - std::min<std::uint64_t>(2500, k * 16);
    f.blood_dt = 0.016;
    f.patch_version = 12 + k;
    f.patch_centre = {0.001 * static_cast<double>(k), 0, 0};
    f.blood_lost_ml = 0.01 * static_cast<double>(k);
    f.damaged = k > 100 ? 1u : 0u;
    f.scene_hash = k % 30 == 0 ? 77 + k : 0;
    r.frames.push_back(f);
  }
  SceneEvent e;
  e.frame = 40, e.t_ns = 123, e.kind = SceneEvent::kBloodSource, e.index = 2, e.position = {0.01, 0.02, 0.03}, e.value = 0.5;
  std::snprintf(e.name, sizeof e.name, "superficial vein");
  r.events.push_back(e);
  e.kind = SceneEvent::kStructureReached, e.index = 0;
  std::snprintf(e.name, sizeof e.name, "radial artery");
  r.events.push_back(e);
  return r;
}

TEST(Hdf5Io, ARecordingReadsBackBitIdentical) {
  const Recording r = sample_recording();
  const std::string path = temp_path("roundtrip.h5");
  ASSERT_TRUE(write_recording(path, r).ok());
  auto back = read_recording(path);
  ASSERT_TRUE(back.ok()) << back.error().message;
  const Recording& b = back.value();
  EXPECT_EQ(b.lancet_version, r.lancet_version);
  EXPECT_EQ(b.scenario_toml, r.scenario_toml);
  EXPECT_EQ(b.scenario_file, r.scenario_file);
  EXPECT_EQ(b.tissue, "phantom");
  EXPECT_EQ(b.patch_radius, 0.025);
  EXPECT_EQ(b.layout_hash, r.layout_hash);
  EXPECT_EQ(b.recorded_layout_hash, r.recorded_layout_hash);
  EXPECT_EQ(b.servo_hash_every, 100u);
  EXPECT_EQ(std::memcmp(&b.servo_model, &r.servo_model, sizeof r.servo_model), 0);
  ASSERT_EQ(b.first_patches.size(), 2u);
  EXPECT_EQ(b.first_patches[0].triangles[4].v[1].y, 0.25f);
  EXPECT_EQ(b.first_patches[1].n_triangles, 7u);
  EXPECT_EQ(b.first_patches[1].triangles[6].v[2].z, -0.5f);
  EXPECT_EQ(b.first_patch_versions, (std::vector<std::uint64_t>{10, 11}));
  EXPECT_FALSE(b.cut_short);
  ASSERT_EQ(b.samples.size(), r.samples.size());
  for (std::size_t i = 0; i < r.samples.size(); ++i) {
    // Every named field (padding aside): compare field by field through the bytes of the members.
    const ToolSample &x = r.samples[i], &y = b.samples[i];
    ASSERT_EQ(x.seq, y.seq);
    ASSERT_EQ(x.t_ns, y.t_ns);
    ASSERT_EQ(x.woke_ns, y.woke_ns);
    ASSERT_EQ(std::memcmp(x.q, y.q, sizeof x.q), 0);
    ASSERT_EQ(x.tool, y.tool);
    ASSERT_EQ(x.force, y.force);
    ASSERT_EQ(x.events, y.events);
    ASSERT_EQ(x.n_commands, y.n_commands);
    ASSERT_EQ(std::memcmp(x.commands, y.commands, sizeof x.commands), 0);
    ASSERT_EQ(x.state_hash, y.state_hash);
  }
  ASSERT_EQ(b.frames.size(), r.frames.size());
  for (std::size_t k = 0; k < r.frames.size(); ++k) {
    ASSERT_EQ(b.frames[k].last_seq, r.frames[k].last_seq);
    ASSERT_EQ(b.frames[k].patch_centre, r.frames[k].patch_centre);
    ASSERT_EQ(b.frames[k].blood_lost_ml, r.frames[k].blood_lost_ml);
    ASSERT_EQ(b.frames[k].scene_hash, r.frames[k].scene_hash);
  }
  ASSERT_EQ(b.events.size(), 2u);
  EXPECT_EQ(b.events[0].kind, SceneEvent::kBloodSource);
  EXPECT_EQ(b.events[0].position, (Vec3{0.01, 0.02, 0.03}));
  EXPECT_STREQ(b.events[0].name, "superficial vein");
  EXPECT_STREQ(b.events[1].name, "radial artery");
  EXPECT_EQ(b.samples_lost, 0u);
  std::filesystem::remove(path);
}

TEST(Hdf5Io, GapsInTheTicksAreCountedNotHidden) {
  Recording r = sample_recording();
  r.samples.erase(r.samples.begin() + 1000, r.samples.begin() + 1010);  // 10 ticks lost, one gap
  const std::string path = temp_path("gaps.h5");
  ASSERT_TRUE(write_recording(path, r).ok());
  auto back = read_recording(path);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back.value().samples_lost, 10u);
  EXPECT_EQ(back.value().gaps, 1u);
  std::filesystem::remove(path);
}

TEST(Hdf5Io, ABrokenFileGetsAClearError) {
  const std::string path = temp_path("broken.h5");
  ASSERT_TRUE(write_recording(path, sample_recording()).ok());
  const auto size = std::filesystem::file_size(path);
  // Truncated to half.
  const std::string cut = temp_path("cut.h5");
  std::filesystem::copy_file(path, cut, std::filesystem::copy_options::overwrite_existing);
  std::filesystem::resize_file(cut, size / 2);
  auto r = read_recording(cut);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find(cut), std::string::npos) << r.error().message;
  // Its superblock overwritten.
  const std::string garbage = temp_path("garbage.h5");
  std::filesystem::copy_file(path, garbage, std::filesystem::copy_options::overwrite_existing);
  {
    std::fstream f(garbage, std::ios::in | std::ios::out | std::ios::binary);
    const std::string junk(64, 'x');
    f.write(junk.data(), static_cast<std::streamsize>(junk.size()));
  }
  r = read_recording(garbage);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("not an HDF5 file"), std::string::npos) << r.error().message;
  // Not there at all.
  r = read_recording(temp_path("absent.h5"));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  for (const auto& p : {path, cut, garbage}) std::filesystem::remove(p);
}

// A recorder that never finished (lancet-viz killed, the power lost) leaves a file that reads up
// to its last flush, marked cut short. A child records, waits until its rows are flushed to the
// file, and is killed (SIGKILL: no finish(), no destructor, the file still marked open for writing
// by its SWMR writer) while it goes on recording; the parent reads what is there.
TEST(Hdf5Io, ARecordingCutShortReadsUpToItsLastFlush) {
  const std::string unfinished = temp_path("unfinished.h5");
  const Recording whole = sample_recording();
  int ready[2];
  ASSERT_EQ(::pipe(ready), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(ready[0]);
    auto rec = Recorder::create(unfinished, whole);
    if (!rec.ok()) ::_exit(2);
    for (std::size_t k = 0; k < 8; ++k) rec.value()->add_frame(whole.frames[k]);  // last_seq 16 .. 128
    rec.value()->add_event(whole.events[0]);
    rec.value()->add_samples(std::span<const ToolSample>(whole.samples).first(100));
    if (!lancet::test::eventually([&] { return rec.value()->samples_flushed() == 100; })) ::_exit(3);
    (void)!::write(ready[1], "f", 1);
    // Recording on, as a viz would, until it is killed.
    for (std::size_t i = 100;; ++i) {
      if (i < whole.samples.size()) rec.value()->add_samples(std::span<const ToolSample>(whole.samples).subspan(i, 1));
      ::usleep(100);
    }
  }
  ::close(ready[1]);
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1) << "the recording child failed before its first flush";
  ::close(ready[0]);
  ::kill(child, SIGKILL);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the recording child ended by itself, status " << status;
  auto r = read_recording(unfinished);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Recording& b = r.value();
  EXPECT_TRUE(b.cut_short);
  // Frames that applied ticks the file does not hold are dropped, and ticks no frame applied: the
  // first six frames (16 ticks each) came with the first 100 ticks, so 96 ticks at least.
  ASSERT_GE(b.frames.size(), 6u) << "frames up to tick 96 were flushed with the first 100 ticks";
  std::uint64_t applied = 0;
  for (const FrameRecord& f : b.frames) applied += f.ticks;
  EXPECT_EQ(b.samples.size(), applied);
  ASSERT_GE(b.samples.size(), 96u) << "rows flushed before the kill are missing";
  for (std::size_t i = 0; i < b.samples.size(); ++i) ASSERT_EQ(b.samples[i].seq, whole.samples[i].seq);
  EXPECT_LE(b.frames.back().last_seq, b.samples.back().seq);
  EXPECT_EQ(b.first_patches.size(), 2u);
  std::filesystem::remove(unfinished);
}

// h5py, an independent reader (the one users have), reads the rows by name with their units.
TEST(Hdf5Io, H5pyReadsTheSamplesByName) {
  if (std::system("/usr/bin/python3 -c 'import h5py' 2>/dev/null") != 0) {
    if (const char* ci = std::getenv("CI"); ci != nullptr && std::string(ci) == "true") FAIL() << "python3-h5py is not installed (CI)";
    GTEST_SKIP() << "python3-h5py is not installed (scripts/setup.sh installs it)";
  }
  const std::string path = temp_path("h5py.h5");
  ASSERT_TRUE(write_recording(path, sample_recording()).ok());
  const std::string out = temp_path("h5py.txt");
  const std::string cmd = "/usr/bin/python3 -c \"import h5py; f = h5py.File('" + path +
                          "', 'r'); s = f['/servo/samples']; print(len(s), s['force'][100][2], s['tool_position'][2000][0], "
                          "'force: N' in s.attrs['units'].decode() if isinstance(s.attrs['units'], bytes) else 'force: N' in "
                          "s.attrs['units'], f.attrs['scenario_name'].decode() if isinstance(f.attrs['scenario_name'], bytes) else "
                          "f.attrs['scenario_name'])\" > " + out;
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  std::ifstream in(out);
  std::size_t n = 0;
  double fz = 0, x = 0;
  std::string units_ok, name;
  in >> n >> fz >> x >> units_ok >> name;
  EXPECT_EQ(n, 2500u);
  EXPECT_DOUBLE_EQ(fz, 0.5 + 0.1);
  EXPECT_DOUBLE_EQ(x, 0.01 * 2.0);
  EXPECT_EQ(units_ok, "True");
  EXPECT_EQ(name, "synthetic");
  std::filesystem::remove(path);
  std::filesystem::remove(out);
}

}  // namespace
}  // namespace lancet::record
