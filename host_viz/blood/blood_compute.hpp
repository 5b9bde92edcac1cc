#pragma once
// BloodCompute: the GPU twin of blood::Automaton (blood/automaton.hpp states the algorithm), as
// GL 4.5 compute shaders. One invocation per cell and one workgroup of blood::kTile invocations
// per tile, so that workgroup w works on tile w. A step is four passes with a storage barrier
// between them: plan (each tile's active flag, and the tiles an active tile sends to stamped as
// receivers), sources and sinks, fluxes, volumes; the last three return at once in tiles the
// plan left out, as the CPU skips them, so that nothing is read back during a step. The float
// operations are the reference's, in its order, and marked precise (no fused multiply-add), so
// that on llvmpipe the two agree to the bit (CPU and GPU agree within 1e-5 after 100 steps is
// the acceptance). The network and the state live in storage buffers; mass is summed per tile
// in double (GL 4.0 made doubles core), the tiles' sums are added on the CPU. Needs a current
// GL 4.5 context.

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "blood/automaton.hpp"
#include "render/gl_objects.hpp"

namespace lancet::blood {

using render::Buffer;
using render::Program;

class BloodCompute {
 public:
  /// Compiles the passes and uploads the network; no blood, no sources, no sinks. Throws
  /// std::runtime_error when GL refuses a shader.
  BloodCompute(const blood::Network& net, const blood::Params& params);

  /// Replaces volume, born, flux, conc (each only when its size matches the network's; a wrong
  /// size or an empty vector: zeros) and the simulated time; the ledger starts again from this
  /// blood (its initial mass).
  void upload_state(const blood::State& s);
  /// As Automaton::set_sources / set_sinks: m³/s and 1/s per cell; empty: none; a size other
  /// than cells() is ignored.
  void set_sources(std::span<const float> rate);
  void set_sinks(std::span<const float> rate);
  /// As Automaton::set_geometry: the tissue moved or opened, the blood stays (a span of a size
  /// other than cells() is ignored).
  void set_geometry(std::span<const float> elevation, std::span<const float> area);

  /// One step of Params::dt (Automaton::step). Leaves its program current and its buffers bound
  /// at storage-buffer binding points 0 to 18.
  void step();

  /// The state (a read-back: waits for the GPU).
  [[nodiscard]] blood::State download() const;
  /// The blood on the network now, m³: per-tile sums on the GPU, added here in double.
  [[nodiscard]] double total_volume() const;
  /// Initial mass (of the last upload_state), sources and sinks so far (each tile's in double on
  /// the GPU), now = total_volume().
  [[nodiscard]] blood::Ledger ledger() const;
  /// The tiles the last step worked on (read back), as Automaton::tile_active().
  [[nodiscard]] std::vector<std::uint8_t> tile_active() const;

  [[nodiscard]] std::size_t cells() const noexcept { return cells_; }
  [[nodiscard]] std::size_t tiles() const noexcept { return tiles_; }
  [[nodiscard]] double time() const noexcept { return time_; }
  [[nodiscard]] std::uint64_t steps() const noexcept { return steps_; }
  /// Per cell, m³ (std430 float[cells()]): what a renderer reads for the depths (V / area).
  [[nodiscard]] GLuint volume_buffer() const noexcept { return volume_.get(); }
  [[nodiscard]] GLuint area_buffer() const noexcept { return area_.get(); }

 private:
  void bind() const;
  void dispatch_tiles(const Program& program) const;
  void upload_rates(const Buffer& buffer, std::span<const float> rate, bool& any);
  Program plan_, sources_, fluxes_, volumes_, mass_;
  // The network (read only) and the state, bound at fixed storage-buffer binding points.
  Buffer area_, elevation_, film_, first_, to_, twin_, conductance_, tile_first_, tile_links_;
  Buffer volume_, born_, flux_, conc_, source_, sink_;
  Buffer active_;    ///< uint per tile: this step works on it
  Buffer receive_;   ///< uint per tile: the step's stamp when an active tile sends to it
  Buffer tile_sum_;  ///< double per tile: total_volume's partial sums
  Buffer ledger_;    ///< dvec2 per tile: volume added by sources, removed by sinks, so far
  std::size_t cells_ = 0, pipes_ = 0, tiles_ = 0;
  blood::Params params_;
  float keep_ = 0;  ///< damping^dt, as the CPU computes it
  double time_ = 0, initial_ = 0;
  std::uint64_t steps_ = 0;
  std::uint32_t stamp_ = 0;  ///< the step's stamp for receive_ (cleared only when it wraps)
  bool any_source_ = false, any_sink_ = false;  ///< neither: pass 1 changes nothing, not dispatched
};

}  // namespace lancet::blood
