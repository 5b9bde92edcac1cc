// lancet-cut-script: replays a scripted hand on the tissue scene, headless, and writes the surface
// before and after (OBJ, PLY, OFF or STL through OpenMesh IO) so a person can open both in a mesh
// viewer. Each command becomes the ToolSamples lancet-rt would send (1 ms apart, fed in frames of
// 16 as lancet-viz drains them) and goes through tissue::TissueScene, the visualizer's own path:
// the dent, the rupture, the cut growing by cut-progress events every 0.5 mm, its groove in the
// volume, the pull, the drill.
//   lancet-cut-script SCRIPT --before before.ply --after after.obj
// The script, one command a line (lengths in mm, '#' starts a comment):
//   mesh sheet CELLS SIZE        a wavy sheet of CELLS×CELLS cells, SIZE mm across, over layered tissue
//   mesh phantom ISO             the built-in phantom's skin at ISO HU (its volume beneath)
//   mesh file PATH               a mesh file OpenMesh reads (relative to the script's folder), in
//                                millimetres like every mesh file written (--units m: metres); a
//                                surface alone: no volume, so no groove and no drill
//   tool NAME                    probe, scalpel, retractor or drill: the mode of the samples that follow
//   press X Y Z DEPTH            a dent at the surface point nearest (X, Y, Z), DEPTH mm along −normal
//   relax SECONDS                let dents and wrinkles return for that long
//   cut X Y Z                    the skin ruptures at the surface point nearest (X, Y, Z): a cut starts
//   to X Y Z                     the blade moves to there (cut progress every 0.5 mm)
//   end                          the blade leaves: the cut ends and reaches into the volume
//   open WIDTH                   the retractor holds the newest cut open at WIDTH mm (its wrinkle relaxed)
//   pull DISTANCE                the retractor pulls the newest cut DISTANCE mm open (opening and wrinkle)
//   drill X Y Z RADIUS           the burr removes the voxels within RADIUS mm (0 < RADIUS <= 10) of (X, Y, Z)
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

#include "tissue/scripted_sample.hpp"
#include "tissue/tissue_scene.hpp"
#include "surface/triangle_mesh.hpp"
#include "surface/surface_model.hpp"

namespace {

using namespace lancet;
namespace fs = std::filesystem;

struct ScriptError {
  std::string message;
};

/// Metres per unit of the mesh files read and written: millimetres unless --units m, as
/// lancet-volume writes them and as 3D Slicer, ITK and VTK pipelines expect.
double g_file_unit = 1e-3;

std::unique_ptr<tissue::TissueScene> make_scene(const std::vector<std::string>& w, const fs::path& dir) {
  const auto need = [&](std::size_t n, const char* form) {
    if (w.size() != n) throw ScriptError{std::string("expected '") + form + "'"};
  };
  if (w.size() < 2) throw ScriptError{"expected 'mesh sheet CELLS SIZE', 'mesh phantom ISO' or 'mesh file PATH'"};
  tissue::SceneDescription d;
  if (w[1] == "sheet") {
    need(4, "mesh sheet CELLS SIZE");
    d.source = tissue::SceneSource::kBlock;
    d.block.cells = std::stoi(w[2]);
    d.block.half_extent = std::stod(w[3]) * 1e-3 / 2;
    if (d.block.cells < 1 || d.block.cells > 4000 || !(d.block.half_extent > 0) || d.block.half_extent > 0.25)
      throw ScriptError{"sheet: CELLS must be 1..4000 and SIZE in (0, 500] mm"};
  } else if (w[1] == "phantom") {
    need(3, "mesh phantom ISO");
    d.source = tissue::SceneSource::kPhantom;
    d.skin_iso = std::stof(w[2]);
  } else if (w[1] == "file") {
    need(3, "mesh file PATH");
    d.source = tissue::SceneSource::kMesh;
    const fs::path path = fs::path(w[2]).is_absolute() ? fs::path(w[2]) : dir / w[2];
    OpenMesh::TriMesh_ArrayKernelT<> m;
    if (!OpenMesh::IO::read_mesh(m, path.string())) throw ScriptError{"cannot read the mesh " + path.string()};
    const auto u = static_cast<float>(g_file_unit);
    for (auto v : m.vertices()) {
      const auto& q = m.point(v);
      if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2]))
        throw ScriptError{path.string() + ": vertex " + std::to_string(v.idx()) + " is not finite"};
      d.mesh.vertices.push_back({q[0] * u, q[1] * u, q[2] * u});
    }
    for (auto f : m.faces()) {
      std::array<std::uint32_t, 3> t{};
      int n = 0;
      for (auto v : m.fv_range(f)) {
        if (n < 3) t[static_cast<std::size_t>(n)] = static_cast<std::uint32_t>(v.idx());
        ++n;
      }
      if (n != 3) throw ScriptError{path.string() + ": face " + std::to_string(f.idx()) + " has " + std::to_string(n) + " corners; triangles only"};
      d.mesh.triangles.push_back(t);
    }
  } else {
    throw ScriptError{"unknown mesh kind '" + w[1] + "': expected sheet, phantom or file"};
  }
  auto scene = tissue::TissueScene::create(std::move(d));
  if (!scene.ok()) throw ScriptError{scene.error().message};
  return std::move(scene).value();
}

// The hand: ToolSamples 1 ms apart (or dt_ms), fed to the scene in frames of 16.
struct ScriptHand {
  tissue::TissueScene* scene = nullptr;
  ToolMode mode = ToolMode::kProbe;
  std::uint64_t seq = 0;
  std::vector<ToolSample> pending;
  ToolSample& add(Stage stage, Vec3 proxy, Vec3 tool, std::uint32_t events = 0, std::int64_t dt_ms = 1) {
    const std::int64_t t_ns = (pending.empty() ? last_t_ns : pending.back().t_ns) + dt_ms * 1'000'000;
    pending.push_back(tissue::scripted_sample(++seq, t_ns, mode, stage, proxy, tool, events));
    return pending.back();
  }
  void flush() {
    for (std::size_t i = 0; i < pending.size(); i += 16)
      (void)scene->apply(std::span<const ToolSample>(pending).subspan(i, std::min<std::size_t>(16, pending.size() - i)));
    if (!pending.empty()) last_t_ns = pending.back().t_ns;
    pending.clear();
  }
  std::int64_t last_t_ns = 0;
};

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

// The result on stdout, one JSON line: the cuts, the mesh's health, the grooves, the drilling.
void print_summary(const tissue::TissueScene& scene, std::size_t steps, const std::string& after) {
  const surface::SurfaceModel& model = scene.surface();
  const auto st = model.stats();
  std::size_t pairs = 0;
  for (const auto& c : model.cuts()) pairs += c.pairs.size();
  const auto cuts = scene.cut_figures();
  const auto grooves = scene.grooves();
  std::printf("{\"cuts\": %zu, \"steps\": %zu, \"split_vertices\": %zu, \"longest_cut_mm\": %.2f, \"opening_mm\": %.2f, "
              "\"faces\": %zu, \"vertices\": %zu, \"boundary_edges\": %zu, \"non_manifold_vertices\": %zu, \"flipped_faces\": %zu, "
              "\"grooves\": %zu, \"groove_width_mm\": %.2f, \"groove_depth_mm\": %.2f, \"voxels_drilled\": %llu, \"after\": \"%s\"}\n",
              model.cuts().size(), steps, pairs, cuts.longest * 1e3, cuts.opening * 1e3, st.faces, st.vertices, st.boundary_edges,
              st.non_manifold_vertices, st.flipped_faces, grooves.size(), grooves.empty() ? 0.0 : grooves.back().top_gap * 1e3,
              grooves.empty() ? 0.0 : grooves.back().depth * 1e3, static_cast<unsigned long long>(scene.events().voxels_drilled),
              after.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"lancet-cut-script: replay a scripted cut on a surface mesh and write it before and after"};
  std::string script, before, after;
  app.add_option("script", script, "the cut script (see the header of lancet_cut_script_main.cpp or the README)")->required();
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
    std::fprintf(stderr, "lancet-cut-script: %s: cannot open\n", script.c_str());
    return 2;
  }
  const fs::path dir = fs::path(script).parent_path();
  std::unique_ptr<tissue::TissueScene> scene;
  ScriptHand hand;
  Vec3 blade{};  // where the blade is while cutting
  bool wrote_before = before.empty();
  std::string line;
  int line_no = 0;
  std::size_t steps = 0;
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
        if (!scene) throw ScriptError{"'mesh' must come before '" + w[0] + "'"};
      };
      const auto point = [&] { return Vec3{num(1) * 1e-3, num(2) * 1e-3, num(3) * 1e-3}; };
      const std::string& cmd = w[0];
      if (cmd == "mesh") {
        if (scene) throw ScriptError{"only one 'mesh' per script"};
        try {
          scene = make_scene(w, dir);
        } catch (const std::invalid_argument&) {
          throw ScriptError{"expected numbers after 'mesh " + (w.size() > 1 ? w[1] : std::string()) + "'"};
        }
        hand.scene = scene.get();
      } else if (cmd == "tool") {
        args(1, "tool NAME");
        if (!tool_from_name(w[1], hand.mode)) throw ScriptError{"unknown tool '" + w[1] + "': expected probe, scalpel, retractor or drill"};
      } else if (cmd == "press") {
        args(4, "press X Y Z DEPTH");
        const surface::SurfaceModel& model = scene->surface();
        const auto hit = model.bvh().closest_point(model.view(), to_vec3f(point()));
        if (!hit) throw ScriptError{"the mesh is empty"};
        const auto& t = model.faces()[hit->face];
        const Vec3 n = normalized(cross(model.position(t[1]) - model.position(t[0]), model.position(t[2]) - model.position(t[0])));
        const Vec3 at = to_vec3(hit->point);
        hand.add(Stage::kDeform, at, at - (num(4) * 1e-3) * n, event::kContactBegin);
      } else if (cmd == "relax") {
        args(1, "relax SECONDS");
        for (double t = 0; t < num(1); t += 0.01) hand.add(Stage::kFree, blade + Vec3{0, 0, 0.05}, blade + Vec3{0, 0, 0.05}, 0, 10);
      } else if (cmd == "cut") {
        args(3, "cut X Y Z");
        hand.flush();
        if (!wrote_before) {
          if (!write(scene->surface(), before)) throw ScriptError{"cannot write " + before};
          wrote_before = true;
        }
        blade = point();
        hand.add(Stage::kRupture, blade, blade, event::kRupture);
        hand.flush();
        if (!scene->surface().cutting()) throw ScriptError{"the cut's start is more than 5 mm from the surface"};
      } else if (cmd == "to") {
        args(3, "to X Y Z");
        if (!scene->surface().cutting()) throw ScriptError{"'to' outside a cut: start one with 'cut X Y Z'"};
        // The blade at 0.1 mm a tick; lancet-rt reports progress every 0.5 mm of its travel.
        const Vec3 from = blade, to = point();
        const int ticks = std::max(1, static_cast<int>(std::ceil(norm(to - from) / 1e-4)));
        for (int i = 1; i <= ticks; ++i) {
          const Vec3 p = from + (static_cast<double>(i) / ticks) * (to - from);
          hand.add(Stage::kCutting, p, p, i % 5 == 0 || i == ticks ? event::kCutProgress : 0u);
        }
        blade = to;
        ++steps;
      } else if (cmd == "end") {
        args(0, "end");
        hand.add(Stage::kFree, blade + Vec3{0, 0, 0.01}, blade + Vec3{0, 0, 0.01}, event::kContactEnd);
      } else if (cmd == "open" || cmd == "pull") {
        args(1, cmd == "open" ? "open WIDTH" : "pull DISTANCE");
        hand.flush();
        if (scene->surface().cuts().empty()) throw ScriptError{"'" + cmd + "' before any cut"};
        const double d = num(1) * 1e-3;
        if (d < 0) throw ScriptError{"expected a width >= 0"};
        hand.add(Stage::kPulling, blade, blade, event::kPull).payload.magnitude = d;
        if (cmd == "open")  // held there while the wrinkle relaxes
          for (int i = 0; i < 200; ++i) hand.add(Stage::kPulling, blade, blade, 0, 10);
      } else if (cmd == "drill") {
        args(4, "drill X Y Z RADIUS");
        const double r = num(4) * 1e-3;
        if (!(r > 0 && r <= 0.01)) throw ScriptError{"expected a radius in (0, 10] mm"};
        ToolSample& t = hand.add(Stage::kFree, point(), point(), event::kDrillRemove);
        t.payload.magnitude = r;
      } else {
        throw ScriptError{"unknown command '" + cmd + "': expected mesh, tool, press, relax, cut, to, end, open, pull or drill"};
      }
    }
    if (!scene) throw ScriptError{"the script has no 'mesh' line"};
    hand.add(Stage::kFree, blade + Vec3{0, 0, 0.05}, blade + Vec3{0, 0, 0.05});  // the hand leaves
    hand.flush();
  } catch (const ScriptError& e) {
    std::fprintf(stderr, "lancet-cut-script: %s:%d: %s\n", script.c_str(), line_no, e.message.c_str());
    return 2;
  }
  const surface::SurfaceModel& model = scene->surface();
  if (!wrote_before && !write(model, before)) {
    std::fprintf(stderr, "lancet-cut-script: cannot write %s\n", before.c_str());
    return 2;
  }
  if (!write(model, after)) {
    std::fprintf(stderr, "lancet-cut-script: cannot write %s\n", after.c_str());
    return 2;
  }
  print_summary(*scene, steps, after);
  return 0;
}
