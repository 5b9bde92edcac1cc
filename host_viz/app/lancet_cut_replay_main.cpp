// lancet-cut-replay: replays a scripted cut on a surface mesh, headless, and writes the mesh before
// and after (OBJ, PLY, OFF or STL through OpenMesh IO) so a person can open both in a mesh viewer.
//   lancet-cut-replay SCRIPT --before before.ply --after after.obj
// The script, one command a line (lengths in mm, '#' starts a comment):
//   mesh sheet CELLS SIZE        a wavy sheet of CELLS×CELLS cells, SIZE mm across
//   mesh phantom ISO             the built-in phantom's isosurface at ISO HU (padded: closed)
//   mesh file PATH               a mesh file OpenMesh reads (relative to the script's folder), in
//                                millimetres like every mesh file written (--units m: metres)
//   press X Y Z DEPTH            a dent at the surface point nearest (X, Y, Z), DEPTH mm along −normal
//   relax SECONDS                let dents and wrinkles return for that long
//   cut X Y Z                    start a cut at the surface point nearest (X, Y, Z)
//   to X Y Z                     extend the cut to there
//   end                          end the cut
//   open WIDTH                   open the newest cut to WIDTH mm (within the elastic limit)
//   pull DISTANCE                pull the newest cut open by DISTANCE mm (opening and wrinkle)
// `mesh` must come first. Exit status: 0 done, 2 bad script, arguments or files (the message
// names the file, line and what was expected).

#include <OpenMesh/Core/IO/MeshIO.hh>  // before any mesh type (OpenMesh's rule)

#include <CLI/CLI.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "surface/placeholder_mesh.hpp"
#include "surface/surface_model.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/phantom.hpp"

namespace {

using namespace lancet;
namespace fs = std::filesystem;

struct ScriptError {
  std::string message;
};

/// Metres per unit of the mesh files read and written: millimetres unless --units m, as
/// lancet-volume writes them and as 3D Slicer, ITK and VTK pipelines expect.
double g_file_unit = 1e-3;

std::unique_ptr<surface::SurfaceModel> make_mesh(const std::vector<std::string>& w, const fs::path& dir) {
  const auto need = [&](std::size_t n, const char* form) {
    if (w.size() != n) throw ScriptError{std::string("expected '") + form + "'"};
  };
  if (w.size() < 2) throw ScriptError{"expected 'mesh sheet CELLS SIZE', 'mesh phantom ISO' or 'mesh file PATH'"};
  std::vector<Vec3f> positions;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  std::vector<std::uint16_t> material;
  if (w[1] == "sheet") {
    need(4, "mesh sheet CELLS SIZE");
    surface::TissueBlockParams p;
    p.cells = std::stoi(w[2]);
    p.half_extent = std::stod(w[3]) * 1e-3 / 2;
    if (p.cells < 1 || p.cells > 4000 || !(p.half_extent > 0)) throw ScriptError{"sheet: CELLS must be 1..4000 and SIZE > 0"};
    const auto m = surface::make_tissue_block(p);
    positions = m.vertices;
    triangles = m.triangles;
    material = m.material;
  } else if (w[1] == "phantom") {
    need(3, "mesh phantom ISO");
    const auto ph = volume::make_phantom(volume::PhantomParams{});
    volume::IsoOptions o;
    o.iso = std::stof(w[2]);
    o.pad_border = true;
    auto s = volume::extract_isosurface(ph.volume, o, ph.material);
    if (!s.ok()) throw ScriptError{s.error().message};
    positions = s.value().positions;
    triangles = s.value().triangles;
    for (const auto& t : triangles) material.push_back(s.value().material[t[0]]);
  } else if (w[1] == "file") {
    need(3, "mesh file PATH");
    const fs::path path = fs::path(w[2]).is_absolute() ? fs::path(w[2]) : dir / w[2];
    OpenMesh::TriMesh_ArrayKernelT<> m;
    if (!OpenMesh::IO::read_mesh(m, path.string())) throw ScriptError{"cannot read the mesh " + path.string()};
    const auto u = static_cast<float>(g_file_unit);
    for (auto v : m.vertices()) {
      const auto& q = m.point(v);
      if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2]))
        throw ScriptError{path.string() + ": vertex " + std::to_string(v.idx()) + " is not finite"};
      positions.push_back({q[0] * u, q[1] * u, q[2] * u});
    }
    for (auto f : m.faces()) {
      std::array<std::uint32_t, 3> t{};
      int n = 0;
      for (auto v : m.fv_range(f)) {
        if (n < 3) t[static_cast<std::size_t>(n)] = static_cast<std::uint32_t>(v.idx());
        ++n;
      }
      if (n != 3) throw ScriptError{path.string() + ": face " + std::to_string(f.idx()) + " has " + std::to_string(n) + " corners; triangles only"};
      triangles.push_back(t);
    }
  } else {
    throw ScriptError{"unknown mesh kind '" + w[1] + "': expected sheet, phantom or file"};
  }
  auto model = surface::SurfaceModel::create(positions, triangles, material);
  if (!model.ok()) throw ScriptError{model.error().message};
  return std::move(model).value();
}

bool write(const surface::SurfaceModel& model, const std::string& path) {
  surface::SurfaceMesh copy = model.mesh();
  copy.garbage_collection();  // drop the faces cuts re-added under new handles
  const auto per_unit = static_cast<float>(1.0 / g_file_unit);
  for (auto v : copy.vertices()) copy.set_point(v, copy.point(v) * per_unit);
  OpenMesh::IO::Options opt = OpenMesh::IO::Options::VertexNormal;
  if (path.size() >= 4 && (path.substr(path.size() - 4) == ".obj" || path.substr(path.size() - 4) == ".ply"))
    opt += OpenMesh::IO::Options::VertexTexCoord;
  return OpenMesh::IO::write_mesh(copy, path, opt);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"lancet-cut-replay: replay a scripted cut on a surface mesh and write it before and after"};
  std::string script, before, after;
  app.add_option("script", script, "the cut script (see the header of lancet_cut_replay_main.cpp or the README)")->required();
  app.add_option("--before", before, "write the mesh before the first cut here (.obj, .ply, .off, .stl)");
  app.add_option("--after", after, "write the mesh after the script here")->required();
  std::string units = "mm";
  app.add_option("--units", units, "length unit of the mesh files read ('mesh file') and written")
      ->check(CLI::IsMember({"mm", "m"}))
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }
  g_file_unit = units == "m" ? 1.0 : 1e-3;
  std::ifstream in(script);
  if (!in) {
    std::fprintf(stderr, "lancet-cut-replay: %s: cannot open\n", script.c_str());
    return 2;
  }
  const fs::path dir = fs::path(script).parent_path();
  std::unique_ptr<surface::SurfaceModel> model;
  bool wrote_before = before.empty();
  std::string line;
  int line_no = 0;
  std::size_t steps = 0, crossings = 0;
  try {
    while (std::getline(in, line)) {
      ++line_no;
      if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
      std::istringstream ss(line);
      std::vector<std::string> w;
      for (std::string x; ss >> x;) w.push_back(x);
      if (w.empty()) continue;
      const auto num = [&](std::size_t i) {
        std::size_t used = 0;
        double v = 0;
        try {
          v = std::stod(w.at(i), &used);
        } catch (const std::exception&) {
          used = 0;
        }
        if (used == 0 || used != w.at(i).size() || !std::isfinite(v)) throw ScriptError{"'" + w[i] + "' is not a number"};
        return v;
      };
      const auto args = [&](std::size_t n, const char* form) {
        if (w.size() != n + 1) throw ScriptError{std::string("expected '") + form + "', found " + std::to_string(w.size() - 1) + " values"};
        if (!model) throw ScriptError{"'mesh' must come before '" + w[0] + "'"};
      };
      const auto point = [&] { return Vec3{num(1) * 1e-3, num(2) * 1e-3, num(3) * 1e-3}; };
      const std::string& cmd = w[0];
      if (cmd == "mesh") {
        if (model) throw ScriptError{"only one 'mesh' per script"};
        try {
          model = make_mesh(w, dir);
        } catch (const std::invalid_argument&) {
          throw ScriptError{"expected numbers after 'mesh " + (w.size() > 1 ? w[1] : std::string()) + "'"};
        }
      } else if (cmd == "press") {
        args(4, "press X Y Z DEPTH");
        Vec3 p = point();
        const auto hit = model->bvh().closest_point(model->view(), to_vec3f(p));
        if (!hit) throw ScriptError{"the mesh is empty"};
        const auto& t = model->faces()[hit->face];
        const Vec3 n = normalized(cross(model->position(t[1]) - model->position(t[0]), model->position(t[2]) - model->position(t[0])));
        model->update_contact(surface::Contact{to_vec3(hit->point), -1.0 * n, num(4) * 1e-3}, 0.0);
      } else if (cmd == "relax") {
        args(1, "relax SECONDS");
        for (double t = 0; t < num(1); t += 0.01) {
          model->update_contact(std::nullopt, 0.01);
          model->relax(0.01);
        }
      } else if (cmd == "cut") {
        args(3, "cut X Y Z");
        if (!wrote_before) {
          if (!write(*model, before)) throw ScriptError{"cannot write " + before};
          wrote_before = true;
        }
        if (!model->begin_cut(point(), 0.01)) throw ScriptError{"the cut's start is more than 10 mm from the surface"};
      } else if (cmd == "to") {
        args(3, "to X Y Z");
        if (!model->cutting()) throw ScriptError{"'to' outside a cut: start one with 'cut X Y Z'"};
        crossings += model->cut_to(point()).crossings;
        ++steps;
      } else if (cmd == "end") {
        args(0, "end");
        model->end_cut();
      } else if (cmd == "open" || cmd == "pull") {
        args(1, cmd == "open" ? "open WIDTH" : "pull DISTANCE");
        if (model->cuts().empty()) throw ScriptError{"'" + cmd + "' before any cut"};
        const double d = num(1) * 1e-3;
        if (d < 0) throw ScriptError{"expected a width >= 0"};
        if (cmd == "open") (void)model->set_opening(model->cuts().size() - 1, d);
        else (void)model->pull(model->cuts().size() - 1, d);
      } else {
        throw ScriptError{"unknown command '" + cmd + "': expected mesh, press, relax, cut, to, end, open or pull"};
      }
    }
    if (!model) throw ScriptError{"the script has no 'mesh' line"};
  } catch (const ScriptError& e) {
    std::fprintf(stderr, "lancet-cut-replay: %s:%d: %s\n", script.c_str(), line_no, e.message.c_str());
    return 2;
  }
  if (model->cutting()) model->end_cut();
  if (!wrote_before && !write(*model, before)) {
    std::fprintf(stderr, "lancet-cut-replay: cannot write %s\n", before.c_str());
    return 2;
  }
  if (!write(*model, after)) {
    std::fprintf(stderr, "lancet-cut-replay: cannot write %s\n", after.c_str());
    return 2;
  }
  const auto st = model->stats();
  std::size_t pairs = 0;
  for (const auto& c : model->cuts()) pairs += c.pairs.size();
  std::printf("{\"cuts\": %zu, \"steps\": %zu, \"crossings\": %zu, \"split_vertices\": %zu, \"faces\": %zu, \"vertices\": %zu, "
              "\"boundary_edges\": %zu, \"non_manifold_vertices\": %zu, \"flipped_faces\": %zu, \"after\": \"%s\"}\n",
              model->cuts().size(), steps, crossings, pairs, st.faces, st.vertices, st.boundary_edges, st.non_manifold_vertices,
              st.flipped_faces, after.c_str());
  return 0;
}
