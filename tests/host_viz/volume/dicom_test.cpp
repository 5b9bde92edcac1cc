// The DICOM series loader on the real GE head CT (shared/data/volumes/head_ct_dicom_ge, SOURCES.md
// #4: 28 slices, gantry tilt 18.5°, spacing 4.22 mm then 7.38 mm) and on bad directories.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "volume/dicom.hpp"

namespace lancet::volume {
namespace {

namespace fs = std::filesystem;

const std::string kVolumes = std::string(LANCET_SOURCE_DIR) + "/../shared/data/volumes";
const std::string kGe = kVolumes + "/head_ct_dicom_ge";

// Fails (never skips) when the shared data folder is missing: CI has it beside the checkout.
void require_data() {
  ASSERT_TRUE(fs::is_directory(kGe)) << "The real test volumes are missing: expected the folder " << kGe
                                     << " (shared/data/volumes beside the repository checkout; see SOURCES.md).";
}

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
  require_data();
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
  require_data();
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
  require_data();
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
  require_data();
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
  require_data();
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
  require_data();
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

}  // namespace
}  // namespace lancet::volume
