#include "render/overlay.hpp"

#include <imgui.h>

#include <cfloat>
#include <cstdio>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

namespace lancet::render {

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
  for (const auto& l : lines) {
    if (l.alert) {
      ImGui::TextColored(ImVec4(1.0f, 0.35f, 0.3f, 1.0f), "%s", l.text.c_str());
    } else {
      ImGui::TextUnformatted(l.text.c_str());
    }
  }
  ImGui::End();
  PanelActions act;
  if (panel != nullptr) {
    const PanelState& p = *panel;
    ImGui::SetNextWindowPos(ImVec2(static_cast<float>(width) - 10, static_cast<float>(height) - 10), ImGuiCond_Always,
                            ImVec2(1, 1));
    ImGui::SetNextWindowBgAlpha(0.7f);
    ImGui::Begin("Controls", nullptr, ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoSavedSettings);
    if (p.task_progress >= 0) {
      ImGui::TextUnformatted(p.task_label.c_str());
      ImGui::ProgressBar(p.task_progress, ImVec2(260, 0));
    }
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
    if (p.watchdog_tripped) ImGui::TextColored(ImVec4(1.0f, 0.35f, 0.3f, 1.0f), "watchdog tripped: force held at zero");
    ImGui::BeginDisabled(!p.connected);
    if (ImGui::Button("Re-arm (W)")) act.rearm = true;
    ImGui::SameLine();
    if (ImGui::Button("Reset (R)")) act.reset = true;
    ImGui::EndDisabled();
    ImGui::SameLine();
    if (ImGui::Button("Screenshot (F12)")) act.screenshot = true;
    int view = p.view;
    ImGui::TextUnformatted("View (V)");
    ImGui::RadioButton("mesh", &view, 0);
    ImGui::SameLine();
    ImGui::RadioButton("composite", &view, 1);
    ImGui::SameLine();
    ImGui::RadioButton("volume", &view, 2);
    if (view != p.view) act.view = view;
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
