// lancet-volume: look inside a CT volume without the visualizer.
//   lancet-volume info SOURCE                    header, geometry, value range and a histogram
//   lancet-volume mesh SOURCE --iso V -o OUT     the isosurface as PLY (.ply) or OBJ (.obj),
//                                                with its topology and size figures
// SOURCE: a MetaImage (.mhd/.mha), an NRRD (.nrrd/.nhdr), a folder of DICOM files, a headerless
// .raw with --dims/--type/--spacing-mm, or "phantom" (the built-in phantom).
// Exit status: 0 done, 1 a check failed (mesh --require-closed), 2 bad input or arguments.

#include <CLI/CLI.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include <unistd.h>

#include "volume/marching_cubes.hpp"
#include "volume/mesh_tools.hpp"
#include "volume/metaimage.hpp"
#include "volume/nrrd.hpp"
#include "volume/dicom.hpp"
#include "volume/phantom.hpp"

namespace {

using namespace lancet;
using namespace lancet::volume;
namespace fs = std::filesystem;

struct Source {
  std::string path;
  std::array<int, 3> dims{0, 0, 0};
  std::string type = "u8";
  std::array<double, 3> spacing_mm{1, 1, 1};
  bool big_endian = false;
  bool resample_uneven = false;
  bool shear_tilted = false;
};

bool ends_with(const std::string& s, const char* suffix) {
  const std::string x(suffix);
  return s.size() >= x.size() && std::equal(x.rbegin(), x.rend(), s.rbegin(), [](char a, char b) { return std::tolower(a) == b; });
}

Result<Volume> load(const Source& src, std::vector<std::uint8_t>* labels, std::string& format) {
  // Progress on a terminal only (a log or a pipe gets the result alone).
  const bool tty = isatty(2) != 0;
  const Progress progress = tty ? Progress([](double f) { std::fprintf(stderr, "\rloading %3.0f%%", f * 100); }) : Progress();
  Result<Volume> r = Error{ErrorCode::kInvalid, ""};
  if (src.path == "phantom") {
    format = "built-in phantom";
    Phantom ph = make_phantom(PhantomParams{});
    if (labels != nullptr) *labels = std::move(ph.material);
    return std::move(ph.volume);
  }
  if (fs::is_directory(src.path)) {
    format = "DICOM series";
    DicomOptions o;
    o.resample_uneven = src.resample_uneven;
    o.shear_tilted = src.shear_tilted;
    r = load_dicom_series(src.path, o, progress);
  } else if (ends_with(src.path, ".mhd") || ends_with(src.path, ".mha")) {
    format = "MetaImage";
    r = load_metaimage(src.path, progress);
  } else if (ends_with(src.path, ".nrrd") || ends_with(src.path, ".nhdr")) {
    format = "NRRD";
    r = load_nrrd(src.path, progress);
  } else if (ends_with(src.path, ".raw")) {
    format = "raw";
    if (src.dims[0] <= 0 || src.dims[1] <= 0 || src.dims[2] <= 0)
      return Error{ErrorCode::kInvalid, src.path + ": a .raw file needs --dims NX NY NZ (and --type, --spacing-mm)"};
    VoxelType t{};
    if (src.type == "u8") t = VoxelType::kU8;
    else if (src.type == "i16") t = VoxelType::kI16;
    else if (src.type == "u16") t = VoxelType::kU16;
    else if (src.type == "f32") t = VoxelType::kF32;
    else return Error{ErrorCode::kInvalid, "--type: expected u8, i16, u16 or f32, found '" + src.type + "'"};
    r = load_raw(src.path, src.dims, t, Vec3{src.spacing_mm[0] * 1e-3, src.spacing_mm[1] * 1e-3, src.spacing_mm[2] * 1e-3},
                 src.big_endian, progress);
  } else {
    return Error{ErrorCode::kInvalid, src.path + ": unknown source: expected a .mhd/.mha, .nrrd/.nhdr or .raw file, a DICOM folder, or 'phantom'"};
  }
  if (tty) std::fprintf(stderr, "\r              \r");
  return r;
}

const char* type_name(VoxelType t) {
  switch (t) {
    case VoxelType::kU8: return "u8";
    case VoxelType::kI16: return "i16";
    case VoxelType::kU16: return "u16";
    case VoxelType::kF32: return "f32";
  }
  return "?";
}

int info(const Source& src) {
  std::string format;
  auto r = load(src, nullptr, format);
  if (!r.ok()) {
    std::fprintf(stderr, "lancet-volume: %s\n", r.error().message.c_str());
    return 2;
  }
  const Volume& v = r.value();
  const auto [lo, hi] = std::minmax_element(v.data.begin(), v.data.end());
  double sum = 0;
  for (float x : v.data) sum += x;
  std::printf("source:     %s (%s)\n", src.path.c_str(), format.c_str());
  std::printf("dims:       %d x %d x %d (%zu voxels)\n", v.dims[0], v.dims[1], v.dims[2], v.voxel_count());
  std::printf("voxel type: %s; values in %s\n", type_name(v.source_type), v.value_unit.c_str());
  std::printf("spacing:    %.6g %.6g %.6g mm\n", v.spacing.x * 1e3, v.spacing.y * 1e3, v.spacing.z * 1e3);
  std::printf("origin:     %.6g %.6g %.6g mm\n", v.origin.x * 1e3, v.origin.y * 1e3, v.origin.z * 1e3);
  std::printf("direction:  %g %g %g / %g %g %g / %g %g %g (rows; column a = axis a)\n", v.direction[0], v.direction[1], v.direction[2],
              v.direction[3], v.direction[4], v.direction[5], v.direction[6], v.direction[7], v.direction[8]);
  std::printf("extent:     %.6g x %.6g x %.6g mm\n", (v.dims[0] - 1) * v.spacing.x * 1e3, (v.dims[1] - 1) * v.spacing.y * 1e3,
              (v.dims[2] - 1) * v.spacing.z * 1e3);
  std::printf("values:     min %g, max %g, mean %.6g\n", double(*lo), double(*hi), sum / static_cast<double>(v.voxel_count()));
  // A 16-bin histogram over the value range.
  std::array<std::size_t, 16> bins{};
  const double span = double(*hi) - double(*lo);
  for (float x : v.data) {
    const auto b = span > 0 ? static_cast<std::size_t>(std::min(15.0, (double(x) - double(*lo)) / span * 16)) : 0;
    ++bins[b];
  }
  std::printf("histogram:\n");
  for (std::size_t b = 0; b < 16; ++b)
    std::printf("  [%10.6g, %10.6g) %10zu %5.1f%%\n", double(*lo) + span * double(b) / 16, double(*lo) + span * double(b + 1) / 16, bins[b],
                100.0 * static_cast<double>(bins[b]) / static_cast<double>(v.voxel_count()));
  return 0;
}

int mesh(const Source& src, double iso, bool pad, std::optional<double> pad_value, int threads, const std::string& out,
         bool require_closed) {
  if (!std::isfinite(iso)) {
    std::fprintf(stderr, "lancet-volume: --iso must be finite\n");
    return 2;
  }
  if (!ends_with(out, ".ply") && !ends_with(out, ".obj")) {
    std::fprintf(stderr, "lancet-volume: -o %s: expected a .ply or .obj file name\n", out.c_str());
    return 2;
  }
  std::string format;
  std::vector<std::uint8_t> labels;
  auto r = load(src, &labels, format);
  if (!r.ok()) {
    std::fprintf(stderr, "lancet-volume: %s\n", r.error().message.c_str());
    return 2;
  }
  IsoOptions o;
  o.iso = static_cast<float>(iso);
  o.pad_border = pad;
  if (pad_value) o.pad_value = static_cast<float>(*pad_value);
  o.threads = threads;
  auto s = extract_isosurface(r.value(), o, labels);
  if (!s.ok()) {
    std::fprintf(stderr, "lancet-volume: %s\n", s.error().message.c_str());
    return 2;
  }
  std::size_t refused = 0;
  const IsoMesh m = to_openmesh(s.value(), &refused);
  const MeshStats st = mesh_stats(m);
  auto written = ends_with(out, ".ply") ? write_ply(m, out) : write_obj(m, out);
  if (!written.ok()) {
    std::fprintf(stderr, "lancet-volume: %s\n", written.error().message.c_str());
    return 2;
  }
  std::printf("{\"source\": \"%s\", \"iso\": %g, \"pad\": %s, \"output\": \"%s\", \"vertices\": %zu, \"faces\": %zu, \"edges\": %zu,\n"
              " \"boundary_edges\": %zu, \"non_manifold_vertices\": %zu, \"refused_faces\": %zu, \"degenerate_faces\": %zu,\n"
              " \"components\": %zu, \"euler\": %lld, \"closed\": %s, \"genus\": %lld, \"area_mm2\": %.6f, \"volume_mm3\": %.6f}\n",
              src.path.c_str(), iso, pad ? "true" : "false", out.c_str(), st.vertices, st.faces, st.edges, st.boundary_edges,
              st.non_manifold_vertices, refused, st.degenerate_faces, st.components, st.euler, st.closed() ? "true" : "false",
              st.closed() ? st.genus() : -1LL, st.area * 1e6, st.volume * 1e9);
  if (require_closed && (!st.closed() || refused != 0)) {
    std::fprintf(stderr, "lancet-volume: the surface is not closed (%zu boundary edges, %zu refused faces)\n", st.boundary_edges, refused);
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"lancet-volume: inspect a CT volume and extract its isosurface"};
  app.require_subcommand(1);
  Source src;
  const auto add_source = [&](CLI::App* cmd) {
    cmd->add_option("source", src.path, "a .mhd/.mha, .nrrd/.nhdr or .raw file, a DICOM folder, or 'phantom'")->required();
    cmd->add_option("--dims", src.dims, ".raw only: voxels along x, y, z")->expected(3);
    cmd->add_option("--type", src.type, ".raw only: u8, i16, u16 or f32");
    cmd->add_option("--spacing-mm", src.spacing_mm, ".raw only: voxel spacing")->expected(3);
    cmd->add_flag("--big-endian", src.big_endian, ".raw only: big-endian samples");
    cmd->add_flag("--resample-uneven", src.resample_uneven, "DICOM: resample uneven slice spacing instead of refusing it");
    cmd->add_flag("--shear-tilted", src.shear_tilted, "DICOM: keep a gantry-tilted series as a sheared grid instead of refusing it");
  };
  auto* info_cmd = app.add_subcommand("info", "print the header, geometry, value range and a histogram");
  add_source(info_cmd);
  auto* mesh_cmd = app.add_subcommand("mesh", "extract the isosurface and write it as PLY or OBJ");
  add_source(mesh_cmd);
  double iso = 0;
  bool pad = false, require_closed = false;
  std::optional<double> pad_value;
  int threads = 0;
  std::string out;
  mesh_cmd->add_option("--iso", iso, "isovalue (in the volume's units, HU for CT)")->required();
  mesh_cmd->add_flag("--pad", pad, "pad the border with background so the surface closes at the volume's edge");
  mesh_cmd->add_option("--pad-value", pad_value, "the background for --pad (default: the volume's minimum)");
  mesh_cmd->add_option("--threads", threads, "threads (0: one per hardware thread)")->check(CLI::NonNegativeNumber);
  mesh_cmd->add_option("-o,--output", out, "output .ply or .obj")->required();
  mesh_cmd->add_flag("--require-closed", require_closed, "exit 1 unless the surface is watertight and manifold");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }
  if (pad_value) pad = true;
  if (*info_cmd) return info(src);
  return mesh(src, iso, pad, pad_value, threads, out, require_closed);
}
