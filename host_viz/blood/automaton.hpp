#pragma once
// Bleeding: a mass-conserving virtual-pipe automaton on a graph of cells (ALGORITHMS.md §5).
//
// The domain is a graph: each cell has an area A (m²), a floor elevation e (m, height against
// gravity) and a film capacity F (m³: the blood a wetted cell keeps, the stain of thesis 5.4);
// pipes join neighbouring cells, each with a conductance C = g·w/l (w the pipe's width, l its
// length; g an effective gravity, Params::mobility, tuned so that blood runs a few cm/s down
// skin). On a surface mesh the cells are its vertices and the pipes its edges, so a cut that
// splits the mesh splits the network with it (docs/BLOOD.md says why not a texture atlas); the
// groove under an incision adds a chain of cells joined to the cut's two lips.
//
// One step of Δt (State holds the blood volume V per cell, m³, and a tracer, its birth mass: V
// times the mean time the blood left the vessels, s·m³, so a cell's mean age is now − born/V
// without touching still cells every step):
//   1. sources add volume born now; sinks (the swab) remove a fraction min(1, k·Δt) of a cell's
//      volume and tracer;
//   2. fluxes, per cell i and each of its pipes k to j, with the head h = e + V/A:
//        f_k = max(0, δ · f_k + Δt · C_k · m_i · (h_i − h_j))             (thesis 5.17)
//      δ = damping^Δt (so the damping does not depend on the step), m_i = min(1, (d_i/d_ref)²)
//      with d_i = max(0, V_i − F_i)/A_i the mobile depth (the thesis's viscous look: thin films
//      cling, thick ones run); then, where Σ_k f_k · Δt exceeds the mobile volume
//      M_i = max(0, V_i − F_i), all of cell i's fluxes are scaled by (1 − 1e-6) · M_i / (Σ_k f_k · Δt)
//      (the margin keeps rounding from overdrawing), so that a cell never sends more than it
//      holds above its film (Mei, Decaudin & Hu 2007);
//   3. volumes: V_i += Δt·Σ inflows − Δt·Σ outflows, the tracer likewise in flux form at the
//      sender's concentration. V never goes negative; the total changes only by sources and sinks
//      (the ledger checks it every step, in double).
// Work is done in tiles of kTile consecutive cells: a tile is stepped only while some cell in
// it holds mobile blood, has a source or sink, or still sends a flux, and volumes are updated
// only in tiles that such a tile sends to; skipping the others is exact (their fluxes are zero
// and stay zero). The GPU twin (blood/blood_compute) runs the same float operations in the same
// order. No OpenGL here.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "blood/worker_pool.hpp"

namespace lancet::blood {

inline constexpr std::size_t kTile = 256;

/// The cells and pipes. Pipes are half-edges in CSR order: cell i's go from first[i] to
/// first[i+1]; to[k] is the neighbour, twin[k] the half-edge back, conductance[k] = w/l.
struct Network {
  std::vector<float> area;       ///< m², > 0
  std::vector<float> elevation;  ///< m, the floor's height against gravity
  std::vector<float> film;       ///< m³ a cell keeps when blood has passed (not mobile)
  std::vector<std::uint32_t> first, to, twin;
  std::vector<float> conductance;
  /// Tiles (kTile cells) that tile t's cells have pipes into, t included: first_tile/tiles in CSR.
  std::vector<std::uint32_t> tile_first, tile_links;

  [[nodiscard]] std::size_t cells() const noexcept { return area.size(); }
  [[nodiscard]] std::size_t pipes() const noexcept { return to.size(); }
  [[nodiscard]] std::size_t tiles() const noexcept { return (cells() + kTile - 1) / kTile; }
};

/// Collects cells and pipes, then makes the CSR network (duplicate pipes are merged: their
/// conductances add; pipes from a cell to itself are dropped).
class NetworkBuilder {
 public:
  std::uint32_t add_cell(float area, float elevation, float film);
  /// A pipe both ways between a and b: width w and length l (m), conductance w/l (the step
  /// multiplies it by Params::mobility).
  void add_pipe(std::uint32_t a, std::uint32_t b, float width, float length);
  [[nodiscard]] Network build() const;
  /// Room for this many more cells and pipes (the builder grows as needed without it).
  void reserve(std::size_t more_cells, std::size_t more_pipes);
  [[nodiscard]] std::size_t cells() const noexcept { return area_.size(); }

 private:
  std::vector<float> area_, elevation_, film_;
  struct Pipe {
    std::uint32_t a, b;
    float conductance;
  };
  std::vector<Pipe> pipes_;
};

/// Appends a triangle mesh to a network being built (its vertex v becomes cell first + v, where
/// first is the builder's cell count before the call), as mesh_network describes.
void add_mesh(NetworkBuilder& b, std::span<const float> xyz, std::span<const std::uint32_t> triangles,
              const float gravity_dir[3], float film_depth);

/// A triangle mesh as a network: a cell per vertex with a third of its faces' area, a pipe per
/// edge whose width is the edge's dual (midpoint to the two faces' centroids), elevation the
/// vertex's height along -gravity_dir, film film_depth·area. Vertices that no face uses get a
/// tiny area and no pipes.
[[nodiscard]] Network mesh_network(std::span<const float> xyz, std::span<const std::uint32_t> triangles,
                                   const float gravity_dir[3], float film_depth);

struct Params {
  float dt = 0.002f;          ///< s a step
  float damping = 1e-6f;      ///< fraction of a pipe's flux left after one second without a drive
  float mobility = 1.5e-4f;   ///< m/s², the effective gravity in C = mobility·w/l (blood on skin: a few cm/s)
  float ref_depth = 5e-4f;    ///< m, mobile depth from which blood runs freely (m = 1)
  bool skip_idle_tiles = true;  ///< false: every tile every step (the tests' check that skipping is exact)
};

struct State {
  std::vector<float> volume;  ///< m³ per cell
  std::vector<float> born;    ///< s·m³ per cell (volume times the mean time it bled)
  std::vector<float> flux;    ///< m³/s per half-edge, >= 0
  std::vector<float> conc;    ///< s, born/V of each sending cell in the last flux pass
  double time = 0;            ///< s simulated
};

/// mass now = initial + sources − sinks, in double.
struct Ledger {
  double initial = 0, sources = 0, sinks = 0, now = 0;
  [[nodiscard]] double expected() const noexcept { return initial + sources - sinks; }
  /// |now − expected| over the largest of expected and the sources, 0 when nothing ever existed.
  [[nodiscard]] double relative_error() const noexcept;
};

class Automaton {
 public:
  Automaton() = default;
  Automaton(Network net, Params params);

  [[nodiscard]] const Network& network() const noexcept { return net_; }
  [[nodiscard]] const State& state() const noexcept { return s_; }
  [[nodiscard]] const Params& params() const noexcept { return p_; }
  [[nodiscard]] const Ledger& ledger() const noexcept { return ledger_; }

  /// Puts v m³ into cell i now (an initial condition: counted in the ledger's initial mass).
  void place(std::uint32_t i, float v);
  /// Source rates (m³/s per cell) and sink rates (1/s per cell) for the next steps; empty spans:
  /// none. Sizes must be cells() (else they are ignored).
  void set_sources(std::span<const float> rate);
  void set_sinks(std::span<const float> rate);
  [[nodiscard]] std::span<const float> sources() const noexcept { return source_; }
  [[nodiscard]] std::span<const float> sinks() const noexcept { return sink_; }

  /// One step (threads: 1 or more threads over the tiles; the result does not depend on it). The
  /// first step with more than one thread starts a WorkerPool that later steps reuse (another
  /// count starts another); a step itself never allocates.
  void step(int threads = 1);
  /// Steps run; tiles stepped in the last one.
  [[nodiscard]] std::uint64_t steps() const noexcept { return steps_; }
  [[nodiscard]] std::size_t active_tiles() const noexcept { return active_count_; }
  /// Volume removed by sinks in the last step (m³), per cell summed.
  [[nodiscard]] double last_sink_volume() const noexcept { return last_sink_; }

  /// Depth (m) of cell i: V / A.
  [[nodiscard]] float depth(std::uint32_t i) const noexcept { return s_.volume[i] / net_.area[i]; }
  /// Mean age (s) of cell i's blood (0 when dry).
  [[nodiscard]] float age(std::uint32_t i) const noexcept {
    return s_.volume[i] > 0.0f ? static_cast<float>(s_.time) - s_.born[i] / s_.volume[i] : 0.0f;
  }
  /// The tiles the last step worked on (its fluxes), for the GPU twin's check.
  [[nodiscard]] std::span<const std::uint8_t> tile_active() const noexcept { return active_; }

  /// Replaces the network (the mesh changed). New cell i takes the blood of old cell
  /// from_old[i] (kNoCell: none); without from_old, cells are matched by index. Fluxes start
  /// again from zero. Old cells that pass their blood to no new cell (or to a second one: only
  /// the first taker gets it) count it as a sink: lost with the tissue.
  static constexpr std::uint32_t kNoCell = 0xffffffffu;
  void reshape(Network net, std::span<const std::uint32_t> from_old = {});
  /// Moves the network's elevations and areas (the tissue moved or opened without changing its
  /// topology); the blood (its volume) stays where it is. Spans of another size are ignored.
  void set_geometry(std::span<const float> elevation, std::span<const float> area);

 private:
  // The passes of a step, each over one tile's cells.
  [[nodiscard]] bool tile_is_active(std::size_t t) const;  // works this step
  [[nodiscard]] bool tile_receives(std::size_t t) const;   // an active tile sends to it (itself included)
  void sources_and_sinks(std::size_t t, double& added, double& removed);
  void fluxes(std::size_t t);
  void volumes(std::size_t t);  // and the tile's volume summed afresh
  void update_heads(std::size_t from, std::size_t to);  // head_ of cells [from, to) from their volumes
  void mark_all();    // every tile may be active
  void mark_rates();  // the tiles with sources or sinks
  Network net_;
  Params p_;
  State s_;
  std::vector<float> source_, sink_;
  std::vector<float> head_;  // m per cell: elevation + volume / area, kept as the volumes change
  std::vector<float> gain_;  // per pipe: dt · (mobility · conductance), the flux pass's factor of m · Δhead
  std::vector<std::uint8_t> active_, receive_;
  std::vector<double> tile_added_, tile_removed_;  // per tile, this step
  std::vector<double> tile_volume_;                // per tile, as of the last step that touched it
  std::vector<std::uint8_t> tile_has_rate_, candidate_;  // a source or sink; may be active next step
  std::vector<std::uint8_t> sending_;       // per cell: some pipe of it sends (flux > 0), as its last fluxes pass left it
  std::vector<std::uint8_t> neighbour_sends_;  // per cell: a neighbour sent this step (set by the fluxes pass, cleared by the volumes pass)
  std::vector<std::uint8_t> tile_flowing_;  // some pipe of the tile sends (flux > 0), as its last fluxes pass left it
  Ledger ledger_;
  std::uint64_t steps_ = 0;
  std::size_t active_count_ = 0;
  double last_sink_ = 0;
  std::unique_ptr<WorkerPool> pool_;  // made by the first step with more than one thread
};

}  // namespace lancet::blood
