#include "render/overlay.hpp"

#include <imgui.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

namespace lancet::render {
namespace {

constexpr float kPanelWidth = 380;
const ImVec4 kAlert(1.0f, 0.35f, 0.3f, 1.0f);  // red: what needs the user

void text_line(const OverlayLine& l) {
  if (l.alert) {
    ImGui::TextColored(kAlert, "%s", l.text.c_str());
  } else {
    ImGui::TextUnformatted(l.text.c_str());
  }
}

ImU32 colour_u32(float r, float g, float b, float a = 1.0f) { return ImGui::ColorConvertFloat4ToU32(ImVec4(r, g, b, a)); }

/// The transfer-function editor: the histogram (grey, log scale), the table as a colour strip,
/// the opacity curve through the control points. Left drag moves a point, double-click adds one,
/// right-click removes one; the selected point's colour is edited below the canvas.
bool tf_editor_widget(volume::TfEditor& e, const volume::Histogram* hist, std::array<float, 4>& canvas_out) {
  const ImVec2 size(260, 110);
  const ImVec2 p0 = ImGui::GetCursorScreenPos();
  canvas_out = {p0.x, p0.y, size.x, size.y};
  ImGui::InvisibleButton("##tf_canvas", size, ImGuiButtonFlags_MouseButtonLeft | ImGuiButtonFlags_MouseButtonRight);
  ImDrawList* dl = ImGui::GetWindowDrawList();
  const ImVec2 p1(p0.x + size.x, p0.y + size.y);
  dl->AddRectFilled(p0, p1, colour_u32(0.08f, 0.08f, 0.08f, 0.9f));
  const auto to_screen = [&](float x, float y) { return ImVec2(p0.x + x * size.x, p0.y + (1.0f - y) * size.y); };
  if (hist != nullptr && !hist->counts.empty()) {
    const std::vector<float> h = hist->log_heights();
    const float n = static_cast<float>(h.size());
    for (std::size_t i = 0; i < h.size(); ++i) {
      // The bin's value range, placed on the editor's value axis.
      const float v0 = hist->lo + (hist->hi - hist->lo) * static_cast<float>(i) / n;
      const float v1 = hist->lo + (hist->hi - hist->lo) * static_cast<float>(i + 1) / n;
      const float x0 = std::clamp(e.x_of(v0), 0.0f, 1.0f), x1 = std::clamp(e.x_of(v1), 0.0f, 1.0f);
      if (x1 <= x0 || h[i] <= 0.0f) continue;
      dl->AddRectFilled(to_screen(x0, h[i]), to_screen(x1, 0), colour_u32(0.45f, 0.45f, 0.45f, 0.8f));
    }
  }
  const volume::TransferFunction tf = e.table();
  const int strip = 64;
  for (int i = 0; i < strip; ++i) {  // the table's colour at full opacity, along the bottom
    const float x0 = static_cast<float>(i) / strip, x1 = static_cast<float>(i + 1) / strip;
    const auto c = tf.lookup(e.value_at(0.5f * (x0 + x1)));
    dl->AddRectFilled(ImVec2(p0.x + x0 * size.x, p1.y - 6), ImVec2(p0.x + x1 * size.x, p1.y), colour_u32(c[0], c[1], c[2]));
  }
  const auto& pts = e.points();
  for (std::size_t i = 1; i < pts.size(); ++i)
    dl->AddLine(to_screen(e.x_of(pts[i - 1].value), pts[i - 1].a), to_screen(e.x_of(pts[i].value), pts[i].a),
                colour_u32(1, 1, 1, 0.9f), 1.5f);
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const ImVec2 c = to_screen(e.x_of(pts[i].value), pts[i].a);
    dl->AddCircleFilled(c, 5.0f, colour_u32(pts[i].r, pts[i].g, pts[i].b));
    dl->AddCircle(c, 5.0f, static_cast<int>(i) == e.selected() ? colour_u32(1, 0.85f, 0.2f) : colour_u32(1, 1, 1), 0, 1.5f);
  }
  // Pointer gestures, in canvas coordinates ([0, 1]², y up); a point is hit within 7 px.
  const ImGuiIO& io = ImGui::GetIO();
  const float mx = (io.MousePos.x - p0.x) / size.x, my = 1.0f - (io.MousePos.y - p0.y) / size.y;
  const float rx = 7.0f / size.x, ry = 7.0f / size.y;
  bool changed = false;
  if (ImGui::IsItemHovered() && ImGui::IsMouseDoubleClicked(ImGuiMouseButton_Left) && e.pick(mx, my, rx, ry) < 0) {
    changed = e.add(mx, my) >= 0;
  } else if (ImGui::IsItemActivated() && ImGui::IsMouseClicked(ImGuiMouseButton_Left)) {
    e.press(mx, my, rx, ry);
  }
  if (ImGui::IsItemActive() && ImGui::IsMouseDragging(ImGuiMouseButton_Left, 0.0f)) changed = e.drag_to(mx, my) || changed;
  if (ImGui::IsItemDeactivated()) e.release();
  if (ImGui::IsItemHovered() && ImGui::IsMouseClicked(ImGuiMouseButton_Right)) changed = e.remove(e.pick(mx, my, rx, ry)) || changed;
  const int sel = e.selected();
  if (sel >= 0 && sel < static_cast<int>(pts.size())) {
    const volume::TfPoint& p = pts[static_cast<std::size_t>(sel)];
    float rgb[3] = {p.r, p.g, p.b};
    ImGui::SetNextItemWidth(140);
    if (ImGui::ColorEdit3("##tf_colour", rgb, ImGuiColorEditFlags_NoInputs)) {
      e.set_colour(sel, rgb[0], rgb[1], rgb[2]);
      changed = true;
    }
    ImGui::SameLine();
    ImGui::Text("%.0f HU, opacity %.2f", static_cast<double>(p.value), static_cast<double>(p.a));
  } else {
    // As tall as the colour button's line: the panel (anchored at its bottom) must not move the
    // canvas under the pointer when a point is picked.
    ImGui::AlignTextToFramePadding();
    ImGui::TextDisabled("drag; double-click: add; right-click: remove");
  }
  return changed;
}

/// The servo's wake-up latency over the recent window, one bar per RtStatus bin (log heights:
/// the tail matters and is thousands of times rarer than the mode).
void wake_histogram_widget(const std::vector<std::uint64_t>& bins, float window_s) {
  std::uint64_t total = 0, late = 0;
  float heights[kWakeBins] = {};
  std::uint64_t most = 0;
  for (std::size_t i = 0; i < bins.size() && i < kWakeBins; ++i) {
    total += bins[i];
    most = std::max(most, bins[i]);
    if (kWakeBinLowerUs[i] >= 1000) late += bins[i];
  }
  for (std::size_t i = 0; i < bins.size() && i < kWakeBins; ++i)
    heights[i] = most > 0 ? static_cast<float>(std::log1p(static_cast<double>(bins[i])) / std::log1p(static_cast<double>(most))) : 0.0f;
  char label[96];
  std::snprintf(label, sizeof label, "wake-up latency, last %.0f s (%llu)", static_cast<double>(window_s),
                static_cast<unsigned long long>(total));
  ImGui::PlotHistogram("##wake_hist", heights, static_cast<int>(kWakeBins), 0, label, 0.0f, 1.0f, ImVec2(260, 50));
  // The axis: a few bin edges under their bars (the bins are not of equal width).
  const ImVec2 lo = ImGui::GetItemRectMin(), hi = ImGui::GetItemRectMax();
  const float bar = (hi.x - lo.x) / static_cast<float>(kWakeBins);
  ImDrawList* dl = ImGui::GetWindowDrawList();
  const ImU32 grey = ImGui::GetColorU32(ImGuiCol_TextDisabled);
  const struct {
    std::size_t bin;
    const char* text;
  } ticks[] = {{0, "0"}, {3, "10"}, {8, "100 us"}, {14, "1 ms"}};
  static_assert(kWakeBinLowerUs[3] == 10 && kWakeBinLowerUs[8] == 100 && kWakeBinLowerUs[14] == 1000, "the labels name these edges");
  for (const auto& t : ticks) dl->AddText(ImVec2(lo.x + bar * static_cast<float>(t.bin), hi.y), grey, t.text);
  ImGui::Dummy(ImVec2(hi.x - lo.x, ImGui::GetTextLineHeight()));
  if (late > 0)
    ImGui::TextColored(kAlert, "%llu wake-up%s 1 ms or more late", static_cast<unsigned long long>(late),
                       late == 1 ? "" : "s");
}

}  // namespace

Overlay::Overlay(GLFWwindow* window, bool install_callbacks) {
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini litter in the working directory
  ImGui::StyleColorsDark();
  // Headless (no window): no platform backend; the frame's size and time are set in draw().
  if (window != nullptr) ImGui_ImplGlfw_InitForOpenGL(window, install_callbacks);
  glfw_ = window != nullptr;
  ImGui_ImplOpenGL3_Init("#version 450");
}

Overlay::~Overlay() {
  ImGui_ImplOpenGL3_Shutdown();
  if (glfw_) ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
}

PanelActions Overlay::build(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height,
                           const PanelState* panel) {
  ImGui_ImplOpenGL3_NewFrame();
  if (glfw_) {
    ImGui_ImplGlfw_NewFrame();
  } else {
    ImGui::GetIO().DeltaTime = 1.0f / 60.0f;
  }
  ImGui::GetIO().DisplaySize = ImVec2(static_cast<float>(width), static_cast<float>(height));
  ImGui::NewFrame();
  ImGui::SetNextWindowPos(ImVec2(10, 10), ImGuiCond_Always);
  ImGui::SetNextWindowBgAlpha(0.7f);
  ImGui::Begin(title.c_str(), nullptr,
               ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoSavedSettings);
  for (const auto& l : lines) text_line(l);
  ImGui::End();
  PanelActions act;
  if (panel != nullptr) {
    const PanelState& p = *panel;
    ImGui::SetNextWindowPos(ImVec2(static_cast<float>(width) - 10, static_cast<float>(height) - 10), ImGuiCond_Always,
                            ImVec2(1, 1));
    ImGui::SetNextWindowBgAlpha(0.7f);
    // A fixed width: anchored at its bottom right, a panel whose width followed its widest line
    // would move the editor's canvas under the pointer as its lines change.
    ImGui::SetNextWindowSizeConstraints(ImVec2(kPanelWidth, 0), ImVec2(kPanelWidth, FLT_MAX));
    ImGui::Begin("Controls", nullptr, ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoSavedSettings);
    ImGui::PushTextWrapPos(0.0f);  // (why the records cannot be reached may be a long line)
    for (const OverlayLine& l : p.trainee) text_line(l);
    ImGui::PopTextWrapPos();
    if (p.task_progress >= 0) {
      ImGui::TextUnformatted(p.task_label.c_str());
      ImGui::ProgressBar(p.task_progress, ImVec2(260, 0));
    }
    for (const OverlayLine& l : p.blood) text_line(l);
    ImGui::TextUnformatted("Tool");
    for (std::size_t i = 0; i < p.tools.size(); ++i) {
      if (i > 0) ImGui::SameLine();
      const bool current = p.tool_keys[i] == p.tool;
      if (current) ImGui::PushStyleColor(ImGuiCol_Button, ImVec4(0.2f, 0.55f, 0.3f, 1.0f));
      if (ImGui::Button(p.tools[i].c_str())) act.tool = p.tool_keys[i];
      if (current) ImGui::PopStyleColor();
    }
    if (!p.force_history.empty()) {
      char label[64];
      std::snprintf(label, sizeof label, "force %.2f N", static_cast<double>(p.force_history.back()));
      ImGui::PlotLines("##force", p.force_history.data(), static_cast<int>(p.force_history.size()), 0, label, 0.0f, FLT_MAX,
                       ImVec2(260, 50));
    }
    if (!p.wake_p99_history.empty()) {
      char label[64];
      std::snprintf(label, sizeof label, "servo wake-up p99 %.0f us", static_cast<double>(p.wake_p99_history.back()));
      ImGui::PlotLines("##wake", p.wake_p99_history.data(), static_cast<int>(p.wake_p99_history.size()), 0, label, 0.0f,
                       FLT_MAX, ImVec2(260, 50));
    }
    if (!p.wake_bins.empty()) wake_histogram_widget(p.wake_bins, p.wake_window_s);
    if (p.watchdog_tripped) ImGui::TextColored(kAlert, "watchdog tripped: force held at zero");
    ImGui::BeginDisabled(!p.connected);
    if (ImGui::Button("Re-arm (W)")) act.rearm = true;
    ImGui::SameLine();
    if (ImGui::Button("Reset (R)")) act.reset = true;
    ImGui::EndDisabled();
    ImGui::SameLine();
    if (ImGui::Button("Screenshot (F12)")) act.screenshot = true;
    if (p.can_record) {
      if (ImGui::Button(p.recording ? "Stop recording (F9)" : "Record (F9)")) act.record = true;
    }
    if (!p.record_line.empty()) {
      if (p.recording) ImGui::TextColored(kAlert, "%s", p.record_line.c_str());
      else ImGui::TextUnformatted(p.record_line.c_str());
    }
    if (p.replay_position >= 0) {
      // The replay's timeline: where it is, play/pause and speed.
      ImGui::ProgressBar(p.replay_position, ImVec2(260, 0));
      ImGui::SameLine();
      ImGui::Text("%.1f / %.1f s", static_cast<double>(p.replay_position * p.replay_duration_s), static_cast<double>(p.replay_duration_s));
      if (ImGui::Button(p.replay_paused ? "Play (space)" : "Pause (space)")) act.replay_pause = true;
      for (const float sp : {0.25f, 1.0f, 4.0f, 20.0f}) {
        ImGui::SameLine();
        char label[16];
        std::snprintf(label, sizeof label, "%gx", static_cast<double>(sp));
        if (ImGui::RadioButton(label, p.replay_speed == sp)) act.replay_speed = sp;
      }
    }
    int view = p.view;
    ImGui::TextUnformatted("View (V)");
    ImGui::RadioButton("mesh", &view, 0);
    ImGui::SameLine();
    ImGui::RadioButton("composite", &view, 1);
    ImGui::SameLine();
    ImGui::RadioButton("volume", &view, 2);
    if (view != p.view) act.view = view;
    ImGui::SameLine();
    bool show_patch = p.show_patch;
    if (ImGui::Checkbox("patch (T)", &show_patch)) act.patch_toggled = true;
    if (p.view != 0 && !p.presets.empty()) {
      int preset = p.preset;
      ImGui::SetNextItemWidth(200);
      if (ImGui::BeginCombo("preset (P)", p.presets[static_cast<std::size_t>(preset)].c_str())) {
        for (std::size_t i = 0; i < p.presets.size(); ++i)
          if (ImGui::Selectable(p.presets[i].c_str(), static_cast<int>(i) == preset)) act.preset = static_cast<int>(i);
        ImGui::EndCombo();
      }
      float level = p.level, win = p.width;
      ImGui::SetNextItemWidth(200);
      const bool l = ImGui::SliderFloat("level (HU)", &level, -1000.0f, 1000.0f, "%+.0f");
      ImGui::SetNextItemWidth(200);
      const bool w = ImGui::SliderFloat("width", &win, 0.05f, 20.0f, "x%.2f", ImGuiSliderFlags_Logarithmic);
      if (l || w) {
        act.window_changed = true;
        act.level = level;
        act.width = win;
      }
      bool clip = p.clip;
      float clip_mm = p.clip_mm;
      const bool c = ImGui::Checkbox("clip above", &clip);
      ImGui::SameLine();
      ImGui::SetNextItemWidth(120);
      const bool h = ImGui::SliderFloat("z (mm)", &clip_mm, -100.0f, 20.0f, "%.0f");
      if (c || h) {
        act.clip_changed = true;
        act.clip = clip;
        act.clip_mm = clip_mm;
      }
      if (p.tf_editor != nullptr) {
        ImGui::TextUnformatted("Transfer function (opacity over the histogram)");
        act.tf_edited = tf_editor_widget(*p.tf_editor, p.histogram, act.tf_canvas);
      }
    }
    ImGui::End();
  }
  ImGui::Render();
  return act;
}

void Overlay::layout(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height,
                     const PanelState* panel) {
  (void)build(title, lines, width, height, panel);
}

PanelActions Overlay::draw(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height,
                           const PanelState* panel) {
  const PanelActions act = build(title, lines, width, height, panel);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
  return act;
}

bool Overlay::wants_mouse() const { return glfw_ && ImGui::GetIO().WantCaptureMouse; }

}  // namespace lancet::render
