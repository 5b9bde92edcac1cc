// Window headless (EGL, no X server): as a double-buffered swap, swap_and_poll() returns once the
// frame before the one it ends is drawn, so that llvmpipe never queues more than one frame behind
// the one being drawn (each queued frame holds its binned triangles: a loop that outran the
// rasterizer held dozens of them).

#include "render/window.hpp"

#include <gtest/gtest.h>

#include "headless_gl.hpp"
#include "render/gl_objects.hpp"
#include "render/scene_renderer.hpp"
#include "surface/triangle_mesh.hpp"

namespace lancet::render {
namespace {

using WindowTest = test::HeadlessGl<640, 480>;

bool signalled(const GLsync s) {
  GLint status = 0;
  glGetSynciv(s, GL_SYNC_STATUS, 1, nullptr, &status);
  return status == GL_SIGNALED;
}

TEST_F(WindowTest, AHeadlessSwapReturnsOnceTheFrameBeforeIsDrawn) {
  SceneRenderer r(640, 480);
  surface::TissueBlockParams p;
  p.cells = 300;  // 180 000 triangles: far longer to rasterize than to queue
  r.set_mesh(surface::make_tissue_block(p));
  SceneInput in;
  in.camera_pitch = 1.5f;
  in.camera_distance = 0.12f;
  for (int i = 0; i < 3; ++i) {
    // A heavy frame, a fence after its draws (only queried, never waited on), then a frame that
    // draws nothing and so ends at once: its swap must still wait for the heavy one.
    r.render(in);
    GLsync heavy = glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
    window_->swap_and_poll();
    window_->swap_and_poll();
    EXPECT_TRUE(signalled(heavy)) << "the heavy frame was still queued after the next frame's swap";
    glDeleteSync(heavy);
  }
}

TEST_F(WindowTest, AFenceWaitsForWhatCameBeforeIt) {
  SceneRenderer r(640, 480);
  surface::TissueBlockParams p;
  p.cells = 300;
  r.set_mesh(surface::make_tissue_block(p));
  r.render(SceneInput{});
  GLsync drawn = glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
  Fence f = Fence::insert();
  Fence moved = std::move(f);
  EXPECT_TRUE(f.empty());  // a moved-from fence is empty
  EXPECT_TRUE(f.wait()) << "an empty fence has nothing to wait for";
  EXPECT_TRUE(moved.wait());
  EXPECT_TRUE(signalled(drawn));
  glDeleteSync(drawn);
}

}  // namespace
}  // namespace lancet::render
