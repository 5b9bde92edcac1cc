#pragma once
// in_two_halves: a loop over [0, count) split into two halves, on two threads when asked, else
// both halves in turn on the caller. For the one-off builds of a large mesh or volume (the BVH,
// the half-edge mesh, the normals, the phantom) where each half writes only its own elements, so
// the result is the same either way. Starts a thread per call (allocates); never on a hot path.

#include <cstddef>
#include <thread>

namespace lancet::volume {

/// Calls work(begin, end, half) for half 0 = [0, count / 2) and half 1 = [count / 2, count):
/// half 1 on a second thread when `two`, else after half 0 on this one.
template <class Work>
void in_two_halves(std::size_t count, bool two, Work&& work) {
  const std::size_t mid = count / 2;
  if (!two) {
    work(std::size_t{0}, mid, 0);
    work(mid, count, 1);
    return;
  }
  std::thread upper([&] { work(mid, count, 1); });
  work(std::size_t{0}, mid, 0);
  upper.join();
}

/// Whether a loop of `count` elements is worth a second thread here: 65 536 or more, and a
/// second core to run it.
inline bool worth_two_threads(std::size_t count) { return count >= (std::size_t{1} << 16) && std::thread::hardware_concurrency() > 1; }

}  // namespace lancet::volume
