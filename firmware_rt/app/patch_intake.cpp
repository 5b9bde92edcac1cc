#include "app/patch_intake.hpp"

#include <sched.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstddef>
#include <cstring>
#include <string>

#include "lancet/shared_model/units.hpp"
#include "lancet/shared_model/validate.hpp"
#include "rt/rt_setup.hpp"

namespace lancet::app {

namespace {
void sleep_until_ns(std::int64_t t_ns) noexcept {
  timespec ts{static_cast<time_t>(t_ns / 1'000'000'000), static_cast<long>(t_ns % 1'000'000'000)};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}
}  // namespace

PatchIntake::PatchIntake(SharedState& shared, std::int64_t period_ns, Hand hand)
    : buffer_(shared.patch[hand_index(hand)]), hand_(hand), period_ns_(period_ns), buffers_(std::make_unique<std::array<ReadyPatch, 3>>()) {}

PatchIntake::~PatchIntake() { stop_thread(); }

bool PatchIntake::poll(std::int64_t now_ns) noexcept {
  ReadyPatch& b = (*buffers_)[back_];
  // Only the triangles in use are copied (a full patch is 720 KB; a typical one a tenth).
  const auto in_use = [](const TissuePatch& p) { return tissue_patch_bytes(p); };
  std::uint64_t version = seen_;
  const ReadStatus r = buffer_.try_read_prefix_if_newer(b.patch, version, offsetof(TissuePatch, triangles), in_use);
  if (r == ReadStatus::kBusy) {
    counters_.busy.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  if (r != ReadStatus::kOk) return false;
  seen_ = version;  // read whole: taken or rejected, it is not read again
  const char* why = wire::check(b.patch, now_ns);
  if (why == nullptr && b.patch.hand != hand_) why = "patch.hand: not the hand whose buffer it came in";
  if (why != nullptr) {
    counters_.last_reject.store(why, std::memory_order_relaxed);
    counters_.rejected.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  haptics::build_patch_bvh(b.tree, b.patch, version);
  b.version = version;
  b.taken_ns = monotonic_ns();
  const std::int64_t work = b.taken_ns - now_ns;
  if (work > counters_.max_work_ns.load(std::memory_order_relaxed)) counters_.max_work_ns.store(work, std::memory_order_relaxed);
  // Hand it over: the filled buffer becomes the middle (fresh); the old middle is ours to fill next.
  back_ = middle_.exchange(back_ | kFresh, std::memory_order_acq_rel) & 3u;
  counters_.taken.fetch_add(1, std::memory_order_relaxed);
  return true;
}

const ReadyPatch* PatchIntake::take() noexcept {
  if ((middle_.load(std::memory_order_relaxed) & kFresh) != 0) {
    // The acquire side of the exchange makes the intake's writes to that buffer visible.
    front_ = middle_.exchange(front_, std::memory_order_acq_rel) & 3u;
    has_front_ = true;
  }
  return has_front_ ? &(*buffers_)[front_] : nullptr;
}

void* PatchIntake::entry(void* self) noexcept {
  static_cast<PatchIntake*>(self)->run();
  return nullptr;
}

void PatchIntake::run() noexcept {
  // A wait for the doorbell ends at a publish or after this long (so a stop is seen).
  constexpr std::int64_t kWaitNs = 20'000'000;
  std::int64_t next_allowed_ns = 0;
  while (!stop_.load(std::memory_order_acquire)) {
    const std::int64_t before = monotonic_ns();
    const bool newer = buffer_.wait_newer(seen_, kWaitNs);
    counters_.wakeups.fetch_add(1, std::memory_order_relaxed);
    if (stop_.load(std::memory_order_acquire)) break;
    std::int64_t now = monotonic_ns();
    if (!newer) {
      // A doorbell rung with nothing new (anything that can write the segment can ring it): pause
      // a period, so that a flood of rings costs this thread little and the servo nothing.
      if (now - before < kWaitNs / 2) sleep_until_ns(now + period_ns_);
      continue;
    }
    // At most one patch a servo period, whatever the writer does.
    if (now < next_allowed_ns) {
      sleep_until_ns(next_allowed_ns);
      now = monotonic_ns();
    }
    if (poll(now)) {
      next_allowed_ns = now + period_ns_;
    } else {
      sleep_until_ns(now + period_ns_);  // unreadable or rejected: not again at once
    }
  }
}

std::string PatchIntake::start_thread(bool fifo, int priority, int avoid_cpu) {
  if (started_) return "patch intake: already running";
  std::string said;
  for (int attempt = 0; attempt < 2 && !started_; ++attempt) {
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
    sched_param sp{};
    if (fifo) sp.sched_priority = priority;
    pthread_attr_setschedpolicy(&attr, fifo ? SCHED_FIFO : SCHED_OTHER);
    pthread_attr_setschedparam(&attr, &sp);
    cpu_set_t set;
    const bool pinned = rt::allowed_cpus_without(avoid_cpu, set);
    if (pinned) pthread_attr_setaffinity_np(&attr, sizeof set, &set);
    const int err = pthread_create(&thread_, &attr, &PatchIntake::entry, this);
    pthread_attr_destroy(&attr);
    if (err == 0) {
      started_ = true;
      said = std::string("patch intake on its own thread (") + (fifo ? "SCHED_FIFO priority " + std::to_string(priority) : "SCHED_OTHER") +
             (pinned ? ", off CPU " + std::to_string(avoid_cpu) : "") + ")";
    } else if (err == EPERM && fifo) {
      fifo = false;  // not permitted: the same thread without real-time priority
    } else {
      return std::string("patch intake: no thread (") + std::strerror(err) + "): the servo takes patches in its tick";
    }
  }
  return said;
}

void PatchIntake::stop_thread() {
  if (!started_) return;
  stop_.store(true, std::memory_order_release);
  buffer_.wake_waiters();
  pthread_join(thread_, nullptr);
  started_ = false;
}

}  // namespace lancet::app
