#pragma once
// ShmSegment: one POSIX shared-memory segment with a self-describing header.
//
// Layout: [SegmentHeader | padding to 4096 | payload (payload_size bytes)].
// The creator (lancet-rt) makes it with O_EXCL and mode 0600, sizes it, prefaults every page,
// locks it in RAM when permitted, writes the header, constructs the payload, then marks it ready.
// A peer opens it only when the magic, header version, layout hash and sizes all match; a
// mismatched peer is refused with a message naming both hashes. The creator unlinks it on clean
// exit. A segment whose creator died (pid gone or reused) is detected as stale: create() replaces
// it, open() reports it.
//
// Not real-time safe (system calls); used at configure time only.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "lancet/shared_model/result.hpp"

namespace lancet {

inline constexpr std::uint64_t kSegmentMagic = 0x5445434e414c0001ull;  // "\1\0LANCET" little-endian
inline constexpr std::uint32_t kSegmentHeaderVersion = 1;
inline constexpr std::size_t kSegmentPayloadOffset = 4096;

enum class SegmentState : std::uint32_t { kInitialising = 0, kReady = 1, kClosed = 2 };

struct SegmentHeader {
  std::uint64_t magic;                 ///< kSegmentMagic
  std::uint32_t header_version;        ///< kSegmentHeaderVersion
  std::int32_t creator_pid;            ///< pid of the creating process
  std::uint64_t creator_start_ticks;   ///< its start time (/proc/<pid>/stat field 22), guards pid reuse
  std::uint64_t layout_hash;           ///< hash of the payload layout (shared_state.hpp)
  std::uint64_t total_size;            ///< bytes of the whole segment
  std::uint64_t payload_offset;        ///< kSegmentPayloadOffset
  std::uint64_t payload_size;          ///< bytes of payload
  std::atomic<std::uint32_t> state;    ///< SegmentState
  char creator_name[36];               ///< process name of the creator, NUL-terminated
};
static_assert(sizeof(SegmentHeader) <= kSegmentPayloadOffset);

/// True when process pid is alive and, if start_ticks is non-zero, is the same process that had
/// that start time (so a reused pid does not count as alive).
bool process_alive(std::int32_t pid, std::uint64_t start_ticks);
/// Start time of a process in clock ticks since boot (/proc/<pid>/stat field 22); 0 if unknown.
std::uint64_t process_start_ticks(std::int32_t pid);

class ShmSegment {
 public:
  struct CreateOptions {
    bool lock_memory = true;     ///< mlock the segment when permitted (noted when refused)
    bool replace_stale = true;   ///< unlink a segment whose creator died and create anew
    std::string creator_name = "lancet";
    /// How long an existing object without a valid header may take to get one before it is judged
    /// garbage (ms): another creator may have just made it with O_EXCL and not yet stamped it.
    std::int64_t header_grace_ms = 200;
  };

  /// Creates segment `name` (must start with '/'). Fails with kInUse when a live process owns a
  /// segment of that name. notes() says what was degraded (mlock refused, stale segment replaced).
  static Result<ShmSegment> create(const std::string& name, std::size_t payload_size,
                                   std::uint64_t layout_hash, const CreateOptions& options);
  /// Same, with default options.
  static Result<ShmSegment> create(const std::string& name, std::size_t payload_size,
                                   std::uint64_t layout_hash) {
    return create(name, payload_size, layout_hash, CreateOptions{});
  }

  /// Opens an existing, ready segment and checks magic, header version, layout hash and sizes.
  /// Errors: kNotFound (no segment), kNotReady (still initialising), kMismatch (names both
  /// hashes or sizes), kStale (its creator is gone).
  static Result<ShmSegment> open(const std::string& name, std::size_t payload_size,
                                 std::uint64_t layout_hash);

  ShmSegment(ShmSegment&& other) noexcept;
  ShmSegment& operator=(ShmSegment&& other) noexcept;
  ShmSegment(const ShmSegment&) = delete;
  ShmSegment& operator=(const ShmSegment&) = delete;
  /// Unmaps; the creator also marks the header closed and unlinks the name.
  ~ShmSegment();

  /// Creator: publishes the header as ready once the payload is constructed.
  void mark_ready() noexcept;

  [[nodiscard]] void* payload() const noexcept { return base_ + kSegmentPayloadOffset; }
  [[nodiscard]] const SegmentHeader& header() const noexcept {
    return *reinterpret_cast<const SegmentHeader*>(base_);
  }
  [[nodiscard]] const std::string& name() const noexcept { return name_; }
  [[nodiscard]] bool is_creator() const noexcept { return creator_; }
  [[nodiscard]] bool locked() const noexcept { return locked_; }
  /// Degraded steps and recoveries during create/open, one line each, for the log.
  [[nodiscard]] const std::vector<std::string>& notes() const noexcept { return notes_; }
  /// True while the creating process is still running (for an opener: is the peer alive?). Uses
  /// the creator's pid and start time as they were when the segment was made or opened, so a peer
  /// that later scribbles over the header cannot make another process look like the creator.
  [[nodiscard]] bool creator_alive() const;
  /// The creator's pid as it was when the segment was made or opened (not re-read from the header).
  [[nodiscard]] std::int32_t creator_pid() const noexcept { return creator_pid_; }
  /// Creator: marks the header closed and removes the name now (only if it still names this
  /// segment), keeping the mapping: for an exit that cannot wait for every user of the mapping.
  void unlink_name() noexcept;
  /// True when the name now refers to a different segment than the one mapped (the creator left
  /// and another started): the opener should reopen.
  [[nodiscard]] bool replaced() const;

 private:
  ShmSegment() = default;
  void release() noexcept;

  std::string name_;
  unsigned char* base_ = nullptr;
  std::size_t size_ = 0;
  bool creator_ = false;
  bool locked_ = false;
  std::uint64_t inode_ = 0;
  std::int32_t creator_pid_ = 0;
  std::uint64_t creator_start_ticks_ = 0;
  std::vector<std::string> notes_;
};

}  // namespace lancet
