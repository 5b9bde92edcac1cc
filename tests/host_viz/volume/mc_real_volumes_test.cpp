// Marching cubes on the real CT volumes in ../shared/data/volumes: with the border padded, every
// surface is closed, manifold and free of degenerate faces; and against VTK on the same file and
// isovalue (tests/vtk/vtk_isosurface.py under Debian's python3-vtk9, which scripts/setup.sh
// installs), the area agrees within 0.5 % and the triangle count lies between vtkMarchingCubes's
// and vtkFlyingEdges3D's.

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "process.hpp"
#include "shared_data.hpp"
#include "volume/dicom.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/mesh_tools.hpp"
#include "volume/metaimage.hpp"

namespace lancet::volume {
namespace {

struct Case {
  const char* file;
  float iso;
};

// Two isovalues per volume (soft tissue and bone, or their 8-bit equivalents). Integer
// isovalues on integer data on purpose: voxels equal to the isovalue are the degenerate cases.
const std::vector<Case> kCases = {
    {"foot_ct_lossy/foot_256x256x256_uint8_zfplossy.mhd", 60},
    {"foot_ct_lossy/foot_256x256x256_uint8_zfplossy.mhd", 120},
    {"aneurism_cta_head/aneurism_256x256x256_uint8.mhd", 80},
    {"head_ct_headsq/headsq_64x64x93_int16.mhd", 500},
    {"head_ct_headsq/headsq_64x64x93_int16.mhd", 1150},
    {"chest_ct_lidc2/LIDC2.mha", 100},
    {"tooth_ct/tooth_103x94x161_uint8.mhd", 100},
    {"tooth_ct/tooth_103x94x161_uint8.mhd", 200},
};

std::string case_name(const Case& c) { return std::string(c.file) + " @ " + std::to_string(c.iso); }

class RealVolumes : public ::testing::TestWithParam<Case> {
 protected:
  void SetUp() override {
    volumes_ = test::shared_volumes_dir();  // a skip (or, under CI, a failure) here stops the test
    if (volumes_.empty()) return;
    auto r = load_metaimage(volumes_ + "/" + GetParam().file);
    ASSERT_TRUE(r.ok()) << r.error().message;
    volume_ = std::move(r).value();
    min_ = *std::min_element(volume_.data.begin(), volume_.data.end());
  }
  IsoOptions padded() const {
    IsoOptions o;
    o.iso = GetParam().iso;
    o.pad_border = true;
    o.pad_value = min_;
    return o;
  }
  std::string volumes_;
  Volume volume_;
  float min_ = 0;
};

TEST_P(RealVolumes, PaddedSurfaceIsClosedManifoldAndNonDegenerate) {
  auto s = extract_isosurface(volume_, padded());
  ASSERT_TRUE(s.ok()) << s.error().message;
  ASSERT_FALSE(s.value().triangles.empty());
  std::size_t refused = 0;
  const IsoMesh m = to_openmesh(s.value(), &refused);
  EXPECT_EQ(refused, 0u);
  const MeshStats st = mesh_stats(m);
  EXPECT_EQ(st.boundary_edges, 0u);
  EXPECT_EQ(st.non_manifold_vertices, 0u);
  EXPECT_EQ(st.degenerate_faces, 0u);
  EXPECT_EQ(st.isolated_vertices, 0u);
  EXPECT_GT(st.volume, 0) << "faces wind outward";
  EXPECT_EQ(st.euler % 2, 0);
}

TEST_P(RealVolumes, AgreesWithVtk) {
  if (std::system("/usr/bin/python3 -c 'import vtk' >/dev/null 2>&1") != 0)
    FAIL() << "Debian's python3-vtk9 is missing (/usr/bin/python3 cannot import vtk): run scripts/setup.sh";
  auto s = extract_isosurface(volume_, padded());
  ASSERT_TRUE(s.ok());
  const MeshStats ours = mesh_stats(to_openmesh(s.value()));
  const std::string out = std::string(LANCET_BINARY_DIR) + "/vtk_isosurface_" + std::to_string(::getpid()) + ".json";
  char pad[64], iso[64];
  std::snprintf(pad, sizeof pad, "%.9g", double(min_));
  std::snprintf(iso, sizeof iso, "%.9g", double(GetParam().iso));
  test::Child vtk({"/usr/bin/python3", std::string(LANCET_SOURCE_DIR) + "/tests/vtk/vtk_isosurface.py", volumes_ + "/" + GetParam().file,
                   "--iso", iso, "--pad", pad, "--threads", "1", "--repeat", "1", "--quick"},
                  out);
  const auto code = vtk.wait_exit(std::chrono::seconds(240));
  const std::string json = test::read_file(out);
  std::remove(out.c_str());
  ASSERT_TRUE(code.has_value() && *code == 0) << json;
  const auto section = [&](const char* name) { return json.substr(json.find(std::string("\"") + name + "\"")); };
  const auto mc_tris = test::json_number(section("marching_cubes"), "triangles");
  const auto fe_tris = test::json_number(section("flying_edges"), "triangles");
  const auto fe_area = test::json_number(section("flying_edges"), "area");
  const auto mc_area = test::json_number(section("marching_cubes"), "area");
  ASSERT_TRUE(mc_tris && fe_tris && fe_area && mc_area) << json;
  // VTK works in the file's units (mm).
  const double area_mm2 = ours.area * 1e6;
  EXPECT_NEAR(area_mm2, *fe_area, 0.005 * *fe_area) << "flying edges";
  EXPECT_NEAR(area_mm2, *mc_area, 0.005 * *mc_area) << "marching cubes";
  const double lo = std::min(*mc_tris, *fe_tris), hi = std::max(*mc_tris, *fe_tris);
  EXPECT_GE(static_cast<double>(ours.faces), lo);
  EXPECT_LE(static_cast<double>(ours.faces), hi);
  std::printf("%s: ours %zu triangles, %.1f mm²; vtkMarchingCubes %.0f, %.1f mm²; vtkFlyingEdges3D %.0f, %.1f mm²\n",
              case_name(GetParam()).c_str(), ours.faces, area_mm2, *mc_tris, *mc_area, *fe_tris, *fe_area);
}

// The GE head CT (DICOM): gantry tilt kept as a sheared grid, uneven spacing resampled. Its
// surfaces close too, on a grid whose slice axis is not perpendicular to the slices.
TEST(RealDicom, ShearedGeHeadSurfacesAreClosed) {
  LANCET_SHARED_VOLUMES_OR_RETURN(kVolumes);
  DicomOptions o;
  o.resample_uneven = true;
  o.shear_tilted = true;
  auto r = load_dicom_series(kVolumes + "/head_ct_dicom_ge", o);
  ASSERT_TRUE(r.ok()) << r.error().message;
  for (float iso : {-300.0f, 400.0f}) {  // skin, bone
    IsoOptions opt;
    opt.iso = iso;
    opt.pad_border = true;
    opt.pad_value = -3000;
    auto s = extract_isosurface(r.value(), opt);
    ASSERT_TRUE(s.ok());
    std::size_t refused = 0;
    const MeshStats st = mesh_stats(to_openmesh(s.value(), &refused));
    EXPECT_EQ(refused, 0u) << iso;
    EXPECT_TRUE(st.closed()) << iso;
    EXPECT_EQ(st.degenerate_faces, 0u) << iso;
    EXPECT_GT(st.volume, 0) << iso;
    EXPECT_GT(st.faces, 10000u) << iso;
  }
}

INSTANTIATE_TEST_SUITE_P(Volumes, RealVolumes, ::testing::ValuesIn(kCases), [](const auto& param_info) {
  std::string n = std::string(param_info.param.file);
  n = n.substr(0, n.find('/')) + "_" + std::to_string(static_cast<int>(param_info.param.iso));
  for (char& ch : n)
    if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
  return n;
});

}  // namespace
}  // namespace lancet::volume
