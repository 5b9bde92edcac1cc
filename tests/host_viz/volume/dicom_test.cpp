// The DICOM series loader on the real GE head CT (shared/data/volumes/head_ct_dicom_ge, SOURCES.md
// #4: 28 slices, gantry tilt 18.5°, spacing 4.22 mm then 7.38 mm), on that series broken the ways
// scans break in the field (a file truncated, pixel data cut short, a file cut to 300 bytes, junk,
// another series, a missing slice), and on small synthetic series.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <span>
#include <sstream>
#include <string>

#include "dicom_bytes.hpp"
#include "shared_data.hpp"
#include "temp_files.hpp"
#include "volume/dicom.hpp"
#include "volume/dicom_scan.hpp"

namespace lancet::volume {
namespace {

namespace fs = std::filesystem;

// The GE series folder, or "" (the test is then skipped, or failed under CI).
std::string ge_dir() {
  const std::string v = test::shared_volumes_dir();
  return v.empty() ? v : v + "/head_ct_dicom_ge";
}

#define GE_OR_RETURN(var)               \
  const std::string var = ge_dir(); \
  if (var.empty()) return

// A fresh empty directory under the system temp folder, removed at the end of the test.
class TempDir {
 public:
  explicit TempDir(const std::string& name)
      : path_(fs::temp_directory_path() / ("lancet_dicom_test_" + name + "_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  [[nodiscard]] const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

TEST(Dicom, WholeGeSeriesIsRefusedForGantryTilt) {
  GE_OR_RETURN(kGe);
  const auto r = load_dicom_series(kGe);
  ASSERT_FALSE(r.ok());
  const std::string& m = r.error().message;
  EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
  EXPECT_NE(m.find("gantry tilt of 18.5 degrees"), std::string::npos) << m;
  EXPECT_NE(m.find("ImagePositionPatient (0020,0032)"), std::string::npos) << m;
  EXPECT_NE(m.find(kGe), std::string::npos) << m;
  // Resampling the uneven spacing does not make a tilted series loadable.
  const auto resampled = load_dicom_series(kGe, DicomOptions{.resample_uneven = true});
  ASSERT_FALSE(resampled.ok());
  EXPECT_NE(resampled.error().message.find("gantry tilt"), std::string::npos) << resampled.error().message;
}

TEST(Dicom, UniformGeSubSeriesIsAlsoTilted) {
  GE_OR_RETURN(kGe);
  TempDir dir("uniform");
  for (int i = 1; i <= 14; ++i) {
    const std::string name = (i < 10 ? "0" : "") + std::to_string(i) + ".dcm";
    fs::copy_file(kGe + "/" + name, dir.path() / name);
  }
  const auto r = load_dicom_series(dir.path().string());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("gantry tilt of 18.5 degrees"), std::string::npos) << r.error().message;
}

TEST(Dicom, SingleGeSliceLoadsWithHuAndGeometry) {
  GE_OR_RETURN(kGe);
  TempDir dir("single");
  fs::copy_file(kGe + "/07.dcm", dir.path() / "07.dcm");
  std::ofstream(dir.path() / "README.txt") << "not a DICOM file\n";  // skipped
  double last = -1;
  auto r = load_dicom_series(dir.path().string(), {}, [&](double f) {
    EXPECT_GE(f, last);
    last = f;
  });
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value();
  EXPECT_EQ(v.dims, (std::array<int, 3>{512, 512, 1}));
  EXPECT_NEAR(v.spacing.x, 0.48828e-3, 1e-8);
  EXPECT_NEAR(v.spacing.y, 0.48828e-3, 1e-8);
  EXPECT_EQ(v.value_unit, "HU");
  EXPECT_EQ(v.source_type, VoxelType::kI16);
  EXPECT_DOUBLE_EQ(last, 1.0);
  // Direction columns: row cosine (1,0,0), column cosine (0,0.948,-0.317), normal = row × column.
  EXPECT_NEAR(v.direction[0], 1.0, 1e-3);
  EXPECT_NEAR(v.direction[4], 0.948, 2e-3);
  EXPECT_NEAR(v.direction[7], -0.317, 2e-3);
  EXPECT_NEAR(v.direction[5], 0.317, 2e-3);
  EXPECT_NEAR(v.direction[8], 0.948, 2e-3);
  const auto [mn, mx] = std::minmax_element(v.data.begin(), v.data.end());
  EXPECT_LE(*mn, -1000.0f);
  EXPECT_GE(*mn, -3100.0f);
  EXPECT_GT(*mx, 1000.0f);
}

// With the tilt tolerated (sine of 18.5° = 0.317 < 0.35), the uneven spacing is what refuses the
// series: along the normal the slices are 4.00 mm apart (4.22 mm · cos 18.5°) until 14.dcm, and
// 15.dcm lies only 1.08 mm past 14.dcm. Resampling then gives the smallest spacing.
TEST(Dicom, GeSeriesUnevenSpacingWhenTiltTolerated) {
  GE_OR_RETURN(kGe);
  const auto r = load_dicom_series(kGe, DicomOptions{.resample_uneven = false, .spacing_tolerance = 0.35});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("slice spacing changes from 4.00 mm to 1.08 mm between 14.dcm and 15.dcm"),
            std::string::npos)
      << r.error().message;
  auto resampled = load_dicom_series(kGe, DicomOptions{.resample_uneven = true, .spacing_tolerance = 0.35});
  ASSERT_TRUE(resampled.ok()) << resampled.error().message;
  const Volume& v = resampled.value();
  EXPECT_EQ(v.dims[0], 512);
  EXPECT_EQ(v.dims[2], 134);
  EXPECT_NEAR(v.spacing.z, 1.081e-3, 1e-5);
  EXPECT_EQ(v.data.size(), v.voxel_count());
}

// Tilt kept as a sheared grid and the uneven spacing resampled: the whole GE series loads, and
// every original slice's first voxel sits where its ImagePositionPatient says.
TEST(Dicom, GeSeriesLoadsShearedAndResampled) {
  GE_OR_RETURN(kGe);
  DicomOptions o;
  o.resample_uneven = true;
  o.shear_tilted = true;
  auto r = load_dicom_series(kGe, o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value();
  EXPECT_EQ(v.dims[0], 512);
  EXPECT_EQ(v.dims[1], 512);
  EXPECT_EQ(v.dims[2], 134);
  EXPECT_EQ(v.data.size(), v.voxel_count());
  // The slice axis leans 18.5 degrees from the normal (row × column), in the y-z plane.
  const Vec3 axis{v.direction[2], v.direction[5], v.direction[8]};
  const Vec3 normal{0, 0.317, 0.948};  // row (1,0,0) × column (0, 0.948, -0.317)
  EXPECT_NEAR(norm(axis), 1.0, 1e-9);
  EXPECT_NEAR(std::acos(dot(axis, normalized(normal))) * 180 / 3.14159265358979, 18.5, 0.2);
  EXPECT_NEAR(v.spacing.z * std::cos(18.5 * 3.14159265358979 / 180), 1.081e-3, 1e-5) << "1.08 mm along the normal";
  const auto [mn, mx] = std::minmax_element(v.data.begin(), v.data.end());
  EXPECT_LE(*mn, -1000.0f);
  EXPECT_GT(*mx, 1000.0f);
}

// The sheared grid puts every slice exactly where the scanner did: the uniform sub-series 01–14,
// loaded sheared, holds slice 07 (loaded alone: no tilt to speak of) at its own position and with
// its own values.
TEST(Dicom, ShearedGridPutsEachSliceAtItsPosition) {
  GE_OR_RETURN(kGe);
  TempDir dir("sheared");
  for (int i = 1; i <= 14; ++i) {
    const std::string name = (i < 10 ? "0" : "") + std::to_string(i) + ".dcm";
    fs::copy_file(kGe + "/" + name, dir.path() / name);
  }
  DicomOptions o;
  o.shear_tilted = true;
  auto r = load_dicom_series(dir.path().string(), o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Volume& v = r.value();
  ASSERT_EQ(v.dims[2], 14);
  EXPECT_NEAR(v.spacing.z, 4.22e-3, 0.01e-3) << "the step along the tilted axis, as the scanner moved";
  TempDir one("sheared_one");
  fs::copy_file(kGe + "/07.dcm", one.path() / "07.dcm");
  auto s7 = load_dicom_series(one.path().string());
  ASSERT_TRUE(s7.ok());
  int best = -1;
  double best_d = 1e9;
  for (int k = 0; k < 14; ++k) {
    const double d = norm(v.position(0, 0, k) - s7.value().origin);
    if (d < best_d) best_d = d, best = k;
  }
  EXPECT_LT(best_d, 1e-6) << "slice 07's first voxel";
  const Vec3 far_corner_sheared = v.position(511, 511, best);
  const Vec3 far_corner_alone = s7.value().position(511, 511, 0);
  EXPECT_LT(norm(far_corner_sheared - far_corner_alone), 1e-6);
  const std::size_t plane = 512u * 512u;
  EXPECT_TRUE(std::equal(s7.value().data.begin(), s7.value().data.end(), v.data.begin() + static_cast<std::ptrdiff_t>(plane * static_cast<std::size_t>(best))));
}

TEST(Dicom, MissingDirectoryIsNotFound) {
  const auto r = load_dicom_series("/nonexistent/lancet/dicom");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_NE(r.error().message.find("/nonexistent/lancet/dicom"), std::string::npos);
}

TEST(Dicom, EmptyDirectoryIsRefused) {
  TempDir dir("empty");
  const auto r = load_dicom_series(dir.path().string());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("contains no files"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find(dir.path().string()), std::string::npos) << r.error().message;
}

TEST(Dicom, DirectoryWithoutDicomImagesIsRefused) {
  TempDir dir("nondicom");
  std::ofstream(dir.path() / "notes.txt") << "hello, not DICOM\n";
  const auto r = load_dicom_series(dir.path().string());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("no DICOM image files"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("notes.txt"), std::string::npos) << r.error().message;
}

// ---- broken scans, made from real GE slices ---------------------------------------------------

std::string ge_name(int i) { return (i < 10 ? "0" : "") + std::to_string(i) + ".dcm"; }

std::string read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void write_bytes(const fs::path& p, const std::string& bytes) {
  fs::remove(p);
  std::ofstream(p, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// GE slices first..last of the uniform sub-series (01..14: 4.22 mm apart, tilted 18.5°), copied
// into dir.
void copy_ge(const std::string& ge, const fs::path& dir, int first, int last) {
  for (int i = first; i <= last; ++i) {
    fs::copy_file(ge + "/" + ge_name(i), dir / ge_name(i));
    fs::permissions(dir / ge_name(i), fs::perms::owner_write, fs::perm_options::add);
  }
}

DicomOptions sheared() {
  DicomOptions o;
  o.shear_tilted = true;
  return o;
}

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// A slice truncated inside its pixel data used to load with the missing half silently zero; the
// whole file truncated inside its header aborted the program in a GDCM assertion.
TEST(DicomBroken, TruncatedSliceIsAnErrorNamingIt) {
  GE_OR_RETURN(ge);
  TempDir dir("truncated");
  copy_ge(ge, dir.path(), 5, 9);
  const std::string full = read_bytes(dir.path() / "07.dcm");
  write_bytes(dir.path() / "07.dcm", full.substr(0, full.size() / 2));
  const auto r = load_dicom_series(dir.path().string(), sheared());
  ASSERT_FALSE(r.ok());
  const std::string& m = r.error().message;
  EXPECT_TRUE(has(m, (dir.path() / "07.dcm").string())) << m;
  EXPECT_TRUE(has(m, "PixelData (7FE0,0010): the file is cut short: expected 524288 bytes of pixel data, found 261174")) << m;
}

// 07.dcm cut at every 53rd byte through its header: each load returns (no abort), and never
// loads the series silently without it.
TEST(DicomBroken, HeaderCutAnywhereNeverAborts) {
  GE_OR_RETURN(ge);
  TempDir dir("header_cut");
  copy_ge(ge, dir.path(), 6, 8);
  const std::string full = read_bytes(dir.path() / "07.dcm");
  for (std::size_t n = 0; n < 2100; n += 53) {
    write_bytes(dir.path() / "07.dcm", full.substr(0, n));
    const auto r = load_dicom_series(dir.path().string(), sheared());
    ASSERT_FALSE(r.ok()) << "cut to " << n << " bytes";
    const std::string& m = r.error().message;
    // Cut after its SeriesInstanceUID, 07.dcm is a broken slice of the series; before it, 07.dcm
    // is skipped and the hole it leaves is a gap between 06.dcm and 08.dcm.
    EXPECT_TRUE(has(m, "07.dcm")) << n << ": " << m;
    if (!has(m, "07.dcm:")) {
      EXPECT_TRUE(has(m, "gap of 8.00 mm") && has(m, "06.dcm and 08.dcm")) << n << ": " << m;
    }
  }
}

// Pixel data shorter than Rows x Columns x 2, in a file that is otherwise whole (PixelData's
// length says so): an error naming the file with expected vs found.
TEST(DicomBroken, PixelDataCutShortIsAnError) {
  GE_OR_RETURN(ge);
  TempDir dir("short_pixels");
  copy_ge(ge, dir.path(), 6, 8);
  std::string b = read_bytes(dir.path() / "07.dcm");
  const DicomScan s = scan_dicom(std::span(reinterpret_cast<const std::uint8_t*>(b.data()), b.size()));
  ASSERT_EQ(s.status, DicomScanStatus::kImage);
  const std::size_t len_at = s.pixel_offset - 4;  // OW: 32-bit length just before the value
  b.replace(len_at, 4, std::string("\xE8\x03\x00\x00", 4));  // 1000 bytes
  write_bytes(dir.path() / "07.dcm", b.substr(0, s.pixel_offset + 1000));
  const auto r = load_dicom_series(dir.path().string(), sheared());
  ASSERT_FALSE(r.ok());
  const std::string& m = r.error().message;
  EXPECT_TRUE(has(m, (dir.path() / "07.dcm").string())) << m;
  EXPECT_TRUE(has(m, "PixelData (7FE0,0010): expected 524288 bytes (Rows 512 x Columns 512 x 2 bytes), found 1000")) << m;
}

// A slice cut to 300 bytes (inside the file meta group) used to be dropped without a word, the
// series loading with a hole. Now it is named in a warning, and the hole is a gap between the
// files around it that the loader refuses unless told.
TEST(DicomBroken, SliceCutTo300BytesIsNamedAndLeavesAGap) {
  GE_OR_RETURN(ge);
  TempDir dir("cut300");
  copy_ge(ge, dir.path(), 5, 9);
  write_bytes(dir.path() / "07.dcm", read_bytes(dir.path() / "07.dcm").substr(0, 300));
  auto r = load_dicom_series(dir.path().string(), sheared());
  ASSERT_FALSE(r.ok());
  std::string m = r.error().message;
  EXPECT_TRUE(has(m, "gap of 8.00 mm along the slice normal between 06.dcm and 08.dcm, where the slices around it are 4.00 mm apart (2.0x"))
      << m;
  EXPECT_TRUE(has(m, "perhaps the missing slice: 07.dcm (unreadable before its SeriesInstanceUID (0020,000E): byte 292")) << m;
  EXPECT_TRUE(has(m, "DicomOptions::resample_uneven with DicomOptions::allow_gaps")) << m;

  DicomOptions o = sheared();
  o.resample_uneven = true;
  r = load_dicom_series(dir.path().string(), o);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(has(r.error().message, "refusing to interpolate across it (use DicomOptions::allow_gaps")) << r.error().message;

  o.allow_gaps = true;
  r = load_dicom_series(dir.path().string(), o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().dims[2], 5) << "16 mm resampled at 4 mm";
  const auto& w = r.value().warnings;
  ASSERT_EQ(w.size(), 2u);
  EXPECT_TRUE(has(w[0], (dir.path() / "07.dcm").string() + ": skipped, not part of the series: unreadable before its SeriesInstanceUID"))
      << w[0];
  EXPECT_TRUE(has(w[1], "gap of 8.00 mm") && has(w[1], "interpolated across")) << w[1];
}

TEST(DicomBroken, MissingMiddleSliceIsAGapNamingItsNeighbours) {
  GE_OR_RETURN(ge);
  TempDir dir("missing");
  copy_ge(ge, dir.path(), 3, 11);
  fs::remove(dir.path() / "07.dcm");
  auto r = load_dicom_series(dir.path().string(), sheared());
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(has(r.error().message, "gap of 8.00 mm along the slice normal between 06.dcm and 08.dcm, where the slices around it are 4.00 mm apart"))
      << r.error().message;
  EXPECT_FALSE(has(r.error().message, "perhaps the missing slice")) << "no unreadable file to blame";
  DicomOptions o = sheared();
  o.resample_uneven = true;
  o.allow_gaps = true;
  r = load_dicom_series(dir.path().string(), o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().dims[2], 9);
  ASSERT_EQ(r.value().warnings.size(), 1u);
  EXPECT_TRUE(has(r.value().warnings[0], "between 06.dcm and 08.dcm")) << r.value().warnings[0];
}

TEST(DicomBroken, JunkAndOtherSeriesAreNamedInWarnings) {
  GE_OR_RETURN(ge);
  TempDir dir("junk");
  copy_ge(ge, dir.path(), 6, 9);
  std::string junk(5000, '\0');
  for (std::size_t i = 0; i < junk.size(); ++i) junk[i] = static_cast<char>(i * 131 + 7);
  write_bytes(dir.path() / "zz.dcm", junk);
  // A slice of another series: 10.dcm with one digit of its SeriesInstanceUID changed.
  std::string other = read_bytes(fs::path(ge) / "10.dcm");
  const std::size_t uid = other.find(std::string("\x20\x00\x0E\x00UI", 6));
  ASSERT_NE(uid, std::string::npos);
  other[uid + 8 + 40] = other[uid + 8 + 40] == '1' ? '2' : '1';
  write_bytes(dir.path() / "other.dcm", other);
  auto r = load_dicom_series(dir.path().string(), sheared());
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().dims[2], 4);
  const auto& w = r.value().warnings;
  ASSERT_EQ(w.size(), 2u);
  EXPECT_TRUE(has(w[0], "other.dcm: skipped, not part of the series: another series (SeriesInstanceUID")) << w[0];
  EXPECT_TRUE(has(w[1], "zz.dcm: skipped, not part of the series: not a DICOM file: no 'DICM' marker at byte 128")) << w[1];
}

// Values are Hounsfield units only for CT: the same slice labelled MR loads with raw values.
TEST(Dicom, MrValuesAreNotHu) {
  GE_OR_RETURN(ge);
  TempDir dir("mr");
  std::string b = read_bytes(fs::path(ge) / "07.dcm");
  const std::size_t at = b.find(std::string("\x08\x00\x60\x00" "CS\x02\x00" "CT", 10));
  ASSERT_NE(at, std::string::npos);
  b.replace(at + 8, 2, "MR");
  write_bytes(dir.path() / "07.dcm", b);
  auto r = load_dicom_series(dir.path().string());
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().modality, "MR");
  EXPECT_EQ(r.value().value_unit, "raw");
}

// ---- small synthetic series -------------------------------------------------------------------

class DicomSynthetic : public test::TempDirTest {
 protected:
  void slice(const std::string& name, const std::string& ts, const test::DicomDataSet& d) { write(name, test::dicom_file(ts, d)); }
};

// The same three slices in implicit VR little endian and explicit VR big endian load like the
// explicit little endian ones (GDCM decodes them; the scan walks them first).
TEST_F(DicomSynthetic, ImplicitAndBigEndianLoadLikeExplicit) {
  struct Enc {
    const char* ts;
    bool explicit_vr, big;
  };
  std::vector<Volume> loaded;
  for (const Enc e : {Enc{"1.2.840.10008.1.2.1", true, false}, Enc{"1.2.840.10008.1.2", false, false}, Enc{"1.2.840.10008.1.2.2", true, true}}) {
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    for (int z = 0; z < 3; ++z) slice("s" + std::to_string(z) + ".dcm", e.ts, test::ct_slice(e.explicit_vr, e.big, 2.0 * z, "1.2.9"));
    auto r = load_dicom_series(dir_.string());
    ASSERT_TRUE(r.ok()) << e.ts << ": " << r.error().message;
    EXPECT_EQ(r.value().dims, (std::array<int, 3>{4, 3, 3}));
    EXPECT_NEAR(r.value().spacing.z, 2e-3, 1e-12);
    EXPECT_EQ(r.value().value_unit, "HU");
    loaded.push_back(std::move(r).value());
  }
  EXPECT_EQ(loaded[0].data, loaded[1].data) << "implicit VR";
  // Big endian: the same bytes, read with the other byte order.
  const float first_le = loaded[0].data[1], first_be = loaded[2].data[1];
  EXPECT_EQ(first_le, static_cast<float>(0x150E - 1024)) << "bytes 14, 21 little endian";
  EXPECT_EQ(first_be, static_cast<float>(0x0E15 - 1024)) << "bytes 14, 21 big endian";
}

TEST_F(DicomSynthetic, TwoSeriesOfEqualSizeAreRefused) {
  slice("a.dcm", "1.2.840.10008.1.2.1", test::ct_slice(true, false, 0, "1.1"));
  slice("b.dcm", "1.2.840.10008.1.2.1", test::ct_slice(true, false, 0, "1.2"));
  const auto r = load_dicom_series(dir_.string());
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(has(r.error().message, "two series with 1 image file(s) each")) << r.error().message;
  EXPECT_TRUE(has(r.error().message, "put each series in its own folder")) << r.error().message;
}

// Seeded random edits of a one-slice folder go through the scan and GDCM in this process: an
// assertion inside GDCM would kill the test.
TEST_F(DicomSynthetic, RandomMutationsNeverAbort) {
  std::mt19937 rng(7);
  const std::vector<std::string> seeds = test::slice_in_every_syntax();
  int loaded = 0;
  for (int n = 0; n < 1500; ++n) {
    const std::string b = test::mutate(seeds[static_cast<std::size_t>(n) % seeds.size()], rng, 3);
    write("x.dcm", b);
    auto r = load_dicom_series(dir_.string());
    if (r.ok()) {
      ++loaded;
      EXPECT_EQ(r.value().data.size(), r.value().voxel_count());
    } else {
      EXPECT_FALSE(r.error().message.empty());
    }
  }
  EXPECT_GT(loaded, 20) << "some edits leave a loadable slice";
}

}  // namespace
}  // namespace lancet::volume
