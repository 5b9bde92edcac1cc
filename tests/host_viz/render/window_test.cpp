// Window headless (EGL, no X server): a frame is finished when swap_and_poll() returns, as a swap
// finishes it, so that llvmpipe never queues frames behind the one being drawn (each queued frame
// holds its binned triangles: a loop that outran the rasterizer held dozens of them).

#include "render/window.hpp"

#include <gtest/gtest.h>

#include "headless_gl.hpp"
#include "render/scene_renderer.hpp"
#include "surface/placeholder_mesh.hpp"

namespace lancet::render {
namespace {

using WindowTest = test::HeadlessGl<640, 480>;

TEST_F(WindowTest, AHeadlessFrameIsFinishedWhenSwapAndPollReturns) {
  SceneRenderer r(640, 480);
  surface::TissueBlockParams p;
  p.cells = 300;  // 180 000 triangles: far longer to rasterize than to queue
  r.set_mesh(surface::make_tissue_block(p));
  SceneInput in;
  in.camera_pitch = 1.5f;
  in.camera_distance = 0.12f;
  for (int frame = 0; frame < 3; ++frame) {
    r.render(in);
    // A fence after everything the frame drew; it is only queried below, never waited on.
    GLsync drawn = glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
    window_->swap_and_poll();
    GLint status = 0;
    glGetSynciv(drawn, GL_SYNC_STATUS, 1, nullptr, &status);
    glDeleteSync(drawn);
    EXPECT_EQ(status, GL_SIGNALED) << "frame " << frame << " was still queued after swap_and_poll()";
  }
}

}  // namespace
}  // namespace lancet::render
