#include "blood/automaton.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>

namespace lancet::blood {

// ---- the network ----------------------------------------------------------------------------

std::uint32_t NetworkBuilder::add_cell(float area, float elevation, float film) {
  area_.push_back(std::max(area, 1e-12f));
  elevation_.push_back(elevation);
  film_.push_back(std::max(film, 0.0f));
  return static_cast<std::uint32_t>(area_.size() - 1);
}

void NetworkBuilder::reserve(std::size_t more_cells, std::size_t more_pipes) {
  area_.reserve(area_.size() + more_cells);
  elevation_.reserve(elevation_.size() + more_cells);
  film_.reserve(film_.size() + more_cells);
  pipes_.reserve(pipes_.size() + more_pipes);
}

void NetworkBuilder::add_pipe(std::uint32_t a, std::uint32_t b, float width, float length) {
  if (a == b || a >= area_.size() || b >= area_.size() || !(width > 0.0f) || !(length > 0.0f)) return;
  pipes_.push_back({a, b, width / length});
}

Network NetworkBuilder::build() const {
  Network n;
  n.area = area_;
  n.elevation = elevation_;
  n.film = film_;
  const std::size_t cells = area_.size();
  // Bucket every pipe under both its ends (a counting sort by source), then per cell sort the
  // few entries by neighbour (stable: duplicates, a mesh edge seen from both its faces, merge in
  // the order they were added, so both directions get the same sum).
  std::vector<std::uint32_t> start(cells + 1, 0);
  for (const Pipe& p : pipes_) ++start[p.a + 1], ++start[p.b + 1];
  for (std::size_t i = 0; i < cells; ++i) start[i + 1] += start[i];
  struct Half {
    std::uint32_t to;
    float conductance;
  };
  std::vector<Half> bucket(start[cells]);
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
  for (const Pipe& p : pipes_) {
    bucket[fill[p.a]++] = {p.b, p.conductance};
    bucket[fill[p.b]++] = {p.a, p.conductance};
  }
  // Per cell, its entries sorted by neighbour and the duplicates merged in place at the front of
  // its range; then the arrays are made at their final size (a mesh edge comes from both its
  // faces, so the bucket holds each half-edge twice: sized by it, they were twice too long).
  for (std::size_t i = 0; i < cells; ++i) {
    const auto b = bucket.begin() + start[i], e = bucket.begin() + start[i + 1];
    // An insertion sort: stable, and a cell has a dozen entries (std::stable_sort would take a
    // buffer from the heap for each cell).
    for (auto it = b + (b != e ? 1 : 0); it < e; ++it) {
      const Half x = *it;
      auto at = it;
      for (; at != b && (at - 1)->to > x.to; --at) *at = *(at - 1);
      *at = x;
    }
    auto w = b;
    for (auto it = b; it != e; ++it) {
      if (w != b && (w - 1)->to == it->to)
        (w - 1)->conductance += it->conductance;
      else
        *w++ = *it;
    }
    fill[i] = static_cast<std::uint32_t>(w - b);  // this cell's distinct neighbours
  }
  n.first.assign(cells + 1, 0);
  for (std::size_t i = 0; i < cells; ++i) n.first[i + 1] = n.first[i] + fill[i];
  n.to.resize(n.first[cells]);
  n.conductance.resize(n.first[cells]);
  for (std::size_t i = 0; i < cells; ++i)
    for (std::uint32_t k = 0; k < fill[i]; ++k) {
      n.to[n.first[i] + k] = bucket[start[i] + k].to;
      n.conductance[n.first[i] + k] = bucket[start[i] + k].conductance;
    }
  n.twin.resize(n.to.size());
  for (std::size_t i = 0; i < cells; ++i)
    for (std::uint32_t k = n.first[i]; k < n.first[i + 1]; ++k) {
      const std::uint32_t j = n.to[k];
      // The half-edge j→i: neighbours are sorted, so a binary search in j's range.
      const auto begin = n.to.begin() + n.first[j], end = n.to.begin() + n.first[j + 1];
      n.twin[k] = static_cast<std::uint32_t>(std::lower_bound(begin, end, static_cast<std::uint32_t>(i)) - n.to.begin());
    }
  // Tile links: the tiles a tile's cells send to (itself included), sorted.
  const std::size_t tiles = n.tiles();
  n.tile_first.assign(tiles + 1, 0);
  std::vector<std::uint32_t> seen(tiles, 0xffffffffu), to_tiles;
  for (std::size_t t = 0; t < tiles; ++t) {
    to_tiles.assign(1, static_cast<std::uint32_t>(t));
    seen[t] = static_cast<std::uint32_t>(t);
    for (std::size_t i = t * kTile; i < std::min(cells, (t + 1) * kTile); ++i)
      for (std::uint32_t k = n.first[i]; k < n.first[i + 1]; ++k) {
        const auto u = static_cast<std::uint32_t>(n.to[k] / kTile);
        if (seen[u] != t) seen[u] = static_cast<std::uint32_t>(t), to_tiles.push_back(u);
      }
    std::sort(to_tiles.begin(), to_tiles.end());
    n.tile_links.insert(n.tile_links.end(), to_tiles.begin(), to_tiles.end());
    n.tile_first[t + 1] = static_cast<std::uint32_t>(n.tile_links.size());
  }
  return n;
}

Network mesh_network(std::span<const float> xyz, std::span<const std::uint32_t> triangles, const float gravity_dir[3],
                     float film_depth) {
  NetworkBuilder nb;
  add_mesh(nb, xyz, triangles, gravity_dir, film_depth);
  return nb.build();
}

void add_mesh(NetworkBuilder& nb, std::span<const float> xyz, std::span<const std::uint32_t> triangles, const float gravity_dir[3],
              float film_depth) {
  const auto first = static_cast<std::uint32_t>(nb.cells());
  const std::size_t nv = xyz.size() / 3;
  nb.reserve(nv, triangles.size());
  const auto p = [&](std::uint32_t v) { return std::array<double, 3>{xyz[3 * v], xyz[3 * v + 1], xyz[3 * v + 2]}; };
  const double gl = std::sqrt(gravity_dir[0] * gravity_dir[0] + gravity_dir[1] * gravity_dir[1] + gravity_dir[2] * gravity_dir[2]);
  const double g[3] = {gravity_dir[0] / gl, gravity_dir[1] / gl, gravity_dir[2] / gl};
  std::vector<double> area(nv, 0.0);
  struct Edge {
    std::uint32_t a, b;
    double dual;  // midpoint-to-centroid length contributed by one face
  };
  std::vector<Edge> edges;
  edges.reserve(triangles.size());
  for (std::size_t f = 0; f + 2 < triangles.size(); f += 3) {
    const std::uint32_t v[3] = {triangles[f], triangles[f + 1], triangles[f + 2]};
    if (v[0] >= nv || v[1] >= nv || v[2] >= nv) continue;
    const auto a = p(v[0]), b = p(v[1]), c = p(v[2]);
    const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const double cr[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
    const double fa = 0.5 * std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
    for (auto vi : v) area[vi] += fa / 3.0;
    const double centroid[3] = {(a[0] + b[0] + c[0]) / 3, (a[1] + b[1] + c[1]) / 3, (a[2] + b[2] + c[2]) / 3};
    for (int e = 0; e < 3; ++e) {
      const std::uint32_t x = v[e], y = v[(e + 1) % 3];
      const auto px = p(x), py = p(y);
      const double mid[3] = {0.5 * (px[0] + py[0]) - centroid[0], 0.5 * (px[1] + py[1]) - centroid[1], 0.5 * (px[2] + py[2]) - centroid[2]};
      edges.push_back({x, y, std::sqrt(mid[0] * mid[0] + mid[1] * mid[1] + mid[2] * mid[2])});
    }
  }
  for (std::size_t v = 0; v < nv; ++v) {
    const auto q = p(static_cast<std::uint32_t>(v));
    const double elevation = -(q[0] * g[0] + q[1] * g[1] + q[2] * g[2]);
    const double a = area[v] > 0 ? area[v] : 1e-12;
    nb.add_cell(static_cast<float>(a), static_cast<float>(elevation), static_cast<float>(film_depth * a));
  }
  for (const Edge& e : edges) {
    const auto a = p(e.a), b = p(e.b);
    const double l = std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
    nb.add_pipe(first + e.a, first + e.b, static_cast<float>(e.dual), static_cast<float>(l));
  }
}

// ---- the ledger ---------------------------------------------------------------------------

double Ledger::relative_error() const noexcept {
  const double scale = std::max({std::abs(expected()), sources, initial});
  return scale > 0 ? std::abs(now - expected()) / scale : 0.0;
}

// ---- the automaton ------------------------------------------------------------------------

Automaton::Automaton(Network net, Params params) : p_(params) { reshape(std::move(net)); }

void Automaton::reshape(Network net, std::span<const std::uint32_t> from_old) {
  const std::size_t n = net.cells(), old_n = s_.volume.size();
  std::vector<float> volume(n, 0.0f), born(n, 0.0f);
  std::vector<std::uint8_t> taken(old_n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t o = from_old.empty() ? i : from_old.size() == n ? from_old[i] : kNoCell;
    if (o >= old_n || taken[o]) continue;
    taken[o] = 1;
    volume[i] = s_.volume[o];
    born[i] = s_.born[o];
  }
  double lost = 0;
  for (std::size_t o = 0; o < old_n; ++o)
    if (!taken[o]) lost += s_.volume[o];
  net_ = std::move(net);
  s_.volume = std::move(volume);
  s_.born = std::move(born);
  s_.conc.assign(n, 0.0f);
  s_.flux.assign(net_.pipes(), 0.0f);
  sending_.assign(n, 0);
  neighbour_sends_.assign(n, 0);
  source_.assign(n, 0.0f);
  sink_.assign(n, 0.0f);
  active_.assign(net_.tiles(), 0);
  receive_.assign(net_.tiles(), 0);
  tile_added_.assign(net_.tiles(), 0.0);
  tile_removed_.assign(net_.tiles(), 0.0);
  tile_volume_.assign(net_.tiles(), 0.0);
  tile_has_rate_.assign(net_.tiles(), 0);
  tile_flowing_.assign(net_.tiles(), 0);
  candidate_.assign(net_.tiles(), 1);
  ledger_.sinks += lost;
  double now = 0;
  for (std::size_t i = 0; i < n; ++i) {
    tile_volume_[i / kTile] += s_.volume[i];
    now += s_.volume[i];
  }
  ledger_.now = now;
  head_.resize(n);
  update_heads(0, n);
  // The same product, in the same order, that the flux pass formed per pipe and step.
  gain_.resize(net_.pipes());
  for (std::size_t k = 0; k < gain_.size(); ++k) gain_[k] = p_.dt * (p_.mobility * net_.conductance[k]);
}

void Automaton::set_geometry(std::span<const float> elevation, std::span<const float> area) {
  mark_all();
  if (elevation.size() == net_.elevation.size()) std::copy(elevation.begin(), elevation.end(), net_.elevation.begin());
  if (area.size() == net_.area.size())
    for (std::size_t i = 0; i < area.size(); ++i) net_.area[i] = std::max(area[i], 1e-12f);
  update_heads(0, net_.cells());
}

void Automaton::place(std::uint32_t i, float v) {
  if (i >= s_.volume.size() || !(v > 0.0f)) return;
  s_.volume[i] += v;
  s_.born[i] += v * static_cast<float>(s_.time);
  update_heads(i, i + 1);
  ledger_.initial += v;
  ledger_.now += v;
  tile_volume_[i / kTile] += v;
  candidate_[i / kTile] = 1;
}

namespace {

// A caller's rates: empty clears them, another size is ignored, and a rate that is negative or
// not finite counts as none.
void copy_rates(std::vector<float>& to, std::span<const float> rate) {
  if (rate.empty()) {
    std::fill(to.begin(), to.end(), 0.0f);
  } else if (rate.size() == to.size()) {
    for (std::size_t i = 0; i < rate.size(); ++i) to[i] = std::isfinite(rate[i]) ? std::max(rate[i], 0.0f) : 0.0f;
  }
}

}  // namespace

void Automaton::set_sources(std::span<const float> rate) {
  copy_rates(source_, rate);
  mark_rates();
}

void Automaton::set_sinks(std::span<const float> rate) {
  copy_rates(sink_, rate);
  mark_rates();
}

void Automaton::mark_rates() {
  const std::size_t n = net_.cells();
  for (std::size_t t = 0; t < tile_has_rate_.size(); ++t) {
    bool any = false;
    for (std::size_t i = t * kTile; i < std::min(n, (t + 1) * kTile) && !any; ++i) any = source_[i] > 0.0f || sink_[i] > 0.0f;
    tile_has_rate_[t] = any ? 1 : 0;
    if (any) candidate_[t] = 1;
  }
}

bool Automaton::tile_is_active(std::size_t t) const {
  // Only tiles that the last step touched (worked on or sent to), or that hold a source or a
  // sink, can be active now: an untouched idle tile has no mobile blood and no flux, and nothing
  // changed it. reshape, place and set_geometry mark every tile.
  if (!p_.skip_idle_tiles) return true;
  if (candidate_[t] == 0) return false;
  const std::size_t n = net_.cells();
  if (tile_flowing_[t] != 0) return true;  // some pipe of the tile still sends
  for (std::size_t i = t * kTile; i < std::min(n, (t + 1) * kTile); ++i)
    if (s_.volume[i] > net_.film[i] || source_[i] > 0.0f || (sink_[i] > 0.0f && s_.volume[i] > 0.0f)) return true;
  return false;
}

bool Automaton::tile_receives(std::size_t t) const {
  // Pipes go both ways, so the tiles that send to t are the tiles t sends to (t among them).
  for (std::uint32_t l = net_.tile_first[t]; l < net_.tile_first[t + 1]; ++l)
    if (active_[net_.tile_links[l]] != 0) return true;
  return false;
}

void Automaton::update_heads(std::size_t from, std::size_t to) {
  for (std::size_t i = from; i < to; ++i) head_[i] = net_.elevation[i] + s_.volume[i] / net_.area[i];
}

void Automaton::mark_all() { std::fill(candidate_.begin(), candidate_.end(), 1); }

void Automaton::sources_and_sinks(std::size_t t, double& added, double& removed) {
  const std::size_t n = net_.cells();
  const float dt = p_.dt, now = static_cast<float>(s_.time);
  added = removed = 0;
  for (std::size_t i = t * kTile; i < std::min(n, (t + 1) * kTile); ++i) {
    if (source_[i] > 0.0f) {
      const float v = source_[i] * dt;
      s_.volume[i] += v;
      s_.born[i] += v * now;
      added += v;
    }
    if (sink_[i] > 0.0f && s_.volume[i] > 0.0f) {
      const float f = std::min(1.0f, sink_[i] * dt);
      const float v = s_.volume[i] * f;
      removed += v;
      s_.volume[i] -= v;
      s_.born[i] -= s_.born[i] * f;
    }
  }
  update_heads(t * kTile, std::min(n, (t + 1) * kTile));
}

void Automaton::fluxes(std::size_t t) {
  const std::size_t n = net_.cells();
  const float dt = p_.dt;
  const float keep = std::pow(p_.damping, dt);
  const float ref_depth = p_.ref_depth;
  // Plain pointers: the flux stores could otherwise alias every float the loop reads.
  const float* const head = head_.data();
  const float* const gain = gain_.data();
  const std::uint32_t* const to = net_.to.data();
  float* const flux = s_.flux.data();
  bool flowing = false;
  std::uint8_t* const sending = sending_.data();
  for (std::size_t i = t * kTile; i < std::min(n, (t + 1) * kTile); ++i) {
    const float v = s_.volume[i], a = net_.area[i];
    // Most cells of a working tile are dry and send nothing: with no mobile blood (m = 0) a pipe's
    // flux is max(0, keep · 0 + 0), so every pipe stays at exactly 0 and the loop is skipped.
    if (sending[i] == 0 && !(v > net_.film[i])) {
      s_.conc[i] = v > 0.0f ? s_.born[i] / v : 0.0f;
      continue;
    }
    const float mobile = std::max(0.0f, v - net_.film[i]);
    const float d = mobile / a / ref_depth;
    const float m = std::min(1.0f, d * d);
    const std::uint32_t first = net_.first[i], last = net_.first[i + 1];
    float sum = 0.0f;
    for (std::uint32_t k = first; k < last; ++k) {
      const float f = std::max(0.0f, keep * flux[k] + gain[k] * m * (head[i] - head[to[k]]));
      flux[k] = f;
      sum += f;
    }
    const float out = sum * dt;
    bool sends = sum > 0.0f;  // every flux is >= 0: some pipe sends
    if (out > mobile) {
      const float scale = out > 0.0f ? 0.999999f * mobile / out : 0.0f;
      sends = false;
      for (std::uint32_t k = first; k < last; ++k) {
        flux[k] *= scale;
        sends = sends || flux[k] > 0.0f;
      }
    }
    sending[i] = sends ? 1 : 0;
    flowing = flowing || sends;
    // Its neighbours may receive: the volumes pass looks at them (and clears the mark). A
    // neighbour may lie in a tile another thread steps, hence the atomic store.
    if (sends)
      for (std::uint32_t k = first; k < last; ++k) std::atomic_ref<std::uint8_t>(neighbour_sends_[to[k]]).store(1, std::memory_order_relaxed);
    s_.conc[i] = v > 0.0f ? s_.born[i] / v : 0.0f;
  }
  tile_flowing_[t] = flowing ? 1 : 0;
}

void Automaton::volumes(std::size_t t) {
  const std::size_t n = net_.cells();
  const float dt = p_.dt;
  const float* const flux = s_.flux.data();
  const float* const conc = s_.conc.data();
  const std::uint32_t* const twin = net_.twin.data();
  const std::uint32_t* const to = net_.to.data();
  const std::uint8_t* const sending = sending_.data();
  std::uint8_t* const neighbour_sends = neighbour_sends_.data();
  for (std::size_t i = t * kTile; i < std::min(n, (t + 1) * kTile); ++i) {
    // A cell that sends nothing, among neighbours that send nothing, has no flux in or out.
    const std::uint32_t first = net_.first[i], last = net_.first[i + 1];
    if (sending[i] == 0 && neighbour_sends[i] == 0) continue;
    neighbour_sends[i] = 0;
    float in = 0.0f, out = 0.0f, born_in = 0.0f;
    for (std::uint32_t k = first; k < last; ++k) {
      const float f_in = flux[twin[k]];
      in += f_in;
      born_in += f_in * conc[to[k]];
      out += flux[k];
    }
    if (in == 0.0f && out == 0.0f) continue;
    const float v = s_.volume[i] + dt * in - dt * out;
    const float b = s_.born[i] + dt * born_in - dt * out * s_.conc[i];
    s_.volume[i] = std::max(v, 0.0f);
    s_.born[i] = std::max(b, 0.0f);
    head_[i] = net_.elevation[i] + s_.volume[i] / net_.area[i];
  }
  double sum = 0;
  for (std::size_t i = t * kTile; i < std::min(n, (t + 1) * kTile); ++i) sum += s_.volume[i];
  tile_volume_[t] = sum;
}

void Automaton::step(int threads) {
  const std::size_t tiles = net_.tiles();
  threads = std::max(1, std::min(threads, static_cast<int>(tiles)));
  if (threads > 1 && (!pool_ || pool_->threads() != threads)) pool_ = std::make_unique<WorkerPool>(threads);
  // Three passes over the tiles, each complete before the next starts: 1. which tiles work this
  // step, and their sources and sinks (a tile's own cells); 2. fluxes (reading the neighbours'
  // volumes after 1); 3. volumes (reading the fluxes after 2) in the tiles an active tile sends
  // to, and those tiles' volume summed afresh. Every pass writes only its tile's cells and
  // pipes, and the tiles are dealt to the threads in a fixed pattern, so the result is the same
  // for any thread count.
  auto job = [&](int w) {
    const auto stride = static_cast<std::size_t>(threads);
    for (std::size_t t = static_cast<std::size_t>(w); t < tiles; t += stride) {
      active_[t] = tile_is_active(t) ? 1 : 0;
      if (active_[t]) sources_and_sinks(t, tile_added_[t], tile_removed_[t]);
    }
    if (threads > 1) pool_->sync();
    for (std::size_t t = static_cast<std::size_t>(w); t < tiles; t += stride)
      if (active_[t]) fluxes(t);
    if (threads > 1) pool_->sync();
    for (std::size_t t = static_cast<std::size_t>(w); t < tiles; t += stride) {
      receive_[t] = tile_receives(t) ? 1 : 0;
      if (receive_[t]) volumes(t);
    }
  };
  if (threads > 1)
    pool_->run(job);
  else
    job(0);
  // The ledger, in tile order: what the active tiles added and removed, and the mass now (every
  // tile's volume, as of the last step that touched it).
  double added = 0, removed = 0, now = 0;
  active_count_ = 0;
  for (std::size_t t = 0; t < tiles; ++t) {
    if (active_[t]) added += tile_added_[t], removed += tile_removed_[t], ++active_count_;
    now += tile_volume_[t];
    candidate_[t] = active_[t] || receive_[t] || tile_has_rate_[t] ? 1 : 0;
  }
  ledger_.sources += added;
  ledger_.sinks += removed;
  last_sink_ = removed;
  ledger_.now = now;
  s_.time += p_.dt;
  ++steps_;
}

}  // namespace lancet::blood
