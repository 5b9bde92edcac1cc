#include "sim/blood_behind.hpp"

#include <chrono>

#include "blood/worker_pool.hpp"

namespace lancet::sim {

BloodBehind::BloodBehind(blood::Bleeding& bleeding, const tissue::TissueScene& scene)
    : bleeding_(bleeding), scene_(scene), thread_([this] { work(); }) {}

BloodBehind::~BloodBehind() {
  (void)wait_stepped();
  stop_ = true;
  posted_.fetch_add(1, std::memory_order_release);
  posted_.notify_one();
  thread_.join();
}

void BloodBehind::work() {
  for (std::uint32_t done = 0;;) {
    blood::await_change(posted_, done);
    if (stop_) return;
    const std::uint32_t frame = done + 1;  // frames run one at a time, in order
    bleeding_.prepare(scene_, dt_[frame & 1]);
    prepared_.store(frame, std::memory_order_release);
    prepared_.notify_one();
    bleeding_.step(1);
    stepped_.store(frame, std::memory_order_release);
    stepped_.notify_one();
    done = frame;
  }
}

void BloodBehind::post(double blood_dt) noexcept {
  (void)wait_prepared();
  const std::uint32_t frame = posted_.load(std::memory_order_relaxed) + 1;
  dt_[frame & 1] = blood_dt;
  posted_.store(frame, std::memory_order_release);
  posted_.notify_one();
}

double BloodBehind::wait_for(const std::atomic<std::uint32_t>& reached) noexcept {
  const std::uint32_t posted = posted_.load(std::memory_order_relaxed);  // only this thread posts
  std::uint32_t now = reached.load(std::memory_order_acquire);
  if (now == posted) return 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (; now != posted; now = reached.load(std::memory_order_acquire)) blood::await_change(reached, now);
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

double BloodBehind::wait_prepared() noexcept { return wait_for(prepared_); }
double BloodBehind::wait_stepped() noexcept { return wait_for(stepped_); }

}  // namespace lancet::sim
