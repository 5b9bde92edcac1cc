#pragma once
// The visualizer's frame, one function for live and replay:
//   drain the frame's ToolSamples (both hands', in tick order) → apply them to the scene → export
//   each hand's patch around that hand's newest tool position (its header set here, and only
//   here) → publish them → advance the blood.
// The blood comes last: it changes nothing a patch holds, and the servo gets the new patch without
// waiting for it.
// Where the samples come from and where the patch goes belongs to a FrameIo: the shared-memory
// link live (app/live_frame.hpp: drained from lancet-rt's ring, published to its seqlock), the
// recording in a replay (record/replay.hpp: re-stepped through the servo, kept for the ticks that
// use it). Because both run this sequence, a replay steps the scene exactly as the live frame did.

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"
#include "sim/scene_sim.hpp"

namespace lancet::sim {

/// A TissuePatch's header: which frame published it, when, and after which servo tick.
struct PatchHeader {
  std::uint64_t seq = 0;              ///< TissuePatch::seq (the publishing frame)
  std::int64_t t_ns = 0;              ///< TissuePatch::t_ns (CLOCK_MONOTONIC, ns)
  std::uint64_t samples_applied = 0;  ///< TissuePatch::samples_applied (newest ToolSample::seq applied)
};

/// One hand's patch in a frame.
struct HandPatch {
  TissuePatch* patch = nullptr;  ///< the patch is exported into this; null: none this frame for this hand
  Vec3 centre{};                 ///< m, the patch is cut out around it (the hand's newest tool position)
  PatchHeader header{};          ///< set on the patch after its export
};

/// What one frame is given by its FrameIo.
struct FrameBatch {
  std::span<const ToolSample> samples;  ///< for the scene, in tick order; valid until publish() returns
  double blood_dt = 0;                  ///< s of blood to simulate this frame
  std::array<HandPatch, kHandCount> patches{};  ///< by Hand
};

/// What one frame did, and where its time went.
struct FrameResult {
  std::size_t samples = 0;     ///< applied to the scene
  double blood_dt = 0;         ///< s of blood simulated
  std::array<bool, kHandCount> patch{};  ///< by Hand: a patch was exported and handed to publish()
  std::array<std::size_t, kHandCount> triangles{};  ///< by Hand: its patch's triangle count
  double scene_s = 0, patch_s = 0, blood_s = 0;  ///< s spent applying; exporting (with the blood's preparation beside it) and publishing; stepping the blood
};

/// The two ends of a frame: where its samples come from, where its patch goes.
class FrameIo {
 public:
  virtual ~FrameIo() = default;
  /// The frame's samples, blood time and patch buffer. An error stops the frame before the scene
  /// changes (a replay whose recording lacks a patch a tick used).
  [[nodiscard]] virtual Result<FrameBatch> drain() = 0;
  /// The frame's end: by Hand, the patch exported into FrameBatch::patches[h].patch with its header
  /// set, or null where the batch asked for none. Called once a frame, after the scene has stepped,
  /// before the blood.
  virtual void publish(const std::array<const TissuePatch*, kHandCount>& patches) = 0;
};

/// One visualizer frame: io.drain(), sim.apply(samples), each hand's patch (cleared, exported
/// around its centre, its header set; the blood prepared meanwhile), io.publish(), sim.step_blood(). Not real-time; it
/// allocates only as the scene does. Returns drain()'s error, if any, with nothing stepped.
[[nodiscard]] Result<FrameResult> run_frame(SceneSim& sim, FrameIo& io);

}  // namespace lancet::sim
