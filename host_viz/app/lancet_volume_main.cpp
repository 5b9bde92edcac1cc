// lancet-volume: look inside a CT volume without the visualizer.
//   lancet-volume info SOURCE                    header, geometry, value range and a histogram
//   lancet-volume mesh SOURCE --iso V -o OUT     the isosurface as PLY (.ply) or OBJ (.obj), in mm
//                                                (--units m for metres), with its topology and
//                                                size figures as JSON on stdout
// SOURCE: a MetaImage (.mhd/.mha), an NRRD (.nrrd/.nhdr), a folder of DICOM files, a headerless
// .raw with --dims/--type/--spacing-mm, or "phantom" (the built-in phantom).
// What the loader skipped or inferred is printed to stderr as "lancet-volume: warning: ...".
// Exit status: 0 done, 1 a check failed (mesh --require-closed), 2 bad input or arguments.

#include <CLI/CLI.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <new>
#include <optional>
#include <string>
#include <string_view>

#include <unistd.h>

#include "app/tool_main.hpp"
#include "text/text.hpp"
#include "volume/dicom.hpp"
#include "volume/marching_cubes.hpp"
#include "volume/mesh_tools.hpp"
#include "volume/metaimage.hpp"
#include "volume/nonfinite.hpp"
#include "volume/nrrd.hpp"
#include "volume/phantom.hpp"

namespace text = lancet::text;

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
  bool allow_gaps = false;
};

bool ends_with(const std::string& s, const char* suffix) {
  const std::string x(suffix);
  return s.size() >= x.size() && std::equal(x.rbegin(), x.rend(), s.rbegin(), [](char a, char b) { return std::tolower(a) == b; });
}

int fail(const std::string& message) {
  std::fprintf(stderr, "lancet-volume: %s\n", message.c_str());
  return 2;
}

// ---- JSON: strings escaped, numbers finite ----------------------------------------------------


// Builds a flat JSON object; a number that is not finite makes finish() an error instead of
// writing nan or inf (which are not JSON).
class JsonObject {
 public:
  void add(const char* key, std::string_view value) { field(key, text::json_string(value)); }
  void add(const char* key, const char* value) { field(key, text::json_string(value)); }
  void add(const char* key, bool value) { field(key, value ? "true" : "false"); }
  void add(const char* key, std::size_t value) { field(key, std::to_string(value)); }
  void add(const char* key, long long value) { field(key, std::to_string(value)); }
  void add(const char* key, double value) {
    if (!std::isfinite(value)) {
      if (bad_.empty()) bad_ = key;
      field(key, "null");
      return;
    }
    field(key, text::format("%.10g", value));
  }
  /// The object, or the name of the first number that was not finite.
  [[nodiscard]] Result<std::string> finish() const {
    if (!bad_.empty()) return Error{ErrorCode::kInvalid, "\"" + bad_ + "\" is not a finite number"};
    return "{" + body_ + "}";
  }

 private:
  void field(const char* key, const std::string& value) { body_ += (body_.empty() ? "" : ", ") + text::json_string(key) + ": " + value; }
  std::string body_;
  std::string bad_;
};

// ---- loading --------------------------------------------------------------------------------------

Result<Volume> load(const Source& src, std::vector<std::uint8_t>* labels, std::string& format) {
  if (src.path == "phantom") {
    format = "built-in phantom";
    LabelledVolume ph = make_phantom(PhantomParams{});
    if (labels != nullptr) *labels = std::move(ph.material);
    return std::move(ph.volume);
  }
  std::error_code ec;
  if (!fs::exists(src.path, ec)) return Error{ErrorCode::kNotFound, src.path + ": not found"};
  // Progress on a terminal only (a log or a pipe gets the result alone).
  const bool tty = isatty(2) != 0;
  const Progress progress = tty ? Progress([](double f) { std::fprintf(stderr, "\rloading %3.0f%%", f * 100); }) : Progress();
  Result<Volume> r = Error{ErrorCode::kInvalid, ""};
  if (fs::is_directory(src.path, ec)) {
    format = "DICOM series";
    DicomOptions o;
    o.resample_uneven = src.resample_uneven;
    o.shear_tilted = src.shear_tilted;
    o.allow_gaps = src.allow_gaps;
    o.names = {"--resample-uneven", "--shear-tilted", "--allow-gaps"};
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
  if (r.ok()) {
    for (const std::string& w : r.value().warnings) std::fprintf(stderr, "lancet-volume: warning: %s\n", w.c_str());
  }
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

// "HU" for CT; "value" otherwise (the file's own numbers).
const char* value_label(const Volume& v) { return v.value_unit == "HU" ? "HU" : "value"; }

std::string voxel_text(const Volume& v, std::size_t index) {
  const auto nx = static_cast<std::size_t>(v.dims[0]), ny = static_cast<std::size_t>(v.dims[1]);
  return "(" + std::to_string(index % nx) + ", " + std::to_string((index / nx) % ny) + ", " + std::to_string(index / (nx * ny)) + ")";
}

// ---- info -------------------------------------------------------------------------------------------

int info(const Source& src) {
  std::string format;
  auto r = load(src, nullptr, format);
  if (!r.ok()) return fail(r.error().message);
  const Volume& v = r.value();
  const NonFiniteVoxels bad = count_nonfinite(v);
  // The range, mean and histogram of the finite values.
  float lo = 0, hi = 0;
  double sum = 0;
  std::size_t finite = 0;
  for (float x : v.data) {
    if (!std::isfinite(x)) continue;
    if (finite == 0 || x < lo) lo = x;
    if (finite == 0 || x > hi) hi = x;
    sum += x;
    ++finite;
  }
  const char* unit = value_label(v);
  std::printf("source:     %s (%s)\n", src.path.c_str(), format.c_str());
  std::printf("dims:       %d x %d x %d (%zu voxels)\n", v.dims[0], v.dims[1], v.dims[2], v.voxel_count());
  if (v.value_unit == "HU") {
    std::printf("voxel type: %s; values in HU (modality %s)\n", type_name(v.source_type), v.modality.empty() ? "CT" : v.modality.c_str());
  } else {
    std::printf("voxel type: %s; values as stored, not HU (modality %s)\n", type_name(v.source_type),
                v.modality.empty() ? "not given" : v.modality.c_str());
  }
  std::printf("spacing:    %.6g %.6g %.6g mm\n", v.spacing.x * 1e3, v.spacing.y * 1e3, v.spacing.z * 1e3);
  std::printf("origin:     %.6g %.6g %.6g mm\n", v.origin.x * 1e3, v.origin.y * 1e3, v.origin.z * 1e3);
  std::printf("direction:  %g %g %g / %g %g %g / %g %g %g (rows; column a = axis a)\n", v.direction[0], v.direction[1], v.direction[2],
              v.direction[3], v.direction[4], v.direction[5], v.direction[6], v.direction[7], v.direction[8]);
  std::printf("extent:     %.6g x %.6g x %.6g mm\n", (v.dims[0] - 1) * v.spacing.x * 1e3, (v.dims[1] - 1) * v.spacing.y * 1e3,
              (v.dims[2] - 1) * v.spacing.z * 1e3);
  std::printf("non-finite: %zu NaN, %zu infinite voxels", bad.nan, bad.infinite);
  if (bad.total() > 0) {
    std::printf(" (first at voxel %s): left out of the values below; mesh refuses them unless --nan-as VALUE",
                voxel_text(v, bad.first).c_str());
  }
  std::printf("\n");
  if (finite == 0) {
    std::printf("values:     none finite\n");
    return 0;
  }
  std::printf("values:     min %g, max %g, mean %.6g (%s)\n", double(lo), double(hi), sum / static_cast<double>(finite), unit);
  // A 16-bin histogram over the finite value range.
  std::array<std::size_t, 16> bins{};
  const double span = double(hi) - double(lo);
  for (float x : v.data) {
    if (!std::isfinite(x)) continue;
    const auto b = span > 0 ? static_cast<std::size_t>(std::min(15.0, (double(x) - double(lo)) / span * 16)) : 0;
    ++bins[b];
  }
  std::printf("histogram (%s):\n", unit);
  for (std::size_t b = 0; b < 16; ++b)
    std::printf("  [%10.6g, %10.6g) %10zu %5.1f%%\n", double(lo) + span * double(b) / 16, double(lo) + span * double(b + 1) / 16, bins[b],
                100.0 * static_cast<double>(bins[b]) / static_cast<double>(finite));
  return 0;
}

// ---- mesh -------------------------------------------------------------------------------------------

struct MeshArgs {
  double iso = 0;
  bool pad = false;
  std::optional<double> pad_value;
  std::optional<double> nan_as;
  int threads = 0;
  std::string out;
  std::string units = "mm";
  bool require_closed = false;
};

int mesh(const Source& src, const MeshArgs& a) {
  if (!std::isfinite(a.iso)) return fail("--iso: expected a finite number, found " + std::to_string(a.iso));
  if (a.pad_value && !std::isfinite(*a.pad_value)) return fail("--pad-value: expected a finite number");
  if (a.nan_as && !std::isfinite(*a.nan_as)) return fail("--nan-as: expected a finite number");
  if (!ends_with(a.out, ".ply") && !ends_with(a.out, ".obj")) return fail("-o " + a.out + ": expected a .ply or .obj file name");
  std::string format;
  std::vector<std::uint8_t> labels;
  auto r = load(src, &labels, format);
  if (!r.ok()) return fail(r.error().message);
  Volume& v = r.value();

  const NonFiniteVoxels bad = count_nonfinite(v);
  if (bad.total() > 0) {
    if (!a.nan_as) {
      return fail(src.path + ": " + std::to_string(bad.nan) + " NaN and " + std::to_string(bad.infinite) +
                  " infinite voxels (the first at voxel " + voxel_text(v, bad.first) +
                  "): a surface through them is not defined; --nan-as VALUE replaces them with VALUE before meshing");
    }
    replace_nonfinite(v, static_cast<float>(*a.nan_as));
    std::fprintf(stderr, "lancet-volume: replaced %zu NaN and %zu infinite voxels with %g (--nan-as)\n", bad.nan, bad.infinite, *a.nan_as);
  }
  if (!a.pad && (v.dims[0] < 2 || v.dims[1] < 2 || v.dims[2] < 2)) {
    return fail(src.path + ": " + std::to_string(v.dims[0]) + " x " + std::to_string(v.dims[1]) + " x " + std::to_string(v.dims[2]) +
                " voxels: a surface needs at least 2 voxels along each axis; --pad surrounds the volume with background");
  }
  IsoOptions o;
  o.iso = static_cast<float>(a.iso);
  o.pad_border = a.pad;
  if (a.pad_value) o.pad_value = static_cast<float>(*a.pad_value);
  o.threads = a.threads;
  auto s = extract_isosurface(v, o, labels);
  if (!s.ok()) return fail(s.error().message);
  std::size_t refused = 0;
  const IsoMesh m = to_openmesh(s.value(), &refused);
  const MeshStats st = mesh_stats(m);
  const LengthUnit unit = a.units == "m" ? LengthUnit::kMetre : LengthUnit::kMillimetre;
  JsonObject j;
  j.add("source", src.path);
  j.add("iso", a.iso);
  j.add("iso_unit", value_label(v));
  j.add("pad", a.pad);
  j.add("output", a.out);
  j.add("units", unit_name(unit));
  j.add("vertices", st.vertices);
  j.add("faces", st.faces);
  j.add("edges", st.edges);
  j.add("boundary_edges", st.boundary_edges);
  j.add("non_manifold_vertices", st.non_manifold_vertices);
  j.add("refused_faces", refused);
  j.add("degenerate_faces", st.degenerate_faces);
  j.add("components", st.components);
  j.add("euler", st.euler);
  j.add("closed", st.closed());
  j.add("genus", st.closed() ? st.genus() : -1LL);
  j.add("area_mm2", st.area * 1e6);
  j.add("volume_mm3", st.volume * 1e9);
  auto json = j.finish();
  if (!json.ok()) return fail("the surface's figures are not finite (" + json.error().message + "); no file written");
  auto written = ends_with(a.out, ".ply") ? write_ply(m, a.out, unit) : write_obj(m, a.out, unit);
  if (!written.ok()) return fail(written.error().message);
  std::printf("%s\n", json.value().c_str());
  if (a.require_closed && (!st.closed() || refused != 0)) {
    std::fprintf(stderr, "lancet-volume: the surface is not closed (%zu boundary edges, %zu refused faces)\n", st.boundary_edges, refused);
    return 1;
  }
  return 0;
}

int run(int argc, char** argv) {
  CLI::App app{"lancet-volume: inspect a CT volume and extract its isosurface"};
  app.require_subcommand(1);
  Source src;
  const auto add_source = [&](CLI::App* cmd) {
    cmd->add_option("source", src.path, "a .mhd/.mha, .nrrd/.nhdr or .raw file, a DICOM folder, or 'phantom'")->required();
    cmd->add_option("--dims", src.dims, ".raw only: voxels along x, y, z");  // std::array: CLI11 takes exactly 3
    cmd->add_option("--type", src.type, ".raw only: u8, i16, u16 or f32");
    cmd->add_option("--spacing-mm", src.spacing_mm, ".raw only: voxel spacing");
    cmd->add_flag("--big-endian", src.big_endian, ".raw only: big-endian samples");
    cmd->add_flag("--resample-uneven", src.resample_uneven, "DICOM: resample uneven slice spacing instead of refusing it");
    cmd->add_flag("--allow-gaps", src.allow_gaps,
                  "DICOM, with --resample-uneven: also interpolate across gaps (a step over 1.5x the spacing around it, e.g. a missing slice)");
    cmd->add_flag("--shear-tilted", src.shear_tilted, "DICOM: keep a gantry-tilted series as a sheared grid instead of refusing it");
  };
  auto* info_cmd = app.add_subcommand("info", "print the header, geometry, value range and a histogram");
  add_source(info_cmd);
  auto* mesh_cmd = app.add_subcommand("mesh", "extract the isosurface and write it as PLY or OBJ");
  add_source(mesh_cmd);
  MeshArgs a;
  mesh_cmd->add_option("--iso", a.iso, "isovalue, in the volume's values (HU for CT)")->required();
  mesh_cmd->add_flag("--pad", a.pad, "pad the border with background so the surface closes at the volume's edge");
  mesh_cmd->add_option("--pad-value", a.pad_value, "the background for --pad (default: the volume's smallest finite value)");
  mesh_cmd->add_option("--nan-as", a.nan_as, "replace NaN and infinite voxels with this value before meshing (default: refuse them)");
  mesh_cmd->add_option("--threads", a.threads, "threads (0: one per hardware thread)")->check(CLI::Range(0, 256));
  mesh_cmd->add_option("-o,--output", a.out, "output .ply or .obj")->required();
  mesh_cmd->add_option("--units", a.units, "length unit of the file: mm (default; 3D Slicer, ITK, VTK) or m")
      ->check(CLI::IsMember({"mm", "m"}));
  mesh_cmd->add_flag("--require-closed", a.require_closed, "exit 1 unless the surface is watertight and manifold");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  }
  if (a.pad_value) a.pad = true;
  if (*info_cmd) return info(src);
  return mesh(src, a);
}

}  // namespace

int main(int argc, char** argv) {
  return lancet::app::guarded_main([&] { return run(argc, argv); }, [](const std::string& m) { return fail(m); });
}
