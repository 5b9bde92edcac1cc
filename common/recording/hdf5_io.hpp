#pragma once
// A recorded session (recording/recording.hpp) as one HDF5 file, through Debian's libhdf5, readable
// by h5py, MATLAB (h5read) and HDFView. Layout (docs/RECORDING.md):
//
//   /                 attributes: format_version, lancet_version, layout_hash, protocol, created,
//                     scenario_name, scenario_file, period_ns, servo_hash_every, scene_hash_every,
//                     and, once finished, samples, frames, samples_lost, gaps, complete = 1
//   /meta/scenario    the scenario file's text (string)
//   /meta/arm_config  the arm's configuration text (string; empty: the built-in stylus)
//   /servo/samples    one compound row per servo tick (the ToolSample's fields by name; array
//                     fields such as q[8] and tool_position[3] as HDF5 arrays); attribute "units"
//   /viz/frames       one compound row per visualizer frame (FrameRecord); attribute "units"
//   /viz/events       one compound row per tissue event (SceneEvent: blood sources, a vessel
//                     stopped, a structure reached, bone drilled); attribute "units"
//
// The rows are chunked (1024 samples, 256 frames) and deflated; the Recorder appends them from its
// own thread, so whoever records (lancet-viz's frame loop) only copies rows into a queue.

#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "lancet/shared_model/result.hpp"
#include "recording/recording.hpp"

namespace lancet::record {

/// Writes one recording, appending as it goes. Not real-time: add_*() lock a mutex and copy;
/// the HDF5 work is done on the recorder's thread.
class Recorder {
 public:
  /// Creates `path` (replacing it) with the provenance of `meta` (its samples and frames are not
  /// written). Errors name the path and what HDF5 said.
  [[nodiscard]] static Result<std::unique_ptr<Recorder>> create(const std::string& path, const Recording& meta);
  ~Recorder();
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  /// Queues ticks (in seq order; a jump in seq is counted as a gap, the missing ticks as lost).
  void add_samples(std::span<const ToolSample> samples);
  /// Queues one frame.
  void add_frame(const FrameRecord& frame);
  /// Queues a tissue event.
  void add_event(const SceneEvent& event);
  /// Writes what is queued, the final counts and complete = 1, and closes the file. Idempotent;
  /// the destructor calls it.
  Result<void> finish();

  [[nodiscard]] const std::string& path() const noexcept { return path_; }
  [[nodiscard]] std::uint64_t samples() const noexcept;  ///< queued so far
  [[nodiscard]] std::uint64_t frames() const noexcept;
  [[nodiscard]] std::uint64_t samples_lost() const noexcept;
  [[nodiscard]] std::uint64_t gaps() const noexcept;
  /// Samples written to the file and flushed (H5Fflush) so far: what a reader of the file, or
  /// one after a crash, would find. Lags samples() by up to a quarter second.
  [[nodiscard]] std::uint64_t samples_flushed() const noexcept;

 private:
  struct File;
  Recorder(std::string path, std::unique_ptr<File> file);
  void run();
  Result<void> flush_pending(std::vector<ToolSample>& samples, std::vector<FrameRecord>& frames, std::vector<SceneEvent>& events);

  std::string path_;
  std::unique_ptr<File> file_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<ToolSample> samples_;  // queued, not yet written
  std::vector<FrameRecord> frames_;
  std::vector<SceneEvent> events_;
  std::uint64_t n_events_ = 0;
  std::uint64_t n_samples_ = 0, n_frames_ = 0, lost_ = 0, gaps_ = 0, n_flushed_ = 0;
  std::uint64_t last_seq_[kHandCount] = {};  ///< by hand: its newest sample's seq (0: none yet)
  bool stop_ = false, finished_ = false;
  std::string error_;  // the writer thread's first error
  std::thread thread_;
};

/// The whole recording at once (tests, tools).
[[nodiscard]] Result<void> write_recording(const std::string& path, const Recording& r);

/// Reads a whole recording. Errors (ErrorCode::kInvalid, kNotFound) name the file and what is
/// wrong: not HDF5 or truncated, not finished (no complete = 1), a missing dataset or attribute,
/// counts that disagree with the rows, another format_version.
[[nodiscard]] Result<Recording> read_recording(const std::string& path);

}  // namespace lancet::record
