// The controls panel, driven as a user drives it (the mouse state set in Dear ImGui's IO, headless): the
// transfer-function editor drags a point, adds one with a double-click and removes it with a
// right-click, each reported as an edit; the servo's latency histogram is drawn.

#include "render/overlay.hpp"

#include <epoxy/gl.h>
#include <gtest/gtest.h>
#include <imgui.h>

#include <cstdlib>
#include <memory>

#include "headless_gl.hpp"
#include "volume/raycast.hpp"

namespace lancet::render {
namespace {

constexpr int kW = 640, kH = 560;

class OverlayTest : public test::HeadlessGl<kW, kH> {
 protected:
  void SetUp() override {
    HeadlessGl::SetUp();
    if (HasFatalFailure()) return;
    glCreateFramebuffers(1, &fbo_);
    glCreateTextures(GL_TEXTURE_2D, 1, &colour_);
    glTextureStorage2D(colour_, 1, GL_RGBA8, kW, kH);
    glNamedFramebufferTexture(fbo_, GL_COLOR_ATTACHMENT0, colour_, 0);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
    glViewport(0, 0, kW, kH);
  }
  void TearDown() override {
    glDeleteFramebuffers(1, &fbo_);
    glDeleteTextures(1, &colour_);
  }
  PanelActions frame(Overlay& o, PanelState& p) {
    glClear(GL_COLOR_BUFFER_BIT);
    return o.draw("Lancet", {{"status"}}, kW, kH, &p);
  }
  GLuint fbo_ = 0, colour_ = 0;
};

TEST_F(OverlayTest, TheTransferFunctionEditorTakesDragsDoubleClicksAndRightClicks) {
  Overlay overlay(nullptr, false);
  volume::TfEditor editor(volume::tf_preset_spec(volume::TfPreset::kCtBone));
  volume::Histogram hist;
  hist.lo = -1000, hist.hi = 3000;
  hist.counts = {1000, 10, 100, 5, 0, 1, 50, 2};
  PanelState p;
  p.view = 1;
  p.presets = {"CT-Bone"};
  p.tf_editor = &editor;
  p.histogram = &hist;
  p.wake_bins = {10, 900, 80, 8, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0};
  p.wake_window_s = 5;
  // ImGui sizes the panel from the frames before: a few frames settle where the canvas is.
  PanelActions a;
  for (int i = 0; i < 3; ++i) a = frame(overlay, p);
  const auto c = a.tf_canvas;
  ASSERT_GT(c[2], 100.0f) << "the editor is drawn";
  const auto screen = [&](float value, float alpha) { return ImVec2(c[0] + editor.x_of(value) * c[2], c[1] + (1.0f - alpha) * c[3]); };
  ImGuiIO& io = ImGui::GetIO();

  // Press on the 300 HU point and drag it right and up.
  const volume::TfPoint before = editor.points()[2];
  const ImVec2 at = screen(before.value, before.a);
  io.MousePos = ImVec2(at.x, at.y);
  frame(overlay, p);
  io.MouseDown[ImGuiMouseButton_Left] = true;
  frame(overlay, p);
  EXPECT_EQ(editor.selected(), 2);
  const ImVec2 to = screen(600.0f, 0.7f);
  io.MousePos = ImVec2(to.x, to.y);
  a = frame(overlay, p);
  EXPECT_TRUE(a.tf_edited);
  EXPECT_NEAR(editor.points()[2].value, 600.0f, 30.0f);
  EXPECT_NEAR(editor.points()[2].a, 0.7f, 0.03f);
  io.MouseDown[ImGuiMouseButton_Left] = false;
  frame(overlay, p);
  EXPECT_FALSE(frame(overlay, p).tf_edited) << "released: no more edits";

  // A double-click on empty canvas adds a point there.
  const std::size_t n = editor.points().size();
  const ImVec2 empty = screen(2000.0f, 0.2f);
  io.MousePos = ImVec2(empty.x, empty.y);
  frame(overlay, p);
  bool edited = false;
  for (int click = 0; click < 2; ++click) {
    io.MouseDown[ImGuiMouseButton_Left] = true;
    edited = frame(overlay, p).tf_edited || edited;
    io.MouseDown[ImGuiMouseButton_Left] = false;
    edited = frame(overlay, p).tf_edited || edited;
  }
  EXPECT_TRUE(edited);
  ASSERT_EQ(editor.points().size(), n + 1);
  EXPECT_NEAR(editor.points()[4].value, 2000.0f, 30.0f);

  // A right-click on it removes it again.
  io.MouseDown[ImGuiMouseButton_Right] = true;
  edited = frame(overlay, p).tf_edited;
  io.MouseDown[ImGuiMouseButton_Right] = false;
  edited = frame(overlay, p).tf_edited || edited;
  EXPECT_TRUE(edited);
  EXPECT_EQ(editor.points().size(), n);

  // Something was drawn (the panel, the histogram, the curve): not a blank frame.
  std::vector<std::uint8_t> px(static_cast<std::size_t>(kW) * kH * 4);
  glReadPixels(0, 0, kW, kH, GL_RGBA, GL_UNSIGNED_BYTE, px.data());
  std::size_t lit = 0;
  for (std::size_t i = 0; i < px.size(); i += 4) lit += px[i] + px[i + 1] + px[i + 2] > 60;
  EXPECT_GT(lit, 5000u);
}

}  // namespace
}  // namespace lancet::render
