// lancet-bench-volume: marching cubes throughput on the real foot and chest volumes, single- and
// multi-threaded, side by side with VTK's vtkFlyingEdges3D and vtkMarchingCubes in the same run
// (through tests/vtk/vtk_isosurface.py and Debian's python3-vtk9, when present); the OpenMesh
// build; local re-extraction after a 5 mm drill; and loader throughput. Prints one JSON object.
//   lancet-bench-volume [--quick] [--data DIR] [--no-vtk]

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "surface/surface_model.hpp"
#include "tissue/tissue_scene.hpp"
#include "volume/drill.hpp"
#include "volume/live_isosurface.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/metaimage.hpp"
#include "volume/nrrd.hpp"

namespace {

using namespace lancet;
using namespace lancet::volume;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

template <class F>
double best_of(int repeat, F&& f) {
  double best = 1e300;
  for (int r = 0; r < repeat; ++r) {
    const auto t0 = Clock::now();
    f();
    best = std::min(best, seconds_since(t0));
  }
  return best;
}

// The best of `repeat` runs of make(), the object it made destroyed after the clock stops: the
// job is making it (freeing a 200 MB mesh is not what a user waits for before cutting).
template <class F>
double best_of_made(int repeat, F&& make) {
  double best = 1e300;
  for (int r = 0; r < repeat; ++r) {
    const auto t0 = Clock::now();
    auto made = make();
    best = std::min(best, seconds_since(t0));
  }
  return best;
}

std::string run_capture(const std::string& cmd) {
  std::string out;
  FILE* p = popen(cmd.c_str(), "r");
  if (p == nullptr) return out;
  char buf[4096];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) out.append(buf, n);
  if (pclose(p) != 0) return {};
  return out;
}

// The number after "key": in the object that follows "section": (a tiny reader for our own JSON).
double json_field(const std::string& json, const std::string& section, const std::string& key) {
  std::size_t at = 0;
  if (!section.empty()) {
    at = json.find("\"" + section + "\"");
    if (at == std::string::npos) return NAN;
  }
  const std::size_t k = json.find("\"" + key + "\"", at);
  if (k == std::string::npos) return NAN;
  const std::size_t colon = json.find(':', k);
  return std::strtod(json.c_str() + colon + 1, nullptr);
}

struct Case {
  const char* name;
  const char* file;
  float iso;
};

}  // namespace

int main(int argc, char** argv) {
  bool quick = false, vtk = true;
  std::string data = std::string(LANCET_SOURCE_DIR) + "/../shared/data/volumes";
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) quick = true;
    else if (std::strcmp(argv[i], "--no-vtk") == 0) vtk = false;
    else if (std::strcmp(argv[i], "--data") == 0 && i + 1 < argc) data = argv[++i];
    else {
      std::fprintf(stderr, "usage: lancet-bench-volume [--quick] [--data DIR] [--no-vtk]\n");
      return 2;
    }
  }
  const int repeat = quick ? 1 : 5;
  const int hw = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const std::string script = std::string(LANCET_SOURCE_DIR) + "/tests/vtk/vtk_isosurface.py";
  const bool have_vtk = vtk && std::system("/usr/bin/python3 -c 'import vtk' >/dev/null 2>&1") == 0;

  // Isovalues with a .5 so that no voxel equals them (integer data): every tool then makes the
  // same non-degenerate triangles and the counts compare directly.
  const std::vector<Case> cases = {
      {"foot_skin", "foot_ct_lossy/foot_256x256x256_uint8_zfplossy.mhd", 60.5f},
      {"foot_bone", "foot_ct_lossy/foot_256x256x256_uint8_zfplossy.mhd", 120.5f},
      {"chest_body", "chest_ct_lidc2/LIDC2_256x256x133_uint8.mhd", 100.5f},
  };

  std::printf("{\n  \"hardware_threads\": %d,\n  \"vtk\": %s,\n  \"marching_cubes\": [\n", hw, have_vtk ? "true" : "false");
  for (std::size_t c = 0; c < cases.size(); ++c) {
    const auto path = data + "/" + cases[c].file;
    auto loaded = load_metaimage(path);
    if (!loaded.ok()) {
      std::fprintf(stderr, "%s\n", loaded.error().message.c_str());
      return 2;
    }
    const Volume& v = loaded.value();
    const double voxels = static_cast<double>(v.voxel_count());
    const double t_read = best_of_made(repeat, [&] { return load_metaimage(path); });
    IsoOptions o;
    o.iso = cases[c].iso;
    std::size_t triangles = 0;
    o.threads = 1;
    const double t1 = best_of(repeat, [&] { triangles = extract_isosurface(v, o).value().triangles.size(); });
    o.threads = hw;
    const double tn = best_of_made(repeat, [&] { return extract_isosurface(v, o); });
    const IsoSurface s = extract_isosurface(v, o).value();
    // The half-edge mesh: built at once (to_openmesh, volume/halfedge_build.hpp) and, for the
    // record, the old way, one add_face a triangle; then the cuttable skin the scene cuts
    // (surface::SurfaceModel, built the same way).
    const double t_mesh = best_of(quick ? 1 : 2, [&] { IsoMesh m = to_openmesh(s); });
    const double t_add_face = best_of(1, [&] {
      IsoMesh m;
      std::vector<IsoMesh::VertexHandle> vh(s.positions.size());
      for (std::size_t i = 0; i < vh.size(); ++i) vh[i] = m.add_vertex(IsoMesh::Point(s.positions[i].x, s.positions[i].y, s.positions[i].z));
      for (const auto& t : s.triangles) (void)m.add_face(vh[t[0]], vh[t[1]], vh[t[2]]);
    });
    const double t_surface = best_of_made(quick ? 1 : 2, [&] { return surface::SurfaceModel::create(s.positions, s.triangles, {}); });
    // The skin's extraction as the scene makes it (tissue_scene.cpp): without gradient normals,
    // which the surface model does not take (it makes its own from its faces).
    IsoOptions skin = o;
    skin.normals = false;
    const double t_skin = best_of_made(repeat, [&] { return extract_isosurface(v, skin); });
    // Then as TissueScene::create goes on: the skin placed in the world (tissue::place_skin, which
    // takes the isosurface's arrays) and handed over to the surface model (no copies). Each run
    // works on a fresh copy of the skin, made outside the clock.
    const IsoSurface skin_surface = extract_isosurface(v, skin).value();
    double t_place = 1e300, t_handed = 1e300;
    for (int r = 0; r < (quick ? 1 : 2); ++r) {
      IsoSurface fresh = skin_surface;
      tissue::VolumePlacement placement;
      placement.axis = {0, 2, 1};
      placement.sign = {1, -1, 1};  // a turn that flips handedness, as the CT scenario's axes do
      auto t0 = Clock::now();
      surface::TriangleMesh placed = tissue::place_skin(std::move(fresh), v, placement);
      t_place = std::min(t_place, seconds_since(t0));
      t0 = Clock::now();
      const auto model = surface::SurfaceModel::create(std::move(placed));
      t_handed = std::min(t_handed, seconds_since(t0));
      if (!model.ok()) std::fprintf(stderr, "error: %s\n", model.error().message.c_str());
    }
    const double end_to_end = t_read + t_skin + t_place + t_handed;
    // The tool's first touch on a fresh model: the faces a 40 mm patch asks for (its radius plus
    // the dent's reach, as patch_export does) around a face in the middle of the list. On a large
    // skin this is where the lazy BVH makes its first blocks, so it is timed apart and added to
    // the end to end below for a second ratio.
    double t_touch = 1e300;
    std::size_t touch_faces = 0, touch_blocks = 0, blocks = 0;
    for (int r = 0; r < (quick ? 1 : 2) && !s.triangles.empty(); ++r) {
      const auto model = surface::SurfaceModel::create(s.positions, s.triangles, {}).value();
      const auto& t = s.triangles[s.triangles.size() / 2];
      const Vec3f p{(s.positions[t[0]].x + s.positions[t[1]].x + s.positions[t[2]].x) / 3,
                    (s.positions[t[0]].y + s.positions[t[1]].y + s.positions[t[2]].y) / 3,
                    (s.positions[t[0]].z + s.positions[t[1]].z + s.positions[t[2]].z) / 3};
      std::vector<std::uint32_t> near;
      const auto t0 = Clock::now();
      model->bvh().faces_in_boxes_within(model->view(), p, static_cast<float>(0.040 + model->params().deform_max_depth), near);
      t_touch = std::min(t_touch, seconds_since(t0));
      touch_faces = near.size();
      touch_blocks = model->bvh().blocks_made();
      blocks = model->bvh().block_count();
    }
    std::printf("    {\"case\": \"%s\", \"file\": \"%s\", \"iso\": %.1f, \"voxels\": %.0f, \"triangles\": %zu,\n", cases[c].name,
                cases[c].file, double(cases[c].iso), voxels, triangles);
    std::printf("     \"lancet_1_thread\": {\"seconds\": %.5f, \"voxels_per_second\": %.4g},\n", t1, voxels / t1);
    std::printf("     \"lancet_%d_threads\": {\"seconds\": %.5f, \"voxels_per_second\": %.4g},\n", hw, tn, voxels / tn);
    std::printf("     \"openmesh_build\": {\"seconds\": %.5f, \"faces_per_second\": %.4g},\n", t_mesh, static_cast<double>(triangles) / t_mesh);
    std::printf("     \"openmesh_add_face\": {\"seconds\": %.5f, \"faces_per_second\": %.4g, \"direct_speedup\": %.2f},\n", t_add_face,
                static_cast<double>(triangles) / t_add_face, t_add_face / t_mesh);
    std::printf("     \"read_s\": %.5f, \"extract_without_normals_s\": %.5f, \"place_skin_s\": %.5f, \"surface_model_handed_over_s\": %.5f, "
                "\"end_to_end_s\": %.5f, \"surface_model_from_spans_s\": %.5f,\n",
                t_read, t_skin, t_place, t_handed, end_to_end, t_surface);
    std::printf("     \"first_touch\": {\"seconds\": %.5f, \"faces\": %zu, \"bvh_blocks_made\": %zu, \"bvh_blocks\": %zu}", t_touch, touch_faces,
                touch_blocks, blocks);
    if (have_vtk) {
      char iso[32];
      std::snprintf(iso, sizeof iso, "%.1f", double(cases[c].iso));
      const std::string base = "/usr/bin/python3 " + script + " " + path + " --iso " + iso + " --repeat " + std::to_string(repeat) + " --quick";
      const std::string one = run_capture(base + " --threads 1");
      const std::string many = run_capture(base + " --threads 0");
      const double fe1 = json_field(one, "flying_edges", "seconds"), mc1 = json_field(one, "marching_cubes", "seconds");
      const double fen = json_field(many, "flying_edges", "seconds");
      // VTK doing the whole job ours does, on two threads: read, flying edges with normals,
      // BuildLinks (the connectivity), vtkStaticCellLocator::BuildLocator (the search structure).
      const std::string job = run_capture(base + " --threads 2 --same-job");
      const double job_s = json_field(job, "same_job", "seconds");
      std::printf(",\n     \"vtk_same_job_2_threads\": {\"read_s\": %.5f, \"flying_edges_normals_s\": %.5f, \"build_links_s\": %.5f, "
                  "\"static_cell_locator_s\": %.5f, \"seconds\": %.5f},\n     \"end_to_end_over_vtk_same_job\": %.2f, "
                  "\"end_to_end_and_first_touch_over_vtk_same_job\": %.2f",
                  json_field(job, "same_job", "read_s"), json_field(job, "same_job", "flying_edges_normals_s"),
                  json_field(job, "same_job", "build_links_s"), json_field(job, "same_job", "static_cell_locator_s"), job_s,
                  end_to_end / job_s, (end_to_end + t_touch) / job_s);
      std::printf(",\n     \"vtk_flying_edges_1_thread\": {\"seconds\": %.5f, \"voxels_per_second\": %.4g, \"triangles\": %.0f},\n", fe1,
                  voxels / fe1, json_field(one, "flying_edges", "triangles"));
      std::printf("     \"vtk_flying_edges_default_threads\": {\"seconds\": %.5f, \"voxels_per_second\": %.4g},\n", fen, voxels / fen);
      std::printf("     \"vtk_marching_cubes\": {\"seconds\": %.5f, \"voxels_per_second\": %.4g, \"triangles\": %.0f},\n", mc1, voxels / mc1,
                  json_field(one, "marching_cubes", "triangles"));
      std::printf("     \"ratio_vs_flying_edges_1_thread\": %.3f, \"ratio_vs_vtk_marching_cubes\": %.3f, "
                  "\"ratio_multi_vs_flying_edges_default\": %.3f,\n     \"end_to_end_over_vtk_flying_edges_default\": %.2f}",
                  fe1 / t1, mc1 / t1, fen / tn, end_to_end / fen);
    } else {
      std::printf("}");
    }
    std::printf("%s\n", c + 1 < cases.size() ? "," : "");
  }
  std::printf("  ],\n");

  // Local re-extraction after a 5 mm drill into the foot's bone (1 mm voxels).
  {
    auto loaded = load_metaimage(data + "/" + cases[0].file);
    Volume v = std::move(loaded).value();
    IsoOptions o;
    o.iso = 120.5f;
    o.pad_border = true;
    auto live = LiveIsosurface::create(v, o).value();
    std::vector<double> times;
    std::size_t faces = 0;
    // Burr centres on the surface: the vertices of the initial mesh, spread over it.
    const auto& m = live->mesh();
    const std::size_t step = std::max<std::size_t>(1, m.n_vertices() / (quick ? 20 : 200));
    std::vector<Vec3> centres;
    for (std::size_t i = 0; i < m.n_vertices(); i += step) {
      const auto p = m.point(IsoMesh::VertexHandle(static_cast<int>(i)));
      centres.push_back({p[0], p[1], p[2]});
    }
    double drill_s = 0;
    for (const Vec3& c : centres) {
      DrillParams dp;
      dp.centre = c;
      dp.radius = 0.0025;
      dp.empty_value = 0;
      dp.material_above = 60;
      auto t0 = Clock::now();
      auto d = drill_sphere(v, dp).value();
      drill_s += seconds_since(t0);
      t0 = Clock::now();
      auto u = live->update(v, d.dirty).value();
      times.push_back(seconds_since(t0));
      faces += u.faces_added;
    }
    std::sort(times.begin(), times.end());
    const auto pct = [&](double q) { return times[static_cast<std::size_t>(q * static_cast<double>(times.size() - 1))] * 1e3; };
    std::printf("  \"reextract_after_5mm_drill\": {\"volume\": \"foot\", \"iso\": 120.5, \"drills\": %zu, \"p50_ms\": %.3f, \"p90_ms\": %.3f, "
                "\"max_ms\": %.3f, \"mean_faces_added\": %.0f, \"drill_mean_ms\": %.3f},\n",
                times.size(), pct(0.5), pct(0.9), times.back() * 1e3, static_cast<double>(faces) / static_cast<double>(times.size()),
                drill_s / static_cast<double>(times.size()) * 1e3);
  }

  // Loader throughput (MB/s of voxel data delivered as floats).
  std::printf("  \"loaders\": [\n");
  const std::vector<std::pair<const char*, std::string>> loads = {
      {"metaimage_raw_foot_u8", data + "/foot_ct_lossy/foot_256x256x256_uint8_zfplossy.mhd"},
      {"metaimage_zlib_chest_u8", data + "/chest_ct_lidc2/LIDC2.mha"},
      {"nrrd_raw_tooth_u8", data + "/tooth_ct/tooth.nrrd"},
      {"nrrd_slices_headsq_i16", data + "/head_ct_headsq/original/quarter.nhdr"},
  };
  for (std::size_t i = 0; i < loads.size(); ++i) {
    std::size_t n = 0;
    const bool nrrd = loads[i].second.find(".nrrd") != std::string::npos || loads[i].second.find(".nhdr") != std::string::npos;
    const double t = best_of(repeat, [&] { n = (nrrd ? load_nrrd(loads[i].second) : load_metaimage(loads[i].second)).value().voxel_count(); });
    std::printf("    {\"case\": \"%s\", \"voxels\": %zu, \"seconds\": %.5f, \"voxels_per_second\": %.4g}%s\n", loads[i].first, n, t,
                static_cast<double>(n) / t, i + 1 < loads.size() ? "," : "");
  }
  std::printf("  ]\n}\n");
  return 0;
}
