#pragma once
// SceneRenderer: draws the tissue surface, the TissuePatch sent to lancet-rt (wireframe), the tool
// (shaft and tip), the proxy and the force arrow into an offscreen framebuffer, which is then
// shown in the window or read back for a screenshot. Needs a current GL 4.5 core context.

#include <glm/glm.hpp>
#include <array>
#include <span>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "render/gl_objects.hpp"
#include "render/image.hpp"
#include "render/volume_raycaster.hpp"
#include "surface/triangle_mesh.hpp"

namespace lancet::render {

/// One hand's tool as drawn: its shaft in the hand's colour (kHandColours).
struct ToolView {
  Vec3 tool{};                 ///< tool tip (m)
  Vec3 proxy{};                ///< proxy (m)
  Vec3 force{};                ///< force on the hand (N)
  bool has_tool = false;
};

/// The shaft's colour of each hand's tool (linear RGB), by Hand: the right hand's steel blue, the
/// left's amber.
inline constexpr float kHandColours[kHandCount][3] = {{0.30f, 0.50f, 0.95f}, {0.95f, 0.60f, 0.15f}};

struct SceneInput {
  std::array<ToolView, kHandCount> tools{};  ///< by Hand
  std::array<const TissuePatch*, kHandCount> patches{};  ///< each drawn as a wireframe when non-null
  float camera_yaw = 0.6f;     ///< rad, about +z
  float camera_pitch = 0.55f;  ///< rad above the surface plane
  float camera_distance = 0.26f;  ///< m
  Vec3 camera_target{};        ///< m, the point the camera looks at and turns about
  /// A guide drawn over the surface (the scenario's incision line, already on the surface), or null.
  const std::vector<Vec3>* guide = nullptr;
  /// The volume, ray cast and composited with the opaque meshes (rays stop at their depth), or null.
  VolumeRaycaster* volume = nullptr;
  std::array<float, 16> volume_to_world{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};  ///< column-major
  volume::RaycastParams volume_params{};
  bool draw_surface = true;    ///< false: the volume alone (the mesh still stops nothing)
};

class SceneRenderer {
 public:
  /// Compiles shaders and allocates a width×height offscreen target. Throws std::runtime_error
  /// (configure time) when GL refuses.
  SceneRenderer(int width, int height);

  /// Replaces the surface mesh on the GPU: indexed (a vertex once, not once per corner), and
  /// only the blocks of vertices, indices and face materials that differ from the last mesh
  /// are sent (a dent or a cut's opening moves a few hundred vertices of a million).
  void set_mesh(const surface::TriangleMesh& mesh);
  /// The blood on the surface mesh's vertices (blood::Bleeding::vertex_blood): depth (m) and
  /// mean age (s) per vertex of the last set_mesh; other sizes: dry. Only changed blocks are sent.
  void set_blood(std::span<const float> depth, std::span<const float> age);
  /// Bytes set_mesh sent to the GPU last time, and what sending everything would have been.
  [[nodiscard]] std::size_t last_upload_bytes() const noexcept { return last_upload_bytes_; }
  [[nodiscard]] std::size_t mesh_bytes() const noexcept;
  /// Resizes the offscreen target.
  void resize(int width, int height);
  /// Draws the scene into the offscreen target; leaves it bound for an overlay to draw on.
  void render(const SceneInput& in);
  /// Copies the offscreen target to the window's framebuffer (w×h pixels).
  void present(int window_width, int window_height) const;
  /// Reads the offscreen target back (top row first).
  [[nodiscard]] Image read_back() const;
  /// Projects the window pixel (x, y) onto the plane z = 0 through the current camera.
  [[nodiscard]] bool pick_plane(double x, double y, int window_width, int window_height, Vec3& out) const;
  [[nodiscard]] int width() const noexcept { return width_; }
  [[nodiscard]] int height() const noexcept { return height_; }

 private:
  struct GpuMesh {
    VertexArray vao;
    Buffer vbo;
    GLsizei count = 0;
  };
  static GpuMesh upload(const std::vector<float>& interleaved);
  void draw(const GpuMesh& m, GLenum primitive, GLint first, GLsizei count, const glm::mat4& model, glm::vec3 color,
            int mode) const;

  int width_, height_;
  Program program_;
  Framebuffer fbo_;
  Renderbuffer color_;
  Texture depth_;           ///< a texture, so the volume's rays can stop at the meshes
  Program composite_;       ///< draws the volume's premultiplied image over the meshes
  VertexArray empty_vao_;
  GpuMesh sphere_, cylinder_;
  // The surface: indexed, its face materials in a storage buffer read by gl_PrimitiveID; the
  // CPU copies are what the GPU holds, to find what changed.
  struct SurfaceBuffers {
    VertexArray vao;
    Buffer vertices, indices, materials, blood;
    std::vector<float> v;           ///< position and normal per vertex
    std::vector<float> b;           ///< blood depth and age per vertex
    std::vector<std::uint32_t> i;   ///< 3 per face
    std::vector<std::uint32_t> m;   ///< material per face
  } surface_;
  std::size_t last_upload_bytes_ = 0;
  GpuMesh lines_;
  glm::mat4 view_{1.0f}, proj_{1.0f};
};

}  // namespace lancet::render
