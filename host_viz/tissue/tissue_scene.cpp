#include "tissue/tissue_scene.hpp"

#include <algorithm>
#include <limits>
#include <cmath>
#include <cstdio>
#include <map>
#include <tuple>
#include <utility>

#include "tissue/block_volume.hpp"
#include "volume/chainmail.hpp"
#include "volume/drill.hpp"
#include "volume/in_two_halves.hpp"
#include "volume/marching_cubes.hpp"

namespace lancet::tissue {
namespace {

double at(const Vec3& v, int a) noexcept { return a == 0 ? v.x : a == 1 ? v.y : v.z; }
double& at(Vec3& v, int a) noexcept { return a == 0 ? v.x : a == 1 ? v.y : v.z; }
std::size_t u(int i) noexcept { return static_cast<std::size_t>(i); }

Error invalid(std::string message) { return Error{ErrorCode::kInvalid, "tissue scene: " + std::move(message)}; }

// +1 when the placement keeps handedness (triangles stay counter-clockwise from outside).
int handedness(const VolumePlacement& p) {
  int inversions = 0;
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b)
      if (p.axis[u(a)] > p.axis[u(b)]) ++inversions;
  const int s = p.sign[0] * p.sign[1] * p.sign[2];
  return (inversions % 2 == 0 ? 1 : -1) * s;
}

// The live bone surface (OpenMesh, volume frame, with deleted elements) as a compact world mesh,
// turned into the world by the placement.
surface::TriangleMesh to_world(const volume::IsoMesh& mesh, const VolumePlacement& placement) {
  surface::TriangleMesh m;
  const VolumePlacement turn{placement.axis, placement.sign, {}};
  std::vector<std::uint32_t> remap(mesh.n_vertices(), UINT32_MAX);
  const bool flip = handedness(placement) < 0;
  for (auto fh : mesh.faces()) {
    if (mesh.status(fh).deleted()) continue;
    std::array<std::uint32_t, 3> t{};
    int c = 0;
    for (auto vh : mesh.fv_range(fh)) {
      std::uint32_t& r = remap[vh.idx()];
      if (r == UINT32_MAX) {
        r = static_cast<std::uint32_t>(m.vertices.size());
        const auto& p = mesh.point(vh);
        const auto& n = mesh.normal(vh);
        m.vertices.push_back(to_vec3f(placement.to_world(Vec3{p[0], p[1], p[2]})));
        m.normals.push_back(to_vec3f(turn.to_world(Vec3{n[0], n[1], n[2]})));
      }
      t[u(c++)] = r;
    }
    if (flip) std::swap(t[1], t[2]);
    m.triangles.push_back(t);
    m.material.push_back(mesh.material(*mesh.fv_range(fh).begin()));
  }
  return m;
}

// box becomes the smallest box holding both it and more (an empty one holds nothing).
void grow(volume::VoxelBox& box, const volume::VoxelBox& more) {
  if (more.empty()) return;
  if (box.empty()) {
    box = more;
    return;
  }
  for (std::size_t a = 0; a < 3; ++a) {
    box.lo[a] = std::min(box.lo[a], more.lo[a]);
    box.hi[a] = std::max(box.hi[a], more.hi[a]);
  }
}

volume::IsoOptions iso_options(float iso) {
  volume::IsoOptions o;
  o.iso = iso;
  o.pad_border = true;
  o.pad_value = -1000;
  return o;
}

// ChainMail behaviour per material label (PhantomMaterial): soft tissue stretches, compresses
// and shears (so a groove's walls close as a V below the held lips); bone barely moves.
std::vector<volume::ChainMailMaterial> chainmail_materials(Vec3 spacing) {
  using volume::ChainMailMaterial;
  const ChainMailMaterial soft = ChainMailMaterial::relative(spacing, 0.6, 1.5, 0.6);
  const ChainMailMaterial bone = ChainMailMaterial::relative(spacing, 0.02, 0.02, 0.02);
  std::vector<ChainMailMaterial> m(8, soft);
  m[volume::kAir] = ChainMailMaterial::air();
  m[volume::kCorticalBone] = bone;
  m[volume::kMarrow] = bone;
  return m;
}
constexpr std::uint8_t kChainMailLabels = 8;

}  // namespace

std::vector<std::uint8_t> labels_from_hu(const volume::Volume& v, float skin_iso, float bone_iso) {
  std::vector<std::uint8_t> labels(v.data.size());
  for (std::size_t i = 0; i < v.data.size(); ++i) {
    const float h = v.data[i];
    labels[i] = !(h >= skin_iso) ? volume::kAir : h >= bone_iso ? volume::kCorticalBone : volume::kMuscle;
  }
  return labels;
}

// The groove under one surface cut.
struct TissueScene::Groove {
  std::size_t surface_cut = 0;
  volume::ChainMailCut cut;
  double width = 0;             // opened to, m
  std::uint64_t conflicts = 0;
};

TissueScene::TissueScene() = default;
TissueScene::~TissueScene() = default;

surface::TriangleMesh place_skin(volume::IsoSurface&& iso, const volume::Volume& v, VolumePlacement& placement) {
  const std::size_t nv = iso.positions.size();
  const bool two = volume::worth_two_threads(iso.triangles.size());
  const Vec3 centre = placement.to_world(v.position(0.5 * (v.dims[0] - 1), 0.5 * (v.dims[1] - 1), 0.5 * (v.dims[2] - 1)));
  double top[2] = {-1e30, -1e30};
  volume::in_two_halves(nv, two, [&](std::size_t begin, std::size_t end, int half) {
    for (std::size_t i = begin; i < end; ++i) top[half] = std::max(top[half], placement.to_world(to_vec3(iso.positions[i])).z);
  });
  placement.offset = {-centre.x, -centre.y, -std::max(top[0], top[1])};
  surface::TriangleMesh m;
  m.vertices = std::move(iso.positions);
  m.triangles = std::move(iso.triangles);
  const bool flip = handedness(placement) < 0;
  volume::in_two_halves(nv, two, [&](std::size_t begin, std::size_t end, int) {
    for (std::size_t i = begin; i < end; ++i) m.vertices[i] = to_vec3f(placement.to_world(to_vec3(m.vertices[i])));
  });
  if (flip)
    volume::in_two_halves(m.triangles.size(), two, [&](std::size_t begin, std::size_t end, int) {
      for (std::size_t f = begin; f < end; ++f) std::swap(m.triangles[f][1], m.triangles[f][2]);
    });
  m.material.assign(m.triangles.size(), static_cast<std::uint16_t>(volume::kSkin));  // by definition
  return m;
}

Result<std::unique_ptr<TissueScene>> TissueScene::create(SceneDescription d) {
  std::unique_ptr<TissueScene> s(new TissueScene());
  surface::TriangleMesh skin;
  switch (d.source) {
    case SceneSource::kBlock:
      s->tissue_ = make_block_volume(d.block);
      s->placement_ = {};  // the block's volume is made in the world
      break;
    case SceneSource::kPhantom:
      s->tissue_ = volume::make_phantom(volume::PhantomParams{});
      d.axis = {2, 0, 1};  // world (x, y, z) = volume (z, x, y): the limb along x, its front up
      d.sign = {1, 1, 1};
      break;
    case SceneSource::kVolume:
      s->tissue_ = std::move(d.volume);
      d.volume = {};
      break;
    case SceneSource::kMesh: {
      if (d.surface != SceneSurface::kSkin) return invalid("a mesh without a volume has no bone to expose");
      auto model = surface::SurfaceModel::create(d.mesh.vertices, d.mesh.triangles, d.mesh.material, d.surface_params);
      if (!model.ok()) return invalid(model.error().message);
      s->surface_ = std::move(model).value();
      d.mesh = {};
      s->desc_ = std::move(d);
      return s;
    }
  }
  volume::LabelledVolume& t = s->tissue_;
  if (t.volume.data.empty() || t.volume.voxel_count() != t.volume.data.size())
    return invalid("the volume is empty or its data does not match its dimensions");
  if (!t.material.empty() && t.material.size() != t.volume.data.size())
    return invalid("the labels (" + std::to_string(t.material.size()) + ") do not match the voxels (" +
                   std::to_string(t.volume.data.size()) + ")");
  if (!std::isfinite(d.skin_iso) || !std::isfinite(d.bone_iso) || d.bone_iso <= d.skin_iso)
    return invalid("isovalues: expected finite skin < bone, found skin " + std::to_string(d.skin_iso) + " HU, bone " +
                   std::to_string(d.bone_iso) + " HU");
  if (!(d.cut_depth > 0) || d.cut_depth > 0.05) return invalid("cut depth: expected (0, 50] mm, found " + std::to_string(d.cut_depth * 1e3) + " mm");
  // Orientation comes from the placement; the brick and the drill work on the voxel grid.
  t.volume.direction = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  if (t.material.empty()) t.material = labels_from_hu(t.volume, d.skin_iso, d.bone_iso);

  if (d.source != SceneSource::kBlock) {
    s->placement_.axis = d.axis;
    s->placement_.sign = d.sign;
    if (!s->placement_.valid()) return invalid("axes: expected a permutation of x, y, z with signs ±1");
    // The skin's isosurface places the volume: its top at z = 0, the volume's centre at x = y = 0.
    // No gradient normals: the surface model makes its own from its faces (as every later change
    // to it does), so sampling the volume's gradient for them would be work thrown away.
    volume::IsoOptions skin_options = iso_options(d.skin_iso);
    skin_options.normals = false;
    auto iso = volume::extract_isosurface(t.volume, skin_options, t.material);
    if (!iso.ok()) return invalid(iso.error().message);
    if (iso.value().triangles.empty())
      return invalid("no skin at " + std::to_string(d.skin_iso) + " HU: the volume has nothing that dense (check skin_iso)");
    skin = place_skin(std::move(iso).value(), t.volume, s->placement_);
  } else {
    skin = surface::make_tissue_block(d.block);
  }

  if (d.surface == SceneSurface::kBone) {
    auto bone = volume::LiveIsosurface::create(t.volume, iso_options(d.bone_iso), t.material);
    if (!bone.ok()) return invalid(bone.error().message);
    s->bone_ = std::move(bone).value();
    skin = to_world(s->bone_->mesh(), s->placement_);
    if (skin.triangles.empty()) return invalid("no bone at " + std::to_string(d.bone_iso) + " HU (check bone_iso)");
  }
  auto model = surface::SurfaceModel::create(std::move(skin), d.surface_params);
  if (!model.ok()) return invalid(model.error().message);
  s->surface_ = std::move(model).value();
  s->desc_ = std::move(d);
  // The lattice's material ids now, not at the first cut's end in the middle of a frame; its
  // elements are still materialised only where a cut or a groove needs them.
  s->ensure_lattice();
  return s;
}

std::uint64_t TissueScene::revision() const noexcept { return surface_->revision() + own_revision_; }

// ---- lancet-rt's stream -----------------------------------------------------------------------

bool TissueScene::apply(std::span<const ToolSample> batch) {
  const std::uint64_t before = revision();
  const auto dt_between = [](const ToolSample& a, const ToolSample& b) {
    return std::clamp(static_cast<double>(b.t_ns - a.t_ns) * 1e-9, 0.0, 0.1);
  };
  // Per hand: a pull sets the opening to the hand's displacement (not by it), so of a run of one
  // hand's pulls in a frame only the newest counts; and the hand's newest sample is always fed.
  std::array<std::size_t, kHandCount> last_pull, last_of_hand;
  last_pull.fill(batch.size());
  last_of_hand.fill(batch.size());
  for (std::size_t i = batch.size(); i-- > 0;) {
    const std::size_t h = hand_slot(batch[i].hand);
    if (last_of_hand[h] == batch.size()) last_of_hand[h] = i;
    if (last_pull[h] == batch.size() && (batch[i].events & event::kPull) != 0) last_pull[h] = i;
  }
  for (std::size_t i = 0; i < batch.size(); ++i) {
    const ToolSample& t = batch[i];
    const std::size_t h = hand_slot(t.hand);
    HandFeed& fed = fed_[h];
    tally(t);
    if ((t.events & event::kDrillRemove) != 0) drill(t);
    // The surface: the cut grows by cut progress events (every 0.5 mm of blade travel), the
    // stages change and pulls apply as they come, the dent follows the hand's newest sample.
    const bool cut_step = t.stage == Stage::kCutting && (t.events & event::kCutProgress) != 0;
    const bool transition = !fed.any || t.stage != fed.last.stage || (t.events & (event::kRupture | event::kGrab)) != 0 ||
                            i == last_pull[h];
    if (!(cut_step || transition || i == last_of_hand[h])) continue;
    apply_one(t, fed.any ? dt_between(fed.last, t) : 0.0);
    fed.last = t;
    fed.any = true;
  }
  if (!batch.empty()) {
    refresh_bone_surface();
    update_grooves();
  }
  return revision() != before;
}

// One hand's sample on the surface. Two hands share one surface: the dent is the hand's that
// pressed first (the other's press is felt, but not drawn, until it lets go), the cut being made is
// the hand's that began it (the other hand neither ends nor extends it), and a retractor pulls the
// cut it grabbed, whatever cut the other hand makes meanwhile. The surface's own time (a released
// dent's return to rest, the wrinkle's damping) runs on the right hand's samples alone (every
// session has a right hand), so two hands do not make it run twice as fast.
void TissueScene::apply_one(const ToolSample& sample, double dt) {
  surface::SurfaceModel& m = *surface_;
  const std::size_t h = hand_slot(sample.hand);
  const bool keeps_time = h == hand_index(Hand::kRight);
  const Vec3 tool = sample.tool.position, proxy = sample.proxy.position;
  if (!is_finite(tool) || !is_finite(proxy)) return;
  const bool cutting_stage = sample.stage == Stage::kRupture || sample.stage == Stage::kCutting;
  if (m.cutting() && cut_hand_ == h && !cutting_stage) {
    m.end_cut();
    cut_hand_ = kNoHand;
  }
  // The dent: only the hand that owns it moves or releases it.
  const bool owns_dent = dent_hand_ == kNoHand || dent_hand_ == h;
  const auto release_dent = [&] {
    if (dent_hand_ == h) {
      m.update_contact(std::nullopt, dt);
      dent_hand_ = kNoHand;
    } else if (dent_hand_ == kNoHand && keeps_time) {
      m.update_contact(std::nullopt, dt);  // the return to rest goes on
    }
  };
  switch (sample.stage) {
    case Stage::kDeform: {
      if (!owns_dent) break;
      const Vec3 into = tool - proxy;
      m.update_contact(surface::Contact{proxy, normalized(into), norm(into)}, dt);
      dent_hand_ = h;
      break;
    }
    case Stage::kRupture:
    case Stage::kCutting: {
      release_dent();
      if (m.cutting() && cut_hand_ != h) break;  // the other hand is cutting: one cut at a time
      if (!m.cutting()) {
        const bool rupture = (sample.events & event::kRupture) != 0 && is_finite(sample.payload.position);
        if (!m.begin_cut(rupture ? sample.payload.position : proxy)) break;
        cut_hand_ = h;
      }
      (void)m.cut_to(proxy);
      break;
    }
    case Stage::kPulling: {
      release_dent();
      if ((sample.events & event::kGrab) != 0 || held_cut_[h] >= m.cuts().size()) held_cut_[h] = nearest_cut(sample.payload.position);
      if (held_cut_[h] < m.cuts().size() && (sample.events & event::kPull) != 0) (void)m.pull(held_cut_[h], sample.payload.magnitude);
      if (keeps_time) m.relax(dt);
      break;
    }
    default:
      release_dent();
      held_cut_[h] = kNoCut;
      if (keeps_time) m.relax(dt);
      break;
  }
}

std::size_t TissueScene::nearest_cut(Vec3 at) const {
  const auto& cuts = surface_->cuts();
  if (cuts.empty()) return kNoCut;
  if (!is_finite(at)) return cuts.size() - 1;
  std::size_t best = cuts.size() - 1;
  double best_d2 = std::numeric_limits<double>::infinity();
  for (std::size_t c = 0; c < cuts.size(); ++c) {
    for (const Vec3& p : cuts[c].path) {
      const double dx = p.x - at.x, dy = p.y - at.y, d2 = dx * dx + dy * dy;
      if (d2 < best_d2) best_d2 = d2, best = c;
    }
  }
  return best;
}

void TissueScene::tally(const ToolSample& t) {
  using namespace event;
  SceneEvents& e = events_;
  ++e.samples;
  char buf[128];
  if ((t.events & kContactBegin) != 0) ++e.contacts;
  if ((t.events & kContactEnd) != 0) ++e.contact_ends;
  if ((t.events & kForceFaded) != 0) ++e.faded_ticks;
  if ((t.events & kCutProgress) != 0) ++e.cut_steps;
  if ((t.events & kPull) != 0) ++e.pulls;
  if ((t.events & kFault) != 0) ++e.fault_ticks;
  const auto say = [&](std::string line, bool warning) {
    e.last = std::move(line);
    e.last_is_warning = warning;
  };
  if ((t.events & kRupture) != 0) {
    ++e.ruptures;
    std::snprintf(buf, sizeof buf, "the skin ruptured at %.1f N: cutting", t.payload.magnitude);
    say(buf, false);
  }
  if ((t.events & kGrab) != 0) {
    ++e.grabs;
    say("the retractor holds the skin", false);
  }
  if ((t.events & kRelease) != 0) {
    ++e.releases;
    say("the grip slipped: pulled past the skin's elastic limit", false);
  }
  if ((t.events & kForceClamped) != 0) {
    if (e.clamped_ticks++ == 0 || e.last.rfind("force limited", 0) != 0) say("force limited by the safety clamp: press less hard", true);
  }
}

// ---- the drill ----------------------------------------------------------------------------------

void TissueScene::drill(const ToolSample& t) {
  if (tissue_.volume.data.empty()) return;  // a mesh alone: nothing to drill
  volume::DrillParams dp;
  dp.centre = placement_.to_volume(t.payload.position);
  dp.radius = t.payload.magnitude;
  auto r = volume::drill_sphere(tissue_.volume, dp, tissue_.material);
  if (!r.ok()) return;  // wire::check bounds the radius; a burr outside the volume removes nothing
  if (!render_.data.empty()) (void)volume::drill_sphere(render_, dp);
  ++events_.drill_removals;
  events_.voxels_drilled += r.value().voxels_removed;
  last_removal_ns_ = t.t_ns;
  grow(dirty_, r.value().dirty);
  grow(changed_, r.value().dirty);
}

const volume::Volume& TissueScene::render_volume() {
  if (render_.data.empty() && !tissue_.volume.data.empty()) {
    render_ = tissue_.volume;
    for (const Groove& g : grooves_)
      if (g.width > 0) carve(g, 0);
  }
  return render_;
}

// The groove's opening in the drawn volume: voxels whose x-y distance to the cut's path is within
// half the opening (tapered to zero at the cut's ends, as the skin's opening is) shrinking
// linearly to zero at the cut depth below the path, become air; bone stays. The region of the
// previous, wider or narrower, opening is restored from the tissue's volume first.
void TissueScene::carve(const Groove& g, double previous_width) {
  const surface::Cut& cut = surface_->cuts()[g.surface_cut];
  const std::vector<Vec3>& path = cut.path;
  if (path.size() < 2) return;
  const double half = 0.5 * std::max(g.width, previous_width) + 0.002, depth = desc_.cut_depth;
  Vec3 lo{1e30, 1e30, 1e30}, hi{-1e30, -1e30, -1e30};
  for (const Vec3& p : path) {
    lo = {std::min(lo.x, p.x - half), std::min(lo.y, p.y - half), std::min(lo.z, p.z - depth - 0.002)};
    hi = {std::max(hi.x, p.x + half), std::max(hi.y, p.y + half), std::max(hi.z, p.z + 0.002)};
  }
  // The box in voxel indices (through the placement's corners).
  const volume::Volume& v = tissue_.volume;
  volume::VoxelBox box{{v.dims[0], v.dims[1], v.dims[2]}, {0, 0, 0}};
  for (int c = 0; c < 8; ++c) {
    const Vec3 w{(c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z};
    const Vec3 q = placement_.to_volume(w);
    for (int a = 0; a < 3; ++a) {
      const double f = (at(q, a) - at(v.origin, a)) / at(v.spacing, a);
      box.lo[u(a)] = std::min(box.lo[u(a)], std::max(0, static_cast<int>(std::floor(f))));
      box.hi[u(a)] = std::max(box.hi[u(a)], std::min(v.dims[u(a)], static_cast<int>(std::ceil(f)) + 1));
    }
  }
  if (box.empty()) return;
  double total = 0;
  std::vector<double> arc(path.size(), 0.0);
  for (std::size_t i = 1; i < path.size(); ++i) arc[i] = total += std::hypot(path[i].x - path[i - 1].x, path[i].y - path[i - 1].y);
  if (total <= 0) return;
  for (int k = box.lo[2]; k < box.hi[2]; ++k)
    for (int j = box.lo[1]; j < box.hi[1]; ++j)
      for (int i = box.lo[0]; i < box.hi[0]; ++i) {
        const std::size_t idx = v.index(i, j, k);
        render_.data[idx] = v.data[idx];  // restore, then carve the current opening
        if (g.width <= 0) continue;
        const std::uint8_t m = tissue_.material[idx];
        if (m == volume::kCorticalBone || m == volume::kMarrow) continue;
        const Vec3 w = placement_.to_world(v.position(i, j, k));
        // Nearest point of the path in x-y: its arc position and surface height.
        double best = 1e30, s = 0, z = 0;
        for (std::size_t n = 1; n < path.size(); ++n) {
          const Vec3 a = path[n - 1], b = path[n];
          const double dx = b.x - a.x, dy = b.y - a.y, l2 = dx * dx + dy * dy;
          const double t = l2 > 0 ? std::clamp(((w.x - a.x) * dx + (w.y - a.y) * dy) / l2, 0.0, 1.0) : 0.0;
          const double px = a.x + t * dx - w.x, py = a.y + t * dy - w.y, d2 = px * px + py * py;
          if (d2 < best) best = d2, s = arc[n - 1] + t * (arc[n] - arc[n - 1]), z = a.z + t * (b.z - a.z);
        }
        const double h = z - w.z;  // below the cut's path
        if (h < -0.002 || h > depth) continue;
        const double open = 0.5 * g.width * std::sin(M_PI * s / total) * (1.0 - std::max(h, 0.0) / depth);
        if (std::sqrt(best) <= open) render_.data[idx] = -1000.0f;
      }
  grow(changed_, box);
}

volume::VoxelBox TissueScene::take_volume_changes() noexcept {
  const volume::VoxelBox b = changed_;
  changed_ = {};
  return b;
}

std::array<float, 16> TissueScene::volume_to_world() const noexcept {
  std::array<float, 16> m{};
  for (std::size_t a = 0; a < 3; ++a) {
    m[4 * static_cast<std::size_t>(placement_.axis[a]) + a] = static_cast<float>(placement_.sign[a]);
    m[12 + a] = static_cast<float>(at(placement_.offset, static_cast<int>(a)));
  }
  m[15] = 1;
  return m;
}

// The removals of this frame re-extract the bone surface where they were (made at the first
// removal); on exposed bone the touched surface follows, at most four times a second.
void TissueScene::refresh_bone_surface() {
  if (!dirty_.empty()) {
    const volume::VoxelBox box = dirty_;
    dirty_ = {};
    if (!bone_) {
      auto made = volume::LiveIsosurface::create(tissue_.volume, iso_options(desc_.bone_iso), tissue_.material);
      if (!made.ok()) return;
      bone_ = std::move(made).value();
    } else if (!bone_->update(tissue_.volume, box, tissue_.material).ok()) {
      return;
    }
    ++events_.bone_updates;
    if (desc_.surface != SceneSurface::kBone) return;
    ++own_revision_;
    bone_changed_ = true;
  }
  // The felt surface follows once the drilling pauses (the drill itself pushes against the
  // brick, not the surface): when no hand holds the drill any more, or half a second after its
  // last removal. Rebuilding it is a whole surface's work, too much for every drilling frame.
  if (!bone_changed_) return;
  for (const HandFeed& f : fed_)
    if (f.any && f.last.mode == ToolMode::kDrill && f.last.t_ns - last_removal_ns_ < 500'000'000) return;
  bone_changed_ = false;
  const surface::TriangleMesh m = to_world(bone_->mesh(), placement_);
  auto model = surface::SurfaceModel::create(m.vertices, m.triangles, m.material, desc_.surface_params);
  if (!model.ok()) return;
  own_revision_ += surface_->revision() + 1;  // the new model counts from 0 again: never repeat a revision
  surface_ = std::move(model).value();
  dent_hand_ = cut_hand_ = kNoHand;  // a new surface: no dent, no cut, nothing held
  held_cut_.fill(kNoCut);
}

// ---- the groove ---------------------------------------------------------------------------------

void TissueScene::ensure_lattice() {
  if (chainmail_) return;
  // The volume's grid turned into the world: world axis a runs along volume axis axis[a].
  const volume::Volume& v = tissue_.volume;
  volume::ChainMailLattice lat;
  std::array<int, 3> vdims = v.dims;
  for (int a = 0; a < 3; ++a) {
    const int ax = placement_.axis[u(a)];
    lat.dims[u(a)] = vdims[u(ax)];
    at(lat.spacing, a) = at(v.spacing, ax);
  }
  // The world position of voxel (0, 0, 0) of the lattice: the corner where every world
  // coordinate is smallest.
  const Vec3 c0 = placement_.to_world(v.position(0, 0, 0));
  const Vec3 c1 = placement_.to_world(v.position(v.dims[0] - 1, v.dims[1] - 1, v.dims[2] - 1));
  lat.origin = {std::min(c0.x, c1.x), std::min(c0.y, c1.y), std::min(c0.z, c1.z)};
  lattice_origin_ = lat.origin;
  lattice_ids_.resize(v.voxel_count());
  std::array<int, 3> idx{}, vi{};
  for (idx[2] = 0; idx[2] < lat.dims[2]; ++idx[2])
    for (idx[1] = 0; idx[1] < lat.dims[1]; ++idx[1])
      for (idx[0] = 0; idx[0] < lat.dims[0]; ++idx[0]) {
        for (int a = 0; a < 3; ++a) {
          const int ax = placement_.axis[u(a)];
          vi[u(ax)] = placement_.sign[u(a)] > 0 ? idx[u(a)] : vdims[u(ax)] - 1 - idx[u(a)];
        }
        const std::uint8_t m = tissue_.material[v.index(vi[0], vi[1], vi[2])];
        lattice_ids_[u(idx[0]) + u(lat.dims[0]) * (u(idx[1]) + u(lat.dims[1]) * u(idx[2]))] =
            m < kChainMailLabels ? m : static_cast<std::uint8_t>(volume::kMuscle);
      }
  chainmail_ = std::make_unique<volume::ChainMail>(lat, chainmail_materials(lat.spacing), lattice_ids_);
}

// A surface cut reaches into the volume once it is done (the blade has left it): the thin cut
// down to the cut depth below the skin, along its path; its groove opens with the incision.
void TissueScene::update_grooves() {
  const auto& cuts = surface_->cuts();
  for (std::size_t c = grooves_.size(); c < cuts.size(); ++c) {
    const surface::Cut& cut = cuts[c];
    if (cut.active) break;  // still growing
    Groove g;
    g.surface_cut = c;
    double length = 0, lowest = 1e30;
    for (std::size_t i = 0; i < cut.path.size(); ++i) {
      lowest = std::min(lowest, cut.path[i].z);
      if (i > 0) length += std::hypot(cut.path[i].x - cut.path[i - 1].x, cut.path[i].y - cut.path[i - 1].y);
    }
    if (cut.path.size() >= 2 && length > 1e-4 && !tissue_.volume.data.empty()) {
      ensure_lattice();
      const auto& lat = chainmail_->lattice();
      const double top = lat.origin.z + (lat.dims[2] - 1) * lat.spacing.z;
      g.cut = chainmail_->cut(cut.path, std::max(top - lowest, 0.0) + desc_.cut_depth);
    }
    grooves_.push_back(std::move(g));
  }
  for (Groove& g : grooves_) {
    const double d = cuts[g.surface_cut].opening;
    if (g.cut.faces.empty() || std::abs(d - g.width) < 1e-4) continue;
    const auto r = chainmail_->open_groove(g.cut, std::max(d, 1e-5));
    g.conflicts += r.conflicts;
    const double before = g.width;
    g.width = d;
    if (!render_.data.empty()) carve(g, before);
    ++own_revision_;
  }
}

std::vector<GrooveFigures> TissueScene::grooves() const {
  std::vector<GrooveFigures> out;
  for (const Groove& g : grooves_) {
    GrooveFigures f;
    f.faces = g.cut.faces.size();
    f.length = g.cut.length;
    f.width = g.width;
    f.conflicts = g.conflicts;
    double sum[2] = {0, 0};
    std::size_t n[2] = {0, 0};
    for (const auto& face : g.cut.faces) {
      f.depth = std::max(f.depth, face.depth);
      if (face.depth > 1e-9) continue;
      const Vec3 disp = chainmail_->displacement(face.element);
      const std::size_t side = face.side > 0 ? 0 : 1;
      sum[side] += (disp.x * face.away.x + disp.y * face.away.y) / std::max(std::hypot(face.away.x, face.away.y), 1e-12);
      ++n[side];
    }
    if (n[0] > 0 && n[1] > 0) f.top_gap = sum[0] / static_cast<double>(n[0]) + sum[1] / static_cast<double>(n[1]);
    out.push_back(f);
  }
  return out;
}

// ---- export -------------------------------------------------------------------------------------

std::size_t TissueScene::export_patch(Vec3 centre, TissuePatch& out) { return export_patch(centre, scratch_, out); }

std::size_t TissueScene::export_patch(Vec3 centre, PatchExportScratch& scratch, TissuePatch& out) const {
  return tissue::export_patch(*surface_, centre, desc_.patch, scratch, out, [this](Vec3 c, VoxelBrick& brick) {
    fill_brick(tissue_.volume, placement_, c, brick);
  });
}

void TissueScene::draw_mesh(surface::TriangleMesh& out, bool walls) const {
  if (desc_.surface == SceneSurface::kBone && bone_) {
    out = to_world(bone_->mesh(), placement_);
    return;
  }
  surface_->to_triangle_mesh(out);
  if (!chainmail_ || !walls) return;
  // Each open groove's walls and floor: its face elements binned by (side, arc, layer), a vertex
  // per bin at their mean position, quads between neighbouring bins, and a floor strip between
  // the deepest bins of the two walls.
  for (const Groove& g : grooves_) {
    if (g.width < 2e-4 || g.cut.faces.empty()) continue;
    const auto& lat = chainmail_->lattice();
    const double ds = std::min(lat.spacing.x, lat.spacing.y);
    struct Bin {
      Vec3 sum{};
      Vec3 away{};
      int n = 0;
      std::uint8_t material = 0;
      std::uint32_t vertex = 0;
    };
    std::map<std::tuple<int, int, int>, Bin> bins;  // (side, arc bin, k)
    for (const auto& f : g.cut.faces) {
      Bin& b = bins[{f.side, static_cast<int>(std::lround(f.arc / ds)), f.element[2]}];
      b.sum = b.sum + chainmail_->position(f.element);
      b.away = f.away;
      ++b.n;
      b.material = lattice_ids_[u(f.element[0]) + u(lat.dims[0]) * (u(f.element[1]) + u(lat.dims[1]) * u(f.element[2]))];
    }
    for (auto& [key, b] : bins) {
      b.vertex = static_cast<std::uint32_t>(out.vertices.size());
      out.vertices.push_back(to_vec3f(b.sum * (1.0 / b.n)));
      out.normals.push_back(to_vec3f(normalized(b.away * -1.0)));
    }
    const auto find = [&](int side, int arc, int k) -> const Bin* {
      auto it = bins.find({side, arc, k});
      return it == bins.end() ? nullptr : &it->second;
    };
    const auto quad = [&](const Bin* a, const Bin* b, const Bin* c, const Bin* d) {
      out.triangles.push_back({a->vertex, b->vertex, c->vertex});
      out.triangles.push_back({a->vertex, c->vertex, d->vertex});
      out.material.push_back(a->material);
      out.material.push_back(a->material);
    };
    std::map<std::pair<int, int>, int> deepest;  // (side, arc) → lowest k
    for (const auto& [key, b] : bins) {
      const auto [side, arc, k] = key;
      auto [it, fresh] = deepest.try_emplace({side, arc}, k);
      if (!fresh) it->second = std::min(it->second, k);
      const Bin* right = find(side, arc + 1, k);
      const Bin* below = find(side, arc, k - 1);
      const Bin* diag = find(side, arc + 1, k - 1);
      if (right && below && diag) quad(&b, right, diag, below);
    }
    for (const auto& [key, k] : deepest) {
      if (key.first != 1) continue;
      const auto other = deepest.find({-1, key.second}), next = deepest.find({1, key.second + 1}),
                 other_next = deepest.find({-1, key.second + 1});
      if (other == deepest.end() || next == deepest.end() || other_next == deepest.end()) continue;
      quad(find(1, key.second, k), find(1, key.second + 1, next->second), find(-1, key.second + 1, other_next->second),
           find(-1, key.second, other->second));
    }
  }
}

// ---- figures ------------------------------------------------------------------------------------

CutFigures TissueScene::cut_figures() const {
  const surface::SurfaceModel& model = *surface_;
  CutFigures f;
  f.cuts = model.cuts().size();
  for (const auto& c : model.cuts()) {
    double len = 0;
    for (std::size_t i = 1; i < c.chain.size(); ++i) len += norm(model.rest_position(c.chain[i]) - model.rest_position(c.chain[i - 1]));
    if (len >= f.longest && !c.chain.empty()) {
      f.longest = len;
      f.from = model.rest_position(c.chain.front());
      f.to = model.rest_position(c.chain.back());
    }
    for (const auto& pr : c.pairs) f.opening = std::max(f.opening, norm(model.position(pr.left) - model.position(pr.right)));
  }
  return f;
}

std::vector<std::vector<Vec3>> TissueScene::cut_paths() const {
  std::vector<std::vector<Vec3>> out;
  for (const auto& c : surface_->cuts()) out.push_back(c.path);
  return out;
}

std::optional<Vec3> TissueScene::surface_below(double x, double y) const {
  const auto hit = surface_->bvh().first_hit(surface_->view(), Vec3f{static_cast<float>(x), static_cast<float>(y), 0.2f},
                                             Vec3f{static_cast<float>(x), static_cast<float>(y), -0.5f});
  if (!hit) return std::nullopt;
  return to_vec3(hit->point);
}

std::vector<Vec3> TissueScene::drape(const std::vector<Vec3>& line, double step) const {
  std::vector<Vec3> out;
  for (std::size_t i = 1; i < line.size(); ++i) {
    const Vec3 a = line[i - 1], b = line[i];
    const double len = std::hypot(b.x - a.x, b.y - a.y);
    const int n = std::max(1, static_cast<int>(std::ceil(len / step)));
    for (int k = i == 1 ? 0 : 1; k <= n; ++k) {
      const double f = static_cast<double>(k) / n;
      if (auto p = surface_below(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y))) out.push_back(*p);
    }
  }
  return out;
}

std::uint8_t TissueScene::label_at(Vec3 world) const noexcept {
  const volume::Volume& v = tissue_.volume;
  const Vec3 p = placement_.to_volume(world);
  std::array<int, 3> i{};
  for (int a = 0; a < 3; ++a) {
    const double f = std::round((at(p, a) - at(v.origin, a)) / at(v.spacing, a));
    if (!(f >= 0 && f < v.dims[u(a)])) return volume::kAir;
    i[u(a)] = static_cast<int>(f);
  }
  return tissue_.material[v.index(i[0], i[1], i[2])];
}

}  // namespace lancet::tissue
