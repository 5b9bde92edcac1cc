// lancet-cut-script end to end: the shipped example writes meshes a viewer (here OpenMesh's
// reader) opens, with the cut visible as new boundary edges; a bad script names its line.

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <string>

#include "process.hpp"
#include "temp_files.hpp"

namespace {

using Mesh = OpenMesh::TriMesh_ArrayKernelT<>;
const std::string kTool = std::string(LANCET_BINARY_DIR) + "/host_viz/lancet-cut-script";

class CutReplay : public lancet::test::TempDirTest {
 protected:
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  int run(const std::vector<std::string>& args, std::string& output) {
    std::vector<std::string> argv = {kTool};
    argv.insert(argv.end(), args.begin(), args.end());
    const std::string log = path("log.txt");
    lancet::test::Child child(argv, log);
    const auto code = child.wait_exit(std::chrono::seconds(120));
    output = lancet::test::read_file(log);
    if (!code || !WIFEXITED(*code)) return -1;
    return WEXITSTATUS(*code);
  }
  static std::size_t boundary_edges(const Mesh& m) {
    std::size_t n = 0;
    for (auto e : m.edges()) n += m.is_boundary(e) ? 1 : 0;
    return n;
  }
};

TEST_F(CutReplay, ExampleWritesMeshesWithTheCutOpen) {
  std::string out;
  const std::string before = path("before.ply"), after = path("after.obj");
  ASSERT_EQ(run({std::string(LANCET_SOURCE_DIR) + "/docs/examples/sheet_cut.txt", "--before", before, "--after", after}, out), 0) << out;
  Mesh b, a;
  ASSERT_TRUE(OpenMesh::IO::read_mesh(b, before));
  ASSERT_TRUE(OpenMesh::IO::read_mesh(a, after));
  EXPECT_EQ(b.n_faces(), 7200u);
  EXPECT_EQ(a.n_faces(), b.n_faces()) << "a cut creates no faces";
  EXPECT_GT(a.n_vertices(), b.n_vertices() + 20) << "split vertices along the cut";
  EXPECT_GT(boundary_edges(a), boundary_edges(b) + 40) << "the cut's two lips are open boundary";
  EXPECT_NE(out.find("\"non_manifold_vertices\": 0"), std::string::npos) << out;
  EXPECT_NE(out.find("\"flipped_faces\": 0"), std::string::npos) << out;
  // The files are in millimetres, like lancet-volume's: the 60 mm sheet spans 60 units.
  float lo = 1e9f, hi = -1e9f;
  for (auto v : b.vertices()) {
    lo = std::min(lo, b.point(v)[0]);
    hi = std::max(hi, b.point(v)[0]);
  }
  EXPECT_NEAR(hi - lo, 60.0f, 0.5f);
}

TEST_F(CutReplay, MeshFilesAreReadAndWrittenInMillimetresOrInMetresWhenAsked) {
  // What one run writes (mm), the next reads back at the same size and cuts.
  const auto script = [&](const std::string& text) { return write("s.txt", text); };
  std::string out;
  const std::string sheet = path("sheet.ply");
  ASSERT_EQ(run({script("mesh sheet 20 60\n"), "--after", sheet}, out), 0) << out;
  const auto extent = [](const std::string& file) {
    Mesh m;
    EXPECT_TRUE(OpenMesh::IO::read_mesh(m, file)) << file;
    float lo = 1e9f, hi = -1e9f;
    for (auto v : m.vertices()) {
      lo = std::min(lo, m.point(v)[0]);
      hi = std::max(hi, m.point(v)[0]);
    }
    return hi - lo;
  };
  // Read as metres and written as mm, the sheet would come back 1000 times larger.
  const std::string cut = "mesh file " + sheet + "\ncut -10 0 0\nto 10 0 0\nend\n";
  ASSERT_EQ(run({script(cut), "--after", path("again.ply")}, out), 0) << out;
  EXPECT_NEAR(extent(path("again.ply")), 60.0f, 0.5f);
  ASSERT_EQ(run({script("mesh sheet 20 60\n"), "--units", "m", "--after", path("metres.ply")}, out), 0) << out;
  EXPECT_NEAR(extent(path("metres.ply")), 0.060f, 0.0005f);
  EXPECT_EQ(run({script("mesh sheet 20 60\n"), "--units", "inch", "--after", path("x.ply")}, out), 2);
}

// The script drives the visualizer's own scene: the cut reaches into the volume under the sheet
// as a groove that opens with the incision, and the drill removes voxels.
TEST_F(CutReplay, TheScriptGoesThroughTheTissueScene) {
  const auto script = [&](const std::string& text) { return write("s.txt", text); };
  std::string out;
  ASSERT_EQ(run({script("mesh sheet 40 40\ntool scalpel\ncut -10 0 0\nto 10 0 0\nend\ntool retractor\nopen 4\n"
                        "tool drill\ndrill 0 10 -3 2\n"),
                 "--after", path("a.ply")},
                out),
            0)
      << out;
  EXPECT_NE(out.find("\"grooves\": 1, \"groove_width_mm\": 4.0"), std::string::npos) << out;
  const auto at = out.find("\"voxels_drilled\": ");
  ASSERT_NE(at, std::string::npos) << out;
  EXPECT_GT(std::stoi(out.substr(at + 18)), 20) << out;
  EXPECT_EQ(run({script("mesh sheet 10 20\ntool saw\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find(":2: unknown tool 'saw'"), std::string::npos) << out;
  EXPECT_EQ(run({script("mesh sheet 10 20\ndrill 0 0 0 50\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find(":2: expected a radius in (0, 10] mm"), std::string::npos) << out;
}

TEST_F(CutReplay, BadScriptsNameTheLine) {
  const auto script = [&](const std::string& text) { return write("s.txt", text); };
  std::string out;
  EXPECT_EQ(run({script("mesh sheet 10 20\ncut 0 0 0\nto 1 x 0\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find("s.txt:3: 'x' is not a number"), std::string::npos) << out;
  EXPECT_EQ(run({script("cut 0 0 0\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find(":1: 'mesh' must come before 'cut'"), std::string::npos) << out;
  EXPECT_EQ(run({script("mesh sheet 10 20\n\n# comment\nslice 1 2 3\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find(":4: unknown command 'slice'"), std::string::npos) << out;
  EXPECT_EQ(run({script("mesh sheet 10 20\nto 1 2 3\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find(":2: 'to' outside a cut"), std::string::npos) << out;
  EXPECT_EQ(run({script("mesh file missing.ply\n"), "--after", path("a.obj")}, out), 2);
  EXPECT_NE(out.find("cannot read the mesh"), std::string::npos) << out;
  EXPECT_EQ(run({path("nope.txt"), "--after", path("a.obj")}, out), 2);
}

}  // namespace
