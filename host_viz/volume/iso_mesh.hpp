#pragma once
// IsoMesh: the OpenMesh triangle mesh that marching cubes fills (host_viz/volume). Points and
// normals in metres as floats; status attributes so that local re-extraction can delete faces;
// three custom properties:
//   material  (vertex, uint8)  material id taken from the volume on the inside of the vertex's edge
//   edge_key  (vertex, uint64) the grid edge the vertex lies on: node index · 3 + axis, in the
//                              extraction grid (the padded grid when the border is padded)
//   cube      (face, uint32)   the grid cube that produced the face
// Allocating; not for the real-time path.

#include <cstdint>

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

namespace lancet::volume {

struct IsoMeshTraits : public OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3f;
  using Normal = OpenMesh::Vec3f;
  VertexAttributes(OpenMesh::Attributes::Normal | OpenMesh::Attributes::Status);
  HalfedgeAttributes(OpenMesh::Attributes::PrevHalfedge | OpenMesh::Attributes::Status);
  EdgeAttributes(OpenMesh::Attributes::Status);
  FaceAttributes(OpenMesh::Attributes::Status);
};

class IsoMesh : public OpenMesh::TriMesh_ArrayKernelT<IsoMeshTraits> {
 public:
  IsoMesh() {
    add_property(material_);
    add_property(edge_key_);
    add_property(cube_);
  }

  [[nodiscard]] std::uint8_t material(VertexHandle v) const { return property(material_, v); }
  [[nodiscard]] std::uint64_t edge_key(VertexHandle v) const { return property(edge_key_, v); }
  [[nodiscard]] std::uint32_t cube(FaceHandle f) const { return property(cube_, f); }
  void set_material(VertexHandle v, std::uint8_t m) { property(material_, v) = m; }
  void set_edge_key(VertexHandle v, std::uint64_t k) { property(edge_key_, v) = k; }
  void set_cube(FaceHandle f, std::uint32_t c) { property(cube_, f) = c; }

 private:
  OpenMesh::VPropHandleT<std::uint8_t> material_;
  OpenMesh::VPropHandleT<std::uint64_t> edge_key_;
  OpenMesh::FPropHandleT<std::uint32_t> cube_;
};

}  // namespace lancet::volume
