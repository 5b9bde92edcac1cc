#pragma once
// Checks and files for IsoMesh: topology and size figures (watertight, manifold, genus, area,
// enclosed volume, degenerate faces) and PLY / OBJ output (millimetres by default) so a person
// can inspect a surface.
// Deleted elements (after local re-extraction) are skipped everywhere.

#include <cstddef>
#include <cstdint>
#include <string>

#include "lancet/shared_model/result.hpp"
#include "volume/iso_mesh.hpp"

namespace lancet::volume {

struct MeshStats {
  std::size_t vertices = 0, faces = 0, edges = 0;
  std::size_t boundary_edges = 0;         ///< 0 for a watertight surface
  std::size_t isolated_vertices = 0;
  std::size_t non_manifold_vertices = 0;  ///< vertices whose faces do not form one fan
  std::size_t degenerate_faces = 0;       ///< zero area or a repeated vertex
  std::size_t components = 0;             ///< connected pieces (by shared edges)
  long long euler = 0;                    ///< V − E + F; 2·components − 2·Σgenus when closed
  double area = 0;                        ///< m²
  double volume = 0;                      ///< m³, signed: positive when faces wind outward
  double min_face_area = 0;               ///< m²

  [[nodiscard]] bool closed() const noexcept { return boundary_edges == 0 && non_manifold_vertices == 0; }
  /// Σ genus over components, valid for a closed surface.
  [[nodiscard]] long long genus() const noexcept { return (2 * static_cast<long long>(components) - euler) / 2; }
};

[[nodiscard]] MeshStats mesh_stats(const IsoMesh& mesh);

/// The length unit of a mesh file's positions. IsoMesh holds metres; files default to millimetres,
/// the unit 3D Slicer, ITK and VTK pipelines for medical data expect.
enum class LengthUnit : std::uint8_t { kMillimetre, kMetre };

/// "mm" or "m", as written in the files' unit comments.
[[nodiscard]] const char* unit_name(LengthUnit unit) noexcept;

/// Binary little-endian PLY with positions (in `unit`), normals and a uchar "material" per vertex.
/// The header says the unit: `comment units mm` (or `m`). Returns the number of faces written; a
/// file that cannot be written is a kSystem error naming it.
[[nodiscard]] Result<std::size_t> write_ply(const IsoMesh& mesh, const std::string& path,
                                            LengthUnit unit = LengthUnit::kMillimetre);
/// Wavefront OBJ with positions (in `unit`) and normals (materials are not representable per
/// vertex). The first lines say the unit: `# units: mm` (or `m`).
[[nodiscard]] Result<std::size_t> write_obj(const IsoMesh& mesh, const std::string& path,
                                            LengthUnit unit = LengthUnit::kMillimetre);

}  // namespace lancet::volume
