#pragma once
// PatchIntake: how a TissuePatch gets from the segment to the servo without costing a tick.
//
// A new patch is up to 16 384 triangles (720 KB): copying it out of the segment, checking every
// triangle (the viz is untrusted) and building its search tree take a few hundred microseconds,
// a quarter of a tick. The intake does that work on a helper thread of lancet-rt, off the servo's
// CPU and below its priority, and hands the servo a patch that is copied, checked and has its
// tree, through an in-process triple buffer: the tick's part is one atomic exchange.
//
//   segment (TripleBuffer<TissuePatch>) ──intake thread: copy, wire::check, build_patch_bvh──▶
//   ReadyPatch ×3 (back | middle | front) ──tick: take()──▶ servo_step
//
// The helper sleeps on the segment's doorbell (a futex) until the viz publishes, takes at most one
// patch a servo period whatever the viz does (a peer that publishes flat out costs the helper a
// bounded share of its CPU, never the servo anything), and counts what it took, rejected and
// could not read. Without the thread (Mode::kInTick: unit tests, tools that want a deterministic
// tick), the tick calls poll() itself, as lancet-rt did before.
//
// Thread contract: poll() from one intake thread (or the servo's, in kInTick); take() from the
// servo thread only; the counters from anyone. Everything is allocated in the constructor; poll()
// and take() never allocate, lock or throw. take() is real-time safe, O(1); poll() is O(patch).

#include <pthread.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>

#include "haptics/patch_bvh.hpp"
#include "lancet/shared_model/shared_state.hpp"

namespace lancet::app {

/// A patch ready for the servo: checked, with its tree built for `version`.
struct ReadyPatch {
  std::uint64_t version = 0;      ///< the segment's publish version (0: none)
  std::int64_t taken_ns = 0;      ///< when the intake finished it (CLOCK_MONOTONIC)
  TissuePatch patch{};
  haptics::PatchBvh tree{};
};

/// What the intake has done (any thread may read).
struct IntakeCounters {
  std::atomic<std::uint64_t> taken{0};     ///< patches checked and handed over
  std::atomic<std::uint64_t> rejected{0};  ///< patches that failed wire::check
  std::atomic<std::uint64_t> busy{0};      ///< reads that could not get a whole copy (a misbehaving writer)
  std::atomic<std::uint64_t> wakeups{0};   ///< times the helper woke (doorbell or timeout)
  std::atomic<std::int64_t> max_work_ns{0};  ///< the longest poll() that took a patch
  std::atomic<const char*> last_reject{nullptr};  ///< the check that rejected the last bad patch (static string)
};

class PatchIntake {
 public:
  enum class Mode { kInTick, kThread };

  /// shared must outlive the intake. period_ns: the servo's (the helper takes at most one patch
  /// per period). Allocates the three ReadyPatch buffers (about 3 × 820 KB).
  /// Takes `hand`'s patches (SharedState::patch[hand]).
  PatchIntake(SharedState& shared, std::int64_t period_ns, Hand hand = Hand::kRight);
  ~PatchIntake();  ///< stops the helper, if started
  PatchIntake(const PatchIntake&) = delete;
  PatchIntake& operator=(const PatchIntake&) = delete;

  /// Starts the helper thread: SCHED_FIFO at `priority` when fifo (falls back to SCHED_OTHER when
  /// refused), on every CPU but `avoid_cpu` (-1: any). Returns a line saying what it got.
  std::string start_thread(bool fifo, int priority, int avoid_cpu);
  /// Stops and joins the helper (idempotent).
  void stop_thread();
  [[nodiscard]] bool threaded() const noexcept { return started_; }

  /// Intake side: takes the newest published patch if there is one newer than the last taken,
  /// checks it (now_ns: the reader's clock, for its timestamp), builds its tree and hands it over.
  /// Returns true when a patch was handed over. O(patch); never allocates.
  bool poll(std::int64_t now_ns) noexcept;

  /// Servo side: the newest patch handed over (it stays the servo's until a newer one is taken),
  /// or nullptr before the first. Real-time safe, O(1).
  [[nodiscard]] const ReadyPatch* take() noexcept;

  [[nodiscard]] const IntakeCounters& counters() const noexcept { return counters_; }

 private:
  void run() noexcept;
  static void* entry(void* self) noexcept;

  static constexpr std::uint32_t kFresh = 4;  ///< in middle_: the middle buffer holds a patch not yet taken
  TripleBuffer<TissuePatch>& buffer_;  // SharedState::patch[hand]
  Hand hand_;
  std::int64_t period_ns_;
  std::unique_ptr<std::array<ReadyPatch, 3>> buffers_;
  std::uint32_t back_ = 0;              ///< intake's
  std::atomic<std::uint32_t> middle_{1};  ///< index | kFresh
  std::uint32_t front_ = 2;             ///< servo's
  bool has_front_ = false;              ///< servo's: front_ holds a patch
  std::uint64_t seen_ = 0;              ///< intake's: the segment version last read
  IntakeCounters counters_;
  std::atomic<bool> stop_{false};
  pthread_t thread_{};
  bool started_ = false;
};

}  // namespace lancet::app
