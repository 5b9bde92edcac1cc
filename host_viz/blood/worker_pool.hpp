#pragma once
// WorkerPool: a fixed team of threads that runs one job at a time on all of them, for the blood
// automaton's passes over its tiles (and whatever else on the viz thread splits the same way).
//
// Made once (the threads start in the constructor); between jobs the workers spin briefly, then
// park on a futex (std::atomic::wait), so a job that follows soon after the last one starts
// without a system call and an idle pool costs nothing. run() and sync() never allocate.
//
// Thread contract: run() is called from one thread at a time (the owner's); the job runs on the
// caller as participant 0 and on every worker as 1 .. threads() − 1, and run() returns once all
// have returned. Inside a job, sync() is a barrier among the participants: every one of them must
// call it the same number of times. A job must not throw.

#include <atomic>
#include <cstdint>
#include <thread>
#include <vector>

namespace lancet::blood {

/// Waits until `a` no longer holds `old`: a short spin (what is awaited usually comes within
/// microseconds), then a futex wait (std::atomic::wait). The pool's waits, and its neighbours'.
void await_change(const std::atomic<std::uint32_t>& a, std::uint32_t old) noexcept;

class WorkerPool {
 public:
  /// threads ≥ 1 participants: the caller and threads − 1 workers (started here; allocates).
  explicit WorkerPool(int threads);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  [[nodiscard]] int threads() const noexcept { return threads_; }

  /// Runs job(w) for every participant w in [0, threads()) at once (w = 0 on the calling thread)
  /// and returns when all have returned. No allocation.
  template <class Job>
  void run(Job& job) {
    run_erased(&job, [](void* j, int w) { (*static_cast<Job*>(j))(w); });
  }

  /// Within a job: returns once every participant has reached it. No allocation.
  void sync() noexcept;

 private:
  using Erased = void (*)(void*, int);
  void run_erased(void* job, Erased call);
  void work(int w);

  int threads_ = 1;
  void* job_ = nullptr;
  Erased call_ = nullptr;
  std::atomic<std::uint32_t> generation_{0};  // bumped once per job (and once to stop)
  std::atomic<std::uint32_t> pending_{0};     // workers still in the current job
  std::atomic<std::uint32_t> arrived_{0};     // participants at the current barrier
  std::atomic<std::uint32_t> barrier_{0};     // barriers passed
  bool stop_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace lancet::blood
