#pragma once
// Waiting for events in tests, not for time.
//
// A test asserts behaviour, never the machine's speed: where it needs another thread or process
// to have done something, it waits for that (a condition, a counter reaching a value) with a
// deadline that only catches hangs. The deadline is generous on purpose (a loaded 2-core VM, a
// sanitizer, an emulated guest), and reaching it is a failure that says what never happened.
//
//   ASSERT_TRUE(test::eventually([&] { return server.requests() >= 10; })) << "the server never saw 10 requests";
//
// Test-only code: allocation and sleeping are fine here.

#include <chrono>
#include <thread>

namespace lancet::test {

/// How long a test waits for an event before calling it a hang.
inline constexpr std::chrono::seconds kHangTimeout{30};

/// Polls `pred` (every `poll`) until it returns true (then true) or `timeout` has passed (then
/// false, after one last try).
template <class Pred>
[[nodiscard]] bool eventually(Pred&& pred, std::chrono::milliseconds timeout = kHangTimeout,
                              std::chrono::microseconds poll = std::chrono::microseconds(500)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (pred()) return true;
    if (std::chrono::steady_clock::now() >= deadline) return pred();
    std::this_thread::sleep_for(poll);
  }
}

}  // namespace lancet::test
