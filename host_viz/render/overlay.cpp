#include "render/overlay.hpp"

#include <imgui.h>
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

void Overlay::build(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height) {
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
  ImGui::Render();
}

void Overlay::layout(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height) {
  build(title, lines, width, height);
}

void Overlay::draw(const std::string& title, const std::vector<OverlayLine>& lines, int width, int height) {
  build(title, lines, width, height);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
}

bool Overlay::wants_mouse() const { return glfw_ && ImGui::GetIO().WantCaptureMouse; }

}  // namespace lancet::render
