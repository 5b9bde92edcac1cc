// SceneRenderer on llvmpipe (headless: EGL, no X server): the surface is drawn indexed with its
// face materials, and a changed mesh sends only the blocks that changed; a shader that does not
// compile is reported with its stage.

#include "render/scene_renderer.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <memory>
#include <stdexcept>
#include <string>

#include "headless_gl.hpp"
#include "surface/triangle_mesh.hpp"

namespace lancet::render {
namespace {

using SceneRendererTest = test::HeadlessGl<320, 200>;

// The mean colour of the image's middle.
std::array<double, 3> centre_colour(const Image& img) {
  std::array<double, 3> sum{};
  int n = 0;
  for (int y = img.height / 3; y < 2 * img.height / 3; ++y)
    for (int x = img.width / 3; x < 2 * img.width / 3; ++x, ++n)
      for (int c = 0; c < 3; ++c) sum[static_cast<std::size_t>(c)] += img.rgba[static_cast<std::size_t>(4 * (y * img.width + x) + c)];
  for (auto& s : sum) s /= n;
  return sum;
}

TEST_F(SceneRendererTest, ADentSendsOnlyWhatChangedAndMaterialsColourTheFaces) {
  SceneRenderer r(320, 200);
  surface::TissueBlockParams p;
  p.cells = 200;  // 80 000 triangles
  surface::TriangleMesh mesh = surface::make_tissue_block(p);
  r.set_mesh(mesh);
  EXPECT_EQ(r.last_upload_bytes(), r.mesh_bytes()) << "the first mesh goes whole";
  r.set_mesh(mesh);
  EXPECT_EQ(r.last_upload_bytes(), 0u) << "the same mesh sends nothing";
  // A dent: 50 neighbouring vertices move.
  for (std::size_t i = 20000; i < 20050; ++i) mesh.vertices[i].z -= 0.002f;
  r.set_mesh(mesh);
  EXPECT_GT(r.last_upload_bytes(), 0u);
  EXPECT_LE(r.last_upload_bytes(), 2 * 16384u) << "one or two 16 kB blocks of " << r.mesh_bytes() << " bytes";

  SceneInput in;
  in.camera_pitch = 1.5f;  // from above
  in.camera_distance = 0.12f;
  std::fill(mesh.material.begin(), mesh.material.end(), std::uint16_t{1});  // skin
  r.set_mesh(mesh);
  r.render(in);
  const auto skin = centre_colour(r.read_back());
  std::fill(mesh.material.begin(), mesh.material.end(), std::uint16_t{6});  // vessel
  r.set_mesh(mesh);
  EXPECT_LE(r.last_upload_bytes(), mesh.material.size() * 4) << "only the materials changed";
  r.render(in);
  const auto vessel = centre_colour(r.read_back());
  EXPECT_GT(skin[1], vessel[1] + 40) << "skin is pale, the vessel dark red";
  EXPECT_GT(vessel[0], 2 * vessel[1]);
}

// Both hands' tools are drawn, each shaft in its hand's colour (blue right, amber left), each
// where its hand is; a hand without a tool draws nothing.
TEST_F(SceneRendererTest, EachHandsToolIsDrawnInItsColour) {
  SceneRenderer r(320, 200);
  surface::TriangleMesh mesh = surface::make_tissue_block({});
  r.set_mesh(mesh);
  SceneInput in;
  in.camera_pitch = 0.4f;
  in.camera_distance = 0.15f;
  // Counts the pixels close to a hand's colour (as the shader shades it: hue, not brightness) in
  // the left and the right half of the image.
  const auto count = [&](std::size_t hand, int& left_half, int& right_half) {
    const Image img = r.read_back();
    left_half = right_half = 0;
    const double cr = kHandColours[hand][0], cg = kHandColours[hand][1], cb = kHandColours[hand][2];
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) {
        const std::size_t i = static_cast<std::size_t>(4 * (y * img.width + x));
        const double pr = img.rgba[i], pg = img.rgba[i + 1], pb = img.rgba[i + 2], sum = pr + pg + pb;
        if (sum < 60) continue;
        const double dr = pr / sum - cr / (cr + cg + cb), dg = pg / sum - cg / (cr + cg + cb), db = pb / sum - cb / (cr + cg + cb);
        if (dr * dr + dg * dg + db * db < 0.004) (x < img.width / 2 ? left_half : right_half)++;
      }
  };
  int blue_l = 0, blue_r = 0, amber_l = 0, amber_r = 0;
  r.render(in);
  count(0, blue_l, blue_r);
  count(1, amber_l, amber_r);
  const int blue_before = blue_l + blue_r, amber_before = amber_l + amber_r;

  // The two tools 40 mm apart along y: on opposite sides of the image, whichever is which.
  in.tools[0] = {{0.0, -0.02, 0.005}, {0.0, -0.02, 0.005}, {}, true};
  in.tools[1] = {{0.0, 0.02, 0.005}, {0.0, 0.02, 0.005}, {}, true};
  r.render(in);
  count(0, blue_l, blue_r);
  count(1, amber_l, amber_r);
  EXPECT_GT(blue_l + blue_r, blue_before + 100) << "the right hand's shaft, blue";
  EXPECT_GT(amber_l + amber_r, amber_before + 100) << "the left hand's shaft, amber";
  // On opposite sides of the image.
  EXPECT_TRUE((blue_l > blue_r) != (amber_l > amber_r)) << "blue " << blue_l << "/" << blue_r << ", amber " << amber_l << "/" << amber_r;

  in.tools[1].has_tool = false;
  r.render(in);
  count(1, amber_l, amber_r);
  EXPECT_LE(amber_l + amber_r, amber_before + 10) << "no left hand, no amber";
}

TEST_F(SceneRendererTest, AShaderThatDoesNotCompileIsNamedByItsStage) {
  const auto message = [](auto make) {
    try {
      make();
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string bad = "#version 450 core\nlayout(local_size_x = 1) in;\nvoid main() { not glsl }\n";
  EXPECT_NE(message([&] { (void)make_compute_program(bad); }).find("compute shader failed to compile"), std::string::npos);
  const std::string vs = "#version 450 core\nvoid main() { gl_Position = vec4(0.0); }\n";
  EXPECT_NE(message([&] { (void)make_program(vs, "#version 450 core\nvoid main() { oops }\n"); }).find("fragment shader failed"),
            std::string::npos);
}

}  // namespace
}  // namespace lancet::render
