#pragma once
// BloodBehind: the blood on a thread of its own, for a replay, which needs a frame's blood only at
// the next frame (or at a hash). A frame posts its blood time once the scene has applied its
// samples; the thread then prepares the blood from the scene (Bleeding::prepare) and steps it
// (Bleeding::step on one automaton thread: the blood does not depend on the thread count) while
// the caller exports the frame's patches, publishes them and steps the next frame's servo ticks.
// So the blood's chain (prepare, step, prepare, ...) runs beside the frame's (ticks, scene,
// patches) instead of after it.
//
// The caller's side of the contract: the scene does not change between post() and
// wait_prepared() (the preparation reads it; other readers may run meanwhile), and the blood is
// not read, nor posted to again, before wait_stepped() or wait_prepared() respectively. Frames
// queue at most one deep: post() waits until the previous frame is prepared. Posting, waiting and
// the thread's loop do not allocate; the blood allocates as it does on any thread.

#include <array>
#include <atomic>
#include <cstdint>
#include <thread>

#include "blood/bleeding.hpp"
#include "tissue/tissue_scene.hpp"

namespace lancet::sim {

class BloodBehind {
 public:
  /// Starts the thread (allocates). `bleeding` and `scene` must outlive this.
  BloodBehind(blood::Bleeding& bleeding, const tissue::TissueScene& scene);
  /// Waits for the posted frames' blood, then stops the thread.
  ~BloodBehind();
  BloodBehind(const BloodBehind&) = delete;
  BloodBehind& operator=(const BloodBehind&) = delete;

  /// The frame's blood, blood_dt s of it, from the scene as it is now: prepared, then stepped.
  void post(double blood_dt) noexcept;
  /// Returns once the posted frames' blood is prepared (the scene may change after it). Returns
  /// the seconds it waited (0 when it did not).
  double wait_prepared() noexcept;
  /// Returns once the posted frames' blood is stepped too (the blood may be read after it).
  double wait_stepped() noexcept;

 private:
  void work();
  double wait_for(const std::atomic<std::uint32_t>& reached) noexcept;

  blood::Bleeding& bleeding_;
  const tissue::TissueScene& scene_;
  std::array<double, 2> dt_{};              // by frame number mod 2 (one prepared, one posted)
  std::atomic<std::uint32_t> posted_{0};    // frames posted (and one more to stop)
  std::atomic<std::uint32_t> prepared_{0};  // frames prepared
  std::atomic<std::uint32_t> stepped_{0};   // frames stepped
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace lancet::sim
