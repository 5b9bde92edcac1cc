#pragma once
// SampleStats: what the viz received on the ToolSample ring, checked for loss and order.

#include <cstddef>
#include <cstdint>

#include "lancet/shared_model/messages.hpp"

namespace lancet::viz {

struct SampleStats {
  std::uint64_t received = 0;      ///< samples taken from the ring
  std::uint64_t first_seq = 0;     ///< seq of the first sample (0: none yet)
  std::uint64_t last_seq = 0;      ///< seq of the newest sample
  std::uint64_t lost = 0;          ///< seq numbers skipped between a hand's consecutive samples
  std::uint64_t out_of_order = 0;  ///< samples whose seq did not increase over their hand's last (duplicates, reordering)
  std::uint64_t hand_last_seq[kHandCount] = {};  ///< by Hand: seq of its newest sample (0: none yet)
  std::uint64_t discarded = 0;     ///< backlog dropped when attaching
  std::uint64_t max_batch = 0;     ///< most samples drained in one frame
  // What the segment held that the viz would not take (never happens with a sane lancet-rt).
  std::uint64_t rejected = 0;        ///< samples that failed validation (wire::check), not used
  std::uint64_t ring_resets = 0;     ///< sample ring indices found impossible and reset
  std::uint64_t status_rejected = 0; ///< RtStatus reads that failed validation (the previous one is kept)
  const char* last_reject = nullptr; ///< the check that failed last (static string)

  /// Accounts n samples in ring order.
  void ingest(const ToolSample* samples, std::size_t n) noexcept {
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t s = samples[i].seq;
      const std::size_t h = hand_slot(samples[i].hand);
      std::uint64_t& last = hand_last_seq[h];
      if (last != 0) {
        if (s <= last) {
          ++out_of_order;
          continue;
        }
        lost += s - last - 1;
      }
      if (received == 0) first_seq = s;
      last = s;
      if (s > last_seq) last_seq = s;
      ++received;
    }
    if (n > max_batch) max_batch = n;
  }
  /// Starts counting afresh (a new lancet-rt has a new sequence).
  void restart() noexcept { *this = SampleStats{}; }
};

}  // namespace lancet::viz
