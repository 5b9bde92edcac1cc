#pragma once
// Bleeding: the blood automaton (blood/automaton) laid on a TissueScene, with sources that make
// clinical sense (ALGORITHMS.md §5, docs/BLOOD.md).
//
// The domain: a cell per vertex of the skin surface, pipes along its edges (a cut splits the
// mesh, and with it the flow), and under every incision a chain of groove cells, one per pair of
// split vertices, joined to both lips and to each other: blood reaching a lip falls into the
// opening, fills the groove and, once it is full, wells over onto the skin. Gravity is world −z.
//
// The sources:
//   - ooze from a fresh cut: along each lip, rate ∝ segment length · (1 + opening / 1 mm)
//     (thesis 5.16: it grows with the cut's width), decaying as it clots (time constant
//     ooze_clot_s from when that piece of the cut was made);
//   - the groove's walls ooze into the groove cells once the incision is opened, ∝ wall area;
//   - a cut vessel: where a cut's depth reaches one of the scene's vessel labels (PhantomMaterial
//     kVessel, the contrast-filled arteries, or kVein), or the drill removes one, a strong constant bleed into that point's groove cell (or
//     onto the skin) that stops only once the probe or the retractor presses on it (in contact,
//     within press_radius) for press_seconds without letting go.
// The swab (ToolMode::kSwab) removes blood within swab_radius of its tip: a sink. Blood loss
// (mL) is counted per source.
//
// Not real-time (the viz thread); allocates when the surface's topology changes.

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "blood/automaton.hpp"
#include "tissue/tissue_scene.hpp"
#include "lancet/shared_model/messages.hpp"
#include "surface/triangle_mesh.hpp"

namespace lancet::blood {

using tissue::TissueScene;

struct BleedingParams {
  blood::Params automaton{0.004f, 1e-6f, 1.5e-4f, 4e-4f, true};
  double film_depth = 2e-5;          ///< m of blood a wetted surface keeps
  double ooze_per_m = 1e-6;          ///< m³/s per m of fresh cut, closed (0.03 mL/s for 30 mm; five times that opened 4 mm)
  double ooze_clot_s = 90;           ///< s, the ooze's decay time
  double wall_ooze_per_m2 = 2e-5;    ///< m³/s per m² of opened groove wall
  double vessel_rate = 3e-7;         ///< m³/s from a cut vessel (0.3 mL/s)
  double press_radius = 0.006;       ///< m, how near a pressing tool must be to a bleeding vessel
  double press_seconds = 3;          ///< s of continuous pressure that stops it
  double swab_radius = 0.004;        ///< m
  double swab_rate = 25;             ///< 1/s, the fraction per second a swab takes from a cell it touches
  double max_frame = 0.1;            ///< s: a longer frame is simulated as this long (the viz stalled)
  double rebuild_interval = 0.5;    ///< s of scene time between two rebuilds of the network (topology changes)
  int threads = 2;                   ///< the automaton's threads (a pool made once; the blood does not depend on it)
};

/// One source of blood loss, for the panel and the training metrics.
struct BloodSource {
  enum class Kind : std::uint8_t { kCutOoze, kGrooveWall, kVessel };
  Kind kind = Kind::kCutOoze;
  std::string name;
  double loss_ml = 0;     ///< bled so far
  double rate_ml_s = 0;   ///< now
  bool stopped = false;   ///< a vessel that was pressed until it stopped
  Vec3 position{};        ///< m, a vessel's bleeding point
  double pressed_s = 0;   ///< s of the current uninterrupted press (vessels)
};

struct BloodFigures {
  double lost_ml = 0;        ///< all sources so far
  double on_tissue_ml = 0;   ///< on the skin and in the grooves now
  double swabbed_ml = 0;     ///< removed by the swab
  double ledger_error = 0;   ///< the automaton's relative mass error (should stay ~1e-7)
  std::size_t cells = 0, active_tiles = 0, tiles = 0;
  std::uint64_t steps = 0;
  std::uint64_t rebuilds = 0;  ///< networks built (topology changes)
  bool vessel_bleeding = false;
};

class Bleeding {
 public:
  explicit Bleeding(const TissueScene& scene, BleedingParams params = {});

  /// The tool as lancet-rt reported it this frame (the newest samples, in order): its position,
  /// mode and contact, and drill removals (a vessel drilled into bleeds).
  void observe(std::span<const ToolSample> samples);
  /// Advances the blood by dt seconds of the scene as it is now (capped at max_frame): rebuilds
  /// the network when the surface's topology changed, refreshes elevations when it moved, sets the
  /// sources and the swab, and steps the automaton.
  void advance(const TissueScene& scene, double dt);
  /// advance() in two halves: prepare() does all that reads the scene (the network, the elevations,
  /// the sources and the swab) and may run beside other readers of the scene (the patch export);
  /// step() then steps the automaton, without the scene, on `threads` automaton threads (0: the
  /// params' threads; the blood does not depend on it). It touches nothing observe() does, so a
  /// step may run on another thread while the next frame's samples are observed.
  void prepare(const TissueScene& scene, double dt);
  void step(int threads = 0);

  /// Per vertex of `drawn` (the scene's draw_mesh: the surface's vertices first, then the
  /// grooves' walls and floors): blood depth (m) and mean age (s). Wall vertices under a groove's
  /// blood level get the depth of blood above them.
  void vertex_blood(const surface::TriangleMesh& drawn, std::vector<float>& depth, std::vector<float>& age) const;

  /// Appends the blood standing in the grooves to `drawn`: between each two neighbouring groove
  /// cells that hold blood, a flat quad at their blood level, as wide as the opening is at that
  /// level (a V of the cut's depth), with its blood depth and age appended to depth and age (which
  /// vertex_blood filled for `drawn`). What a trainee sees in the opening when the volume, not
  /// the groove's walls, is drawn beneath.
  void append_pools(const TissueScene& scene, surface::TriangleMesh& drawn, std::vector<float>& depth, std::vector<float>& age) const;

  [[nodiscard]] const std::vector<BloodSource>& sources() const noexcept { return sources_; }
  [[nodiscard]] BloodFigures figures() const;
  [[nodiscard]] const blood::Automaton& automaton() const noexcept { return automaton_; }
  /// Cells in the grooves (one per pair of split vertices).
  [[nodiscard]] std::size_t groove_cells() const noexcept { return groove_.size(); }

 private:
  struct GrooveCell {
    std::uint32_t cell;       // automaton index
    std::size_t cut, pair;
    Vec3 centre;              // m, between the lips at the rim
    float floor;              // m, elevation of the cell's floor
    double spacing;           // m along the cut
  };
  void rebuild(const TissueScene& scene);
  void refresh_elevations(const TissueScene& scene);
  void find_vessels(const TissueScene& scene);
  void add_vessel(const TissueScene& scene, const std::string& name, Vec3 at);
  std::uint32_t nearest_cell(const TissueScene& scene, Vec3 p) const;
  void set_rates(const TissueScene& scene, double dt);

  BleedingParams p_;
  blood::Automaton automaton_;
  std::size_t skin_cells_ = 0;
  std::vector<GrooveCell> groove_;
  std::vector<std::size_t> pairs_seen_;      // per cut: pairs already examined for vessels
  std::vector<std::vector<double>> pair_born_;  // per cut, per pair: scene time the pair was cut
  std::vector<std::uint32_t> vessel_cell_;   // per source (vessels only; kNoCell otherwise)
  std::vector<BloodSource> sources_;
  std::vector<float> source_rate_, sink_rate_;
  std::size_t faces_seen_ = 0, vertices_seen_ = 0, groove_pairs_seen_ = 0;
  std::uint64_t revision_seen_ = 0, rebuilds_ = 0;
  double time_ = 0, rebuilt_at_ = -1e9;
  int prepared_steps_ = 0;  // by prepare(), for step()
  double swabbed_ = 0;
  // The tool, from the newest sample.
  /// Each hand's tool as its newest sample left it (a vessel is pressed, or blood swabbed, by either hand).
  struct HandTool {
    Vec3 tool{};
    ToolMode mode = ToolMode::kProbe;
    bool contact = false, seen = false;
  };
  std::array<HandTool, kHandCount> hands_{};
  std::vector<Vec3> drilled_;  // removal centres since the last advance
};

}  // namespace lancet::blood
