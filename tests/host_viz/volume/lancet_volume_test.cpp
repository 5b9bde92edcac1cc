// lancet-volume end to end, as a user runs it: broken DICOM folders (made from real GE slices)
// end with a message naming the file and the CLI's own flags and exit status 2, never an abort;
// skipped files and gaps are printed as warnings; NaN voxels are counted by info and refused by
// mesh unless --nan-as; the JSON is valid (checked by Python's json module, NaN refused); PLY and
// OBJ state their unit (mm by default); values are labelled HU only for CT.

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "shared_data.hpp"
#include "temp_files.hpp"

namespace {

namespace fs = std::filesystem;
const std::string kTool = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-volume";

struct CliRun {
  int code = -1;        // exit status; -1 when it did not exit normally (a signal, a hang)
  std::string output;   // stdout and stderr together
  [[nodiscard]] bool has(const std::string& s) const { return output.find(s) != std::string::npos; }
  // The one line of JSON mesh prints.
  [[nodiscard]] std::string json() const {
    std::istringstream in(output);
    for (std::string line; std::getline(in, line);) {
      if (!line.empty() && line.front() == '{') return line;
    }
    return {};
  }
};

std::string ge_name(int i) { return (i < 10 ? "0" : "") + std::to_string(i) + ".dcm"; }

std::string read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class LancetVolume : public lancet::test::TempDirTest {
 protected:
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  CliRun run(const std::vector<std::string>& args) {
    std::vector<std::string> argv = {kTool};
    argv.insert(argv.end(), args.begin(), args.end());
    const std::string log = path("log.txt");
    lancet::test::Child child(argv, log);
    const auto status = child.wait_exit(std::chrono::seconds(60));
    CliRun r;
    r.output = lancet::test::read_file(log);
    if (status && WIFEXITED(*status)) r.code = WEXITSTATUS(*status);
    if (status && WIFSIGNALED(*status)) r.output += "\n[killed by signal " + std::to_string(WTERMSIG(*status)) + "]";
    return r;
  }

  // GE slices first..last (uniform 4.22 mm sub-series, tilted) in dir_/name; "" without the data.
  std::string ge_folder(const std::string& name, int first, int last) {
    const std::string volumes = lancet::test::shared_volumes_dir();
    if (volumes.empty()) return {};
    const fs::path d = dir_ / name;
    fs::create_directories(d);
    for (int i = first; i <= last; ++i) {
      fs::copy_file(volumes + "/head_ct_dicom_ge/" + ge_name(i), d / ge_name(i));
      fs::permissions(d / ge_name(i), fs::perms::owner_write, fs::perm_options::add);
    }
    return d.string();
  }

  // Python's json module accepts the text, with NaN and Infinity refused.
  static bool valid_json(const std::string& text, std::string& why) {
    const std::string file = ::testing::TempDir() + "lancet_volume_json_" + std::to_string(::getpid()) + ".json";
    std::ofstream(file) << text;
    const std::string log = file + ".log";
    lancet::test::Child py({"/usr/bin/python3", "-c",
                            "import json,sys\n"
                            "def bad(c): raise ValueError('not JSON: ' + c)\n"
                            "json.loads(open(sys.argv[1]).read(), parse_constant=bad)\n",
                            file},
                           log);
    const auto st = py.wait_exit(std::chrono::seconds(30));
    why = lancet::test::read_file(log);
    std::remove(file.c_str());
    std::remove(log.c_str());
    return st && WIFEXITED(*st) && WEXITSTATUS(*st) == 0;
  }

  // A 10³ float ball (value 100 inside radius 3.5, 0 outside), with NaN and inf voxels on its
  // surface when `holes`; as .mha (MetaImage) or .nrrd.
  std::string float_ball(const std::string& name, bool holes) {
    std::vector<float> v(1000);
    for (int k = 0; k < 10; ++k)
      for (int j = 0; j < 10; ++j)
        for (int i = 0; i < 10; ++i) v[static_cast<std::size_t>(i + 10 * (j + 10 * k))] = std::hypot(i - 4.5, j - 4.5, k - 4.5) < 3.5 ? 100.0f : 0.0f;
    if (holes) {
      v[4 + 10 * (4 + 10 * 1)] = std::numeric_limits<float>::quiet_NaN();
      v[4 + 10 * (4 + 10 * 8)] = std::numeric_limits<float>::quiet_NaN();
      v[1 + 10 * (4 + 10 * 4)] = std::numeric_limits<float>::infinity();
    }
    const std::string data = lancet::test::bytes_of(v, false);
    if (name.ends_with(".nrrd")) {
      return write(name, "NRRD0004\ntype: float\ndimension: 3\nsizes: 10 10 10\nendian: little\nencoding: raw\n"
                         "space: LPS\nspace directions: (2,0,0) (0,2,0) (0,0,2)\n\n" + data);
    }
    return write(name, "ObjectType = Image\nNDims = 3\nDimSize = 10 10 10\nElementType = MET_FLOAT\nElementSpacing = 2 2 2\n"
                       "ElementDataFile = LOCAL\n" + data);
  }
};

// ---- broken DICOM folders ---------------------------------------------------------------------

TEST_F(LancetVolume, TruncatedSliceEndsWithAMessageNotAnAbort) {
  const std::string d = ge_folder("truncated", 6, 8);
  if (d.empty()) return;
  const std::string full = read_all(fs::path(d) / "07.dcm");
  for (const std::size_t cut : {std::size_t{1000}, full.size() / 2}) {  // inside the header (GDCM used to abort), inside the pixels
    write("truncated/07.dcm", full.substr(0, cut));
    const CliRun r = run({"info", d, "--shear-tilted"});
    EXPECT_EQ(r.code, 2) << cut << ": " << r.output;
    EXPECT_FALSE(r.has("Assertion")) << r.output;
    EXPECT_TRUE(r.has("07.dcm")) << r.output;
  }
  const CliRun r = run({"info", d, "--shear-tilted"});
  EXPECT_TRUE(r.has(d + "/07.dcm: byte 1928: PixelData (7FE0,0010): the file is cut short")) << r.output;
}

TEST_F(LancetVolume, SliceCutTo300BytesIsAWarningAndAGapNamingTheFlags) {
  const std::string d = ge_folder("cut300", 5, 9);
  if (d.empty()) return;
  write("cut300/07.dcm", read_all(fs::path(d) / "07.dcm").substr(0, 300));
  CliRun r = run({"info", d, "--shear-tilted"});
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_TRUE(r.has("gap of 8.00 mm along the slice normal between 06.dcm and 08.dcm")) << r.output;
  EXPECT_TRUE(r.has("use --resample-uneven with --allow-gaps")) << r.output;
  EXPECT_FALSE(r.has("DicomOptions")) << r.output;
  r = run({"info", d, "--shear-tilted", "--resample-uneven"});
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_TRUE(r.has("refusing to interpolate across it (use --allow-gaps to allow)")) << r.output;
  r = run({"info", d, "--shear-tilted", "--resample-uneven", "--allow-gaps"});
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(r.has("lancet-volume: warning: " + d + "/07.dcm: skipped, not part of the series: unreadable")) << r.output;
  EXPECT_TRUE(r.has("lancet-volume: warning: " + d + ": gap of 8.00 mm")) << r.output;
  EXPECT_TRUE(r.has("dims:       512 x 512 x 5")) << r.output;
}

TEST_F(LancetVolume, JunkDcmIsAWarning) {
  const std::string d = ge_folder("junk", 6, 8);
  if (d.empty()) return;
  write("junk/zz.dcm", std::string(3000, 'j'));
  const CliRun r = run({"info", d, "--shear-tilted"});
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(r.has("lancet-volume: warning: " + d + "/zz.dcm: skipped, not part of the series: not a DICOM file")) << r.output;
  EXPECT_TRUE(r.has("values in HU (modality CT)")) << r.output;
}

TEST_F(LancetVolume, MissingSliceIsAGapNamingItsNeighbours) {
  const std::string d = ge_folder("missing", 4, 10);
  if (d.empty()) return;
  fs::remove(fs::path(d) / "07.dcm");
  const CliRun r = run({"mesh", d, "--shear-tilted", "--resample-uneven", "--iso", "300", "-o", path("x.ply")});
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_TRUE(r.has("gap of 8.00 mm along the slice normal between 06.dcm and 08.dcm, where the slices around it are 4.00 mm apart"))
      << r.output;
  EXPECT_TRUE(r.has("--allow-gaps")) << r.output;
  EXPECT_FALSE(fs::exists(path("x.ply")));
}

TEST_F(LancetVolume, TiltAndUnevenSpacingNameTheCliFlags) {
  const std::string d = ge_folder("tilt", 6, 8);
  if (d.empty()) return;
  const CliRun r = run({"info", d});
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_TRUE(r.has("gantry tilt of 18.5 degrees")) << r.output;
  EXPECT_TRUE(r.has("use --shear-tilted")) << r.output;
  EXPECT_FALSE(r.has("DicomOptions")) << r.output;
}

TEST_F(LancetVolume, MrSliceIsNotLabelledHu) {
  const std::string d = ge_folder("mr", 7, 7);
  if (d.empty()) return;
  std::string b = read_all(fs::path(d) / "07.dcm");
  const std::size_t at = b.find(std::string("\x08\x00\x60\x00" "CS\x02\x00" "CT", 10));
  ASSERT_NE(at, std::string::npos);
  b.replace(at + 8, 2, "MR");
  write("mr/07.dcm", b);
  const CliRun r = run({"info", d});
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(r.has("values as stored, not HU (modality MR)")) << r.output;
  EXPECT_TRUE(r.has("histogram (value):")) << r.output;
  EXPECT_FALSE(r.has("HU)")) << r.output;
}

TEST_F(LancetVolume, MissingSourcesSayNotFound) {
  for (const std::string p : {"/nonexistent/lancet/head.mha", "/nonexistent/lancet/dicom_folder", "/nonexistent/lancet/x.raw"}) {
    const CliRun r = run({"info", p, "--dims", "2", "2", "2"});
    EXPECT_EQ(r.code, 2) << r.output;
    EXPECT_TRUE(r.has("lancet-volume: " + p + ": not found")) << r.output;
  }
  const CliRun r = run({"mesh", path("nope.nrrd"), "--iso", "1", "-o", path("x.obj")});
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(r.has(path("nope.nrrd") + ": not found")) << r.output;
}

// ---- NaN voxels, JSON, units --------------------------------------------------------------------

TEST_F(LancetVolume, NanVoxelsAreCountedRefusedOrReplaced) {
  for (const std::string name : {"nan.mha", "nan.nrrd"}) {
    const std::string f = float_ball(name, true);
    CliRun r = run({"info", f});
    EXPECT_EQ(r.code, 0) << r.output;
    EXPECT_TRUE(r.has("non-finite: 2 NaN, 1 infinite voxels (first at voxel (4, 4, 1))")) << r.output;
    EXPECT_TRUE(r.has("values:     min 0, max 100")) << r.output;
    // The value and histogram lines hold numbers only, all finite.
    std::istringstream lines(r.output);
    for (std::string line; std::getline(lines, line);) {
      if (line.rfind("values:", 0) != 0 && line.rfind("  [", 0) != 0) continue;
      EXPECT_EQ(line.find("nan"), std::string::npos) << line;
      EXPECT_EQ(line.find("inf"), std::string::npos) << line;
    }
    EXPECT_TRUE(r.has("values as stored, not HU (modality not given)")) << r.output;

    fs::remove(path("ball.ply"));
    r = run({"mesh", f, "--iso", "50", "--pad", "-o", path("ball.ply")});
    EXPECT_EQ(r.code, 2) << r.output;
    EXPECT_TRUE(r.has("2 NaN and 1 infinite voxels")) << r.output;
    EXPECT_TRUE(r.has("--nan-as VALUE")) << r.output;
    EXPECT_FALSE(fs::exists(path("ball.ply")));

    r = run({"mesh", f, "--iso", "50", "--pad", "--nan-as", "0", "-o", path("ball.ply"), "--require-closed"});
    EXPECT_EQ(r.code, 0) << r.output;
    const std::string json = r.json();
    std::string why;
    EXPECT_TRUE(valid_json(json, why)) << json << "\n" << why;
    EXPECT_NE(json.find("\"closed\": true"), std::string::npos) << json;
    EXPECT_NE(json.find("\"iso_unit\": \"value\""), std::string::npos) << json;
    const auto area = lancet::test::json_number(json, "area_mm2");
    ASSERT_TRUE(area.has_value()) << json;
    EXPECT_GT(*area, 100.0) << "a ball of radius ~7 mm";
    EXPECT_LT(*area, 1000.0);
  }
  EXPECT_EQ(run({"mesh", float_ball("n.mha", true), "--iso", "50", "--nan-as", "nan", "-o", path("x.ply")}).code, 2);
}

// A source path with a quote, a backslash and a tab still gives valid JSON.
TEST_F(LancetVolume, JsonEscapesStrings) {
  const std::string f = float_ball("we\"ird\\name\t.mha", false);
  const CliRun r = run({"mesh", f, "--iso", "50", "--pad", "-o", path("o.obj")});
  ASSERT_EQ(r.code, 0) << r.output;
  std::string why;
  EXPECT_TRUE(valid_json(r.json(), why)) << r.json() << "\n" << why;
}

// PLY and OBJ in millimetres by default, with the unit in the file; --units m gives metres.
TEST_F(LancetVolume, MeshFilesStateTheirUnit) {
  const std::string f = float_ball("ball.mha", false);
  ASSERT_EQ(run({"mesh", f, "--iso", "50", "--pad", "-o", path("mm.ply")}).code, 0);
  ASSERT_EQ(run({"mesh", f, "--iso", "50", "--pad", "-o", path("m.ply"), "--units", "m"}).code, 0);
  const CliRun obj = run({"mesh", f, "--iso", "50", "--pad", "-o", path("mm.obj")});
  ASSERT_EQ(obj.code, 0) << obj.output;
  ASSERT_EQ(run({"mesh", f, "--iso", "50", "--pad", "-o", path("m.obj"), "--units", "m"}).code, 0);
  EXPECT_NE(obj.json().find("\"units\": \"mm\""), std::string::npos) << obj.output;
  EXPECT_NE(read_all(path("mm.ply")).find("\ncomment units mm\n"), std::string::npos);
  EXPECT_NE(read_all(path("m.ply")).find("\ncomment units m\n"), std::string::npos);
  const std::string mm = read_all(path("mm.obj")), m = read_all(path("m.obj"));
  EXPECT_NE(mm.find("# units: mm\n"), std::string::npos);
  EXPECT_NE(m.find("# units: m\n"), std::string::npos);
  // The ball (radius ~7 mm, 2 mm voxels centred at 9 mm): the largest |coordinate| in mm is
  // ~16, in metres ~0.016.
  const auto max_coordinate = [](const std::string& obj_text) {
    std::istringstream in(obj_text);
    double largest = 0;
    for (std::string line; std::getline(in, line);) {
      if (line.rfind("v ", 0) != 0) continue;
      std::istringstream l(line.substr(2));
      for (double x; l >> x;) largest = std::max(largest, std::abs(x));
    }
    return largest;
  };
  EXPECT_NEAR(max_coordinate(mm), 1000 * max_coordinate(m), 1e-3);
  EXPECT_GT(max_coordinate(mm), 10.0);
  EXPECT_LT(max_coordinate(mm), 20.0);
}

TEST_F(LancetVolume, BadArgumentsExitTwo) {
  const std::string f = float_ball("ball.mha", false);
  EXPECT_EQ(run({"mesh", f, "--iso", "inf", "-o", path("x.ply")}).code, 2);
  EXPECT_EQ(run({"mesh", f, "--iso", "50", "-o", path("x.stl")}).code, 2);
  EXPECT_EQ(run({"mesh", f, "--iso", "50", "-o", path("x.ply"), "--units", "cm"}).code, 2);
  EXPECT_EQ(run({"mesh", f, "--iso", "50", "-o", path("x.ply"), "--threads", "100000"}).code, 2);
  EXPECT_EQ(run({"mesh", f, "--iso", "50", "--pad-value", "nan", "-o", path("x.ply")}).code, 2);
  const CliRun r = run({"mesh", f, "--iso", "50", "-o", path("no/such/folder/x.ply")});
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(r.has("cannot open for writing")) << r.output;
}

}  // namespace
