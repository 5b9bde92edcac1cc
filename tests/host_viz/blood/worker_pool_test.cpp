// WorkerPool: every participant runs every job once, a barrier inside a job holds them all until
// the last arrives, the pool is reused across thousands of jobs (parking between them), run()
// and sync() never allocate, and a pool of one runs the job on the caller.

#include "blood/worker_pool.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "malloc_guard.hpp"

namespace lancet::blood {
namespace {

TEST(WorkerPool, EveryParticipantRunsEveryJobAndTheBarrierHoldsThemAll) {
  for (int n : {2, 3, 4}) {
    SCOPED_TRACE(std::to_string(n) + " threads");
    WorkerPool pool(n);
    ASSERT_EQ(pool.threads(), n);
    std::vector<int> runs(static_cast<std::size_t>(n), 0);
    std::atomic<int> before{0}, wrong{0};
    for (int job = 0; job < 2000; ++job) {
      before = 0;
      auto f = [&](int w) {
        ++runs[static_cast<std::size_t>(w)];
        before.fetch_add(1);
        pool.sync();
        if (before.load() != n) wrong.fetch_add(1);  // someone passed the barrier early
        pool.sync();
        pool.sync();
      };
      pool.run(f);
    }
    EXPECT_EQ(wrong.load(), 0);
    for (int w = 0; w < n; ++w) EXPECT_EQ(runs[static_cast<std::size_t>(w)], 2000) << "participant " << w;
  }
}

TEST(WorkerPool, WorkersParkedBetweenJobsWakeForTheNext) {
  WorkerPool pool(2);
  std::atomic<int> done{0};
  auto f = [&](int) { done.fetch_add(1); };
  for (int job = 0; job < 3; ++job) {
    pool.run(f);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));  // long past the spin: parked
  }
  EXPECT_EQ(done.load(), 6);
}

TEST(WorkerPool, RunAndSyncDoNotAllocate) {
  WorkerPool pool(2);
  std::vector<double> out(2, 0.0);
  auto f = [&](int w) {
    out[static_cast<std::size_t>(w)] += 1.0;
    pool.sync();
  };
  pool.run(f);  // the first job (nothing in it allocates either)
  test::MallocGuard guard;
  for (int job = 0; job < 100; ++job) pool.run(f);
  EXPECT_EQ(guard.count(), 0u);
  EXPECT_EQ(out[0], 101.0);
  EXPECT_EQ(out[1], 101.0);
}

TEST(WorkerPool, APoolOfOneRunsTheJobOnTheCaller) {
  WorkerPool pool(0);
  EXPECT_EQ(pool.threads(), 1);
  const auto me = std::this_thread::get_id();
  bool here = false;
  auto f = [&](int w) {
    here = w == 0 && std::this_thread::get_id() == me;
    pool.sync();
  };
  pool.run(f);
  EXPECT_TRUE(here);
}

}  // namespace
}  // namespace lancet::blood
