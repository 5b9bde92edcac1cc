#include "tissue/scenario_scene.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <system_error>
#include <utility>

#include "volume/dicom.hpp"
#include "volume/metaimage.hpp"
#include "volume/nrrd.hpp"
#include "volume/phantom.hpp"

namespace lancet::tissue {
namespace {

bool ends_with(const std::string& s, const char* tail) {
  const std::string t = tail;
  return s.size() >= t.size() && std::equal(t.rbegin(), t.rend(), s.rbegin(), [](char a, char b) {
           return std::tolower(static_cast<unsigned char>(a)) == std::tolower(static_cast<unsigned char>(b));
         });
}

}  // namespace

Result<volume::Volume> load_ct(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return Error{ErrorCode::kNotFound, path + ": not found"};
  if (std::filesystem::is_directory(path, ec)) return volume::load_dicom_series(path);
  if (ends_with(path, ".mhd") || ends_with(path, ".mha")) return volume::load_metaimage(path);
  if (ends_with(path, ".nrrd") || ends_with(path, ".nhdr")) return volume::load_nrrd(path);
  return Error{ErrorCode::kInvalid, path + ": unknown volume format: expected a DICOM directory, .mhd, .mha, .nrrd or .nhdr"};
}

Result<SceneDescription> scene_description(const scenario::Scenario& s, const std::string& volume_override) {
  SceneDescription d;
  const scenario::Tissue& t = s.tissue;
  if (!volume_override.empty() && t.source != scenario::TissueSource::kFile)
    return Error{ErrorCode::kInvalid, s.file + ": --volume " + volume_override + ": this scenario's tissue is the built-in " +
                                          std::string(scenario::source_key(t.source)) + ", not a file"};
  switch (t.source) {
    case scenario::TissueSource::kBlock: d.source = SceneSource::kBlock; break;
    case scenario::TissueSource::kPhantom: d.source = SceneSource::kPhantom; break;
    case scenario::TissueSource::kFile: {
      const std::string path = volume_override.empty() ? t.volume_path : volume_override;
      if (path.empty())
        return Error{ErrorCode::kInvalid, s.file + ": tissue.source = \"file\" names no path: give the CT with --volume PATH"};
      auto v = load_ct(path);
      if (!v.ok()) return Error{v.error().code, "--volume: " + v.error().message};
      d.source = SceneSource::kVolume;
      d.volume.volume = std::move(v).value();
      break;
    }
  }
  d.skin_iso = t.skin_iso;
  d.bone_iso = t.bone_iso;
  d.surface = t.surface == scenario::SurfaceKind::kBone ? SceneSurface::kBone : SceneSurface::kSkin;
  d.axis = t.axis;
  d.sign = t.sign;
  d.cut_depth = t.cut_depth;
  return d;
}

}  // namespace lancet::tissue
