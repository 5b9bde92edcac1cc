#include "blood/bleeding.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

#include "volume/phantom.hpp"

namespace lancet::blood {
namespace {

constexpr float kDown[3] = {0, 0, -1};
constexpr double kMl = 1e6;  // mL per m³

double planar(Vec3 a, Vec3 b) { return std::hypot(a.x - b.x, a.y - b.y); }

// A groove cell's geometry: its floor half the cut's depth below the lower lip (a V-shaped
// groove's capacity in a flat-bottomed cell), and its width the opening (at least 0.3 mm: a cut
// not yet opened still holds a little).
float groove_floor(Vec3 left, Vec3 right, double cut_depth) { return static_cast<float>(std::min(left.z, right.z) - 0.5 * cut_depth); }
double groove_width(const surface::Cut& cut) { return std::max(cut.opening, 3e-4); }

}  // namespace

Bleeding::Bleeding(const TissueScene& scene, BleedingParams params) : p_(params) {
  automaton_ = blood::Automaton(blood::Network{}, p_.automaton);
  rebuild(scene);
}

void Bleeding::observe(std::span<const ToolSample> samples) {
  for (const ToolSample& s : samples) {
    HandTool& h = hands_[hand_slot(s.hand)];
    h.tool = s.tool.position;
    h.mode = s.mode;
    h.contact = s.stage != Stage::kFree;
    h.seen = true;
    if ((s.events & event::kDrillRemove) != 0) drilled_.push_back(s.payload.position);
  }
}

void Bleeding::rebuild(const TissueScene& scene) {
  const surface::SurfaceModel& surf = scene.surface();
  const std::size_t nv = surf.mesh().n_vertices();
  std::vector<float> xyz(3 * nv);
  for (std::size_t v = 0; v < nv; ++v) {
    const Vec3 q = surf.position(static_cast<std::uint32_t>(v));
    xyz[3 * v] = static_cast<float>(q.x), xyz[3 * v + 1] = static_cast<float>(q.y), xyz[3 * v + 2] = static_cast<float>(q.z);
  }
  std::vector<std::uint32_t> tri;
  tri.reserve(3 * surf.faces().size());
  for (const auto& f : surf.faces()) tri.insert(tri.end(), f.begin(), f.end());
  blood::NetworkBuilder nb;
  blood::add_mesh(nb, xyz, tri, kDown, static_cast<float>(p_.film_depth));

  // The grooves: a cell per pair of split vertices, between the lips.
  const double depth = scene.description().cut_depth;
  std::map<std::pair<std::size_t, std::size_t>, std::uint32_t> old_groove;
  for (const GrooveCell& g : groove_) old_groove[{g.cut, g.pair}] = g.cell;
  std::vector<GrooveCell> groove;
  const auto& cuts = surf.cuts();
  pair_born_.resize(cuts.size());
  pairs_seen_.resize(cuts.size(), 0);
  std::size_t pairs_total = 0;
  for (std::size_t c = 0; c < cuts.size(); ++c) {
    const auto& pairs = cuts[c].pairs;
    pairs_total += pairs.size();
    pair_born_[c].resize(pairs.size(), time_);
    const double width = groove_width(cuts[c]);
    std::uint32_t previous = blood::Automaton::kNoCell;
    for (std::size_t k = 0; k < pairs.size(); ++k) {
      const Vec3 l = surf.position(pairs[k].left), r = surf.position(pairs[k].right);
      const Vec3 mid_rest = (pairs[k].rest_left + pairs[k].rest_right) * 0.5;
      const std::size_t other = k + 1 < pairs.size() ? k + 1 : (k > 0 ? k - 1 : k);
      const double spacing =
          std::max(3e-4, norm((pairs[other].rest_left + pairs[other].rest_right) * 0.5 - mid_rest));
      const float floor = groove_floor(l, r, depth);
      const std::uint32_t cell = nb.add_cell(static_cast<float>(spacing * width), floor, 0.0f);
      const float reach = static_cast<float>(std::max(0.5 * width, 5e-4));
      nb.add_pipe(cell, pairs[k].left, static_cast<float>(spacing), reach);
      nb.add_pipe(cell, pairs[k].right, static_cast<float>(spacing), reach);
      if (previous != blood::Automaton::kNoCell) nb.add_pipe(previous, cell, static_cast<float>(width), static_cast<float>(spacing));
      previous = cell;
      groove.push_back({cell, c, k, (l + r) * 0.5, floor, spacing});
    }
  }
  blood::Network net = nb.build();
  // Blood stays with its vertex (vertices keep their index; a cut appends new ones) and with its
  // groove cell (matched by cut and pair).
  std::vector<std::uint32_t> from_old(net.cells(), blood::Automaton::kNoCell);
  for (std::size_t v = 0; v < std::min(nv, skin_cells_); ++v) from_old[v] = static_cast<std::uint32_t>(v);
  for (const GrooveCell& g : groove)
    if (auto it = old_groove.find({g.cut, g.pair}); it != old_groove.end()) from_old[g.cell] = it->second;
  automaton_.reshape(std::move(net), from_old);
  // Vessel sources follow their cell: the groove cell or vertex nearest their point.
  skin_cells_ = nv;
  groove_ = std::move(groove);
  for (std::size_t s = 0; s < sources_.size(); ++s)
    if (sources_[s].kind == BloodSource::Kind::kVessel) vessel_cell_[s] = nearest_cell(scene, sources_[s].position);
  source_rate_.assign(automaton_.network().cells(), 0.0f);
  sink_rate_.assign(automaton_.network().cells(), 0.0f);
  faces_seen_ = surf.faces().size();
  vertices_seen_ = nv;
  groove_pairs_seen_ = pairs_total;
  revision_seen_ = scene.revision();
  ++rebuilds_;
}

void Bleeding::refresh_elevations(const TissueScene& scene) {
  const surface::SurfaceModel& surf = scene.surface();
  std::vector<float> e(automaton_.network().elevation), area(automaton_.network().area);
  for (std::size_t v = 0; v < skin_cells_; ++v) e[v] = static_cast<float>(surf.position(static_cast<std::uint32_t>(v)).z);
  const double depth = scene.description().cut_depth;
  // The groove follows its lips down and up, and widens as the incision opens (the same blood
  // then stands lower in it).
  for (GrooveCell& g : groove_) {
    const auto& cut = surf.cuts()[g.cut];
    const auto& pair = cut.pairs[g.pair];
    const Vec3 l = surf.position(pair.left), r = surf.position(pair.right);
    g.centre = (l + r) * 0.5;
    g.floor = groove_floor(l, r, depth);
    e[g.cell] = g.floor;
    area[g.cell] = static_cast<float>(g.spacing * groove_width(cut));
  }
  automaton_.set_geometry(e, area);
  revision_seen_ = scene.revision();
}

std::uint32_t Bleeding::nearest_cell(const TissueScene& scene, Vec3 p) const {
  // A groove cell within 3 mm takes it (blood from a cut vessel wells up in the opening), else
  // the nearest skin vertex.
  double best = 0.003;
  std::uint32_t cell = blood::Automaton::kNoCell;
  for (const GrooveCell& g : groove_)
    if (const double d = planar(g.centre, p); d < best) best = d, cell = g.cell;
  if (cell != blood::Automaton::kNoCell) return cell;
  const auto& net = automaton_.network();
  best = std::numeric_limits<double>::max();
  for (std::uint32_t v = 0; v < skin_cells_ && v + 1 < net.first.size(); ++v) {
    if (net.first[v] == net.first[v + 1]) continue;  // no pipes: not part of the surface
    if (const double d = norm(scene.surface().position(v) - p); d < best) best = d, cell = v;
  }
  return cell;
}

void Bleeding::add_vessel(const TissueScene& scene, const std::string& name, Vec3 at) {
  for (const BloodSource& s : sources_)
    if (s.kind == BloodSource::Kind::kVessel && norm(s.position - at) < 0.008) return;  // already bleeding there
  BloodSource s;
  s.kind = BloodSource::Kind::kVessel;
  s.name = name;
  s.position = at;
  sources_.push_back(s);
  vessel_cell_.resize(sources_.size(), blood::Automaton::kNoCell);
  vessel_cell_.back() = nearest_cell(scene, at);
}

void Bleeding::find_vessels(const TissueScene& scene) {
  const auto& cuts = scene.surface().cuts();
  const double depth = scene.description().cut_depth;
  for (std::size_t c = 0; c < cuts.size() && c < pairs_seen_.size(); ++c) {
    for (std::size_t k = pairs_seen_[c]; k < cuts[c].pairs.size(); ++k) {
      const auto& pair = cuts[c].pairs[k];
      const Vec3 top = (pair.rest_left + pair.rest_right) * 0.5;
      for (double dz = 0; dz <= depth; dz += 5e-4) {
        const Vec3 q{top.x, top.y, top.z - dz};
        if (const std::uint8_t l = scene.label_at(q); l == volume::kVessel || l == volume::kVein) {
          add_vessel(scene, std::string(l == volume::kVein ? "vein" : "artery") + " cut by incision " + std::to_string(c + 1), q);
          break;
        }
      }
    }
    pairs_seen_[c] = cuts[c].pairs.size();
  }
  // A drill removal next to a vessel opens it (the removed voxels are air by now: look around).
  for (const Vec3& at : drilled_) {
    for (int a = 0; a < 6; ++a) {
      const double r = 0.0015;
      const Vec3 q = at + Vec3{a == 0 ? r : a == 1 ? -r : 0, a == 2 ? r : a == 3 ? -r : 0, a == 4 ? r : a == 5 ? -r : 0};
      if (const std::uint8_t l = scene.label_at(q); l == volume::kVessel || l == volume::kVein) {
        add_vessel(scene, std::string(l == volume::kVein ? "vein" : "artery") + " opened by the drill", q);
        break;
      }
    }
  }
  drilled_.clear();
}

void Bleeding::set_rates(const TissueScene& scene, double dt) {
  std::fill(source_rate_.begin(), source_rate_.end(), 0.0f);
  std::fill(sink_rate_.begin(), sink_rate_.end(), 0.0f);
  const surface::SurfaceModel& surf = scene.surface();
  const auto& cuts = surf.cuts();
  const double depth = scene.description().cut_depth;
  // One ooze and one groove-wall source per cut, made when the cut appears.
  const auto source_for = [&](BloodSource::Kind kind, std::size_t cut) -> BloodSource& {
    const std::string name = (kind == BloodSource::Kind::kCutOoze ? "ooze along incision " : "groove walls of incision ") + std::to_string(cut + 1);
    for (BloodSource& s : sources_)
      if (s.kind == kind && s.name == name) return s;
    BloodSource s;
    s.kind = kind;
    s.name = name;
    sources_.push_back(s);
    vessel_cell_.resize(sources_.size(), blood::Automaton::kNoCell);
    return sources_.back();
  };
  // Ooze from both lips of every pair in the network (pairs cut since the last rebuild wait for
  // the next), and, once the incision is open, from the groove's walls into its cell.
  std::vector<double> ooze(cuts.size(), 0.0), walls(cuts.size(), 0.0);
  for (const GrooveCell& g : groove_) {
    const surface::Cut& cut = cuts[g.cut];
    const auto& pair = cut.pairs[g.pair];
    const double clot = std::exp(-(time_ - pair_born_[g.cut][g.pair]) / p_.ooze_clot_s);
    const double r = p_.ooze_per_m * g.spacing * (1.0 + cut.opening / 1e-3) * clot;  // thesis 5.16: more as it opens
    source_rate_[pair.left] += static_cast<float>(0.5 * r);
    source_rate_[pair.right] += static_cast<float>(0.5 * r);
    ooze[g.cut] += r;
    if (cut.opening > 5e-4) {
      const double w = p_.wall_ooze_per_m2 * 2.0 * g.spacing * depth * clot;
      source_rate_[g.cell] += static_cast<float>(w);
      walls[g.cut] += w;
    }
  }
  for (std::size_t c = 0; c < cuts.size(); ++c) {
    if (ooze[c] > 0) {
      BloodSource& o = source_for(BloodSource::Kind::kCutOoze, c);
      o.rate_ml_s = ooze[c] * kMl;
      o.loss_ml += ooze[c] * dt * kMl;
    }
    if (walls[c] > 0) {
      BloodSource& w = source_for(BloodSource::Kind::kGrooveWall, c);
      w.rate_ml_s = walls[c] * kMl;
      w.loss_ml += walls[c] * dt * kMl;
    }
  }
  // Vessels bleed until pressed for press_seconds without a break (pressure slows them).
  const auto presses = [&](const HandTool& h, Vec3 at, double within) {
    return h.seen && h.contact && (h.mode == ToolMode::kProbe || h.mode == ToolMode::kRetractor) && norm(h.tool - at) < within;
  };
  for (std::size_t s = 0; s < sources_.size(); ++s) {
    BloodSource& v = sources_[s];
    if (v.kind != BloodSource::Kind::kVessel) continue;
    v.rate_ml_s = 0;
    if (v.stopped) continue;
    const double within = p_.press_radius + 0.5 * depth;
    const bool pressed = presses(hands_[0], v.position, within) || presses(hands_[1], v.position, within);
    v.pressed_s = pressed ? v.pressed_s + dt : 0.0;
    if (v.pressed_s >= p_.press_seconds) {
      v.stopped = true;
      continue;
    }
    const double r = p_.vessel_rate * (pressed ? 0.1 : 1.0);
    if (vessel_cell_[s] < source_rate_.size()) source_rate_[vessel_cell_[s]] += static_cast<float>(r);
    v.rate_ml_s = r * kMl;
    v.loss_ml += r * dt * kMl;
  }
  // A swab (in either hand) takes what its tip touches.
  for (const HandTool& h : hands_) {
    if (!h.seen || h.mode != ToolMode::kSwab) continue;
    for (std::uint32_t v = 0; v < skin_cells_; ++v)
      if (norm(surf.position(v) - h.tool) < p_.swab_radius) sink_rate_[v] = static_cast<float>(p_.swab_rate);
    for (const GrooveCell& gc : groove_)
      if (norm(gc.centre - h.tool) < p_.swab_radius + 0.5 * depth) sink_rate_[gc.cell] = static_cast<float>(p_.swab_rate);
  }
}

void Bleeding::advance(const TissueScene& scene, double dt) {
  prepare(scene, dt);
  step();
}

void Bleeding::prepare(const TissueScene& scene, double dt) {
  prepared_steps_ = 0;
  dt = std::clamp(dt, 0.0, p_.max_frame);
  const surface::SurfaceModel& surf = scene.surface();
  std::size_t pairs_total = 0;
  for (const auto& c : surf.cuts()) pairs_total += c.pairs.size();
  // A changed topology rebuilds the network, at most every rebuild_interval while a cut grows
  // (a rebuild costs tens of ms on a 65k-vertex skin); meanwhile the new cut steps wait.
  const bool changed = surf.faces().size() != faces_seen_ || surf.mesh().n_vertices() != vertices_seen_ || pairs_total != groove_pairs_seen_;
  if (changed && time_ - rebuilt_at_ >= p_.rebuild_interval) {
    rebuild(scene);
    rebuilt_at_ = time_;
  } else if (scene.revision() != revision_seen_) {
    refresh_elevations(scene);
  }
  find_vessels(scene);
  const int steps = static_cast<int>(std::floor(dt / static_cast<double>(p_.automaton.dt) + 0.5));
  if (steps <= 0) return;
  const double simulated = steps * static_cast<double>(p_.automaton.dt);
  set_rates(scene, simulated);
  automaton_.set_sources(source_rate_);
  automaton_.set_sinks(sink_rate_);
  prepared_steps_ = steps;
}

void Bleeding::step(int threads) {
  if (threads <= 0) threads = p_.threads;
  for (int s = 0; s < prepared_steps_; ++s) {
    automaton_.step(threads);
    swabbed_ += automaton_.last_sink_volume();
  }
  time_ += prepared_steps_ * static_cast<double>(p_.automaton.dt);
  prepared_steps_ = 0;
}

void Bleeding::vertex_blood(const surface::TriangleMesh& drawn, std::vector<float>& depth, std::vector<float>& age) const {
  const std::size_t n = drawn.vertices.size();
  depth.assign(n, 0.0f);
  age.assign(n, 0.0f);
  const std::size_t skin = std::min(n, skin_cells_);
  for (std::size_t v = 0; v < skin; ++v) {
    depth[v] = automaton_.depth(static_cast<std::uint32_t>(v));
    age[v] = automaton_.age(static_cast<std::uint32_t>(v));
  }
  if (groove_.empty()) return;
  for (std::size_t v = skin; v < n; ++v) {
    const Vec3 q{drawn.vertices[v].x, drawn.vertices[v].y, drawn.vertices[v].z};
    const GrooveCell* best = nullptr;
    double best_d = 0.004;
    for (const GrooveCell& g : groove_)
      if (const double d = planar(g.centre, q); d < best_d) best_d = d, best = &g;
    if (best == nullptr) continue;
    const float level = best->floor + automaton_.depth(best->cell);
    const float above = level - static_cast<float>(q.z);
    if (automaton_.depth(best->cell) > 0.0f && above > 0.0f) {
      depth[v] = std::min(above, 0.003f);
      age[v] = automaton_.age(best->cell);
    }
  }
}

void Bleeding::append_pools(const TissueScene& scene, surface::TriangleMesh& drawn, std::vector<float>& depth,
                            std::vector<float>& age) const {
  const auto& cuts = scene.surface().cuts();
  const double cut_depth = scene.description().cut_depth;
  struct Edge {
    Vec3 left, right;
    float depth, age;
  };
  // Where the blood stands in groove cell g: its level, and the opening's width there.
  const auto edge = [&](const GrooveCell& g, Edge& e) {
    const float d = automaton_.depth(g.cell);
    if (!(d > 1e-5f) || g.cut >= cuts.size() || g.pair >= cuts[g.cut].pairs.size()) return false;
    const auto& pair = cuts[g.cut].pairs[g.pair];
    const Vec3 l = scene.surface().position(pair.left), r = scene.surface().position(pair.right);
    const double rim = std::min(l.z, r.z), level = std::min(static_cast<double>(g.floor + d), rim);
    const double fill = std::clamp((level - (rim - cut_depth)) / cut_depth, 0.0, 1.0);
    const Vec3 mid = (l + r) * 0.5;
    const Vec3 half = (r - l) * (0.5 * fill);
    e = {Vec3{mid.x - half.x, mid.y - half.y, level}, Vec3{mid.x + half.x, mid.y + half.y, level}, std::min(d, 0.001f),
         automaton_.age(g.cell)};
    return true;
  };
  for (std::size_t i = 0; i + 1 < groove_.size(); ++i) {
    const GrooveCell& a = groove_[i];
    const GrooveCell& b = groove_[i + 1];
    Edge ea{}, eb{};
    if (a.cut != b.cut || !edge(a, ea) || !edge(b, eb)) continue;
    const auto v0 = static_cast<std::uint32_t>(drawn.vertices.size());
    for (const Vec3& q : {ea.left, ea.right, eb.right, eb.left}) {
      drawn.vertices.push_back(Vec3f{static_cast<float>(q.x), static_cast<float>(q.y), static_cast<float>(q.z)});
      drawn.normals.push_back(Vec3f{0, 0, 1});
    }
    for (const Edge* e : {&ea, &ea, &eb, &eb}) depth.push_back(e->depth), age.push_back(e->age);
    drawn.triangles.push_back({v0, v0 + 1, v0 + 2});
    drawn.triangles.push_back({v0, v0 + 2, v0 + 3});
    drawn.material.push_back(volume::kVessel);
    drawn.material.push_back(volume::kVessel);
  }
}

BloodFigures Bleeding::figures() const {
  BloodFigures f;
  for (const BloodSource& s : sources_) {
    f.lost_ml += s.loss_ml;
    if (s.kind == BloodSource::Kind::kVessel && !s.stopped) f.vessel_bleeding = true;
  }
  f.on_tissue_ml = automaton_.ledger().now * kMl;
  f.swabbed_ml = swabbed_ * kMl;
  f.ledger_error = automaton_.ledger().relative_error();
  f.cells = automaton_.network().cells();
  f.active_tiles = automaton_.active_tiles();
  f.tiles = automaton_.network().tiles();
  f.steps = automaton_.steps();
  f.rebuilds = rebuilds_;
  return f;
}

}  // namespace lancet::blood
