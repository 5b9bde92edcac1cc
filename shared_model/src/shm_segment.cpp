#include "lancet/shared_model/shm_segment.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <new>
#include <sstream>
#include <utility>

namespace lancet {
namespace {

std::string errno_text(int err) { return std::string(std::strerror(err)); }

std::string hex(std::uint64_t v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "0x%016" PRIx64, v);
  return buf;
}

std::size_t round_up_page(std::size_t n) {
  const auto page = static_cast<std::size_t>(sysconf(_SC_PAGESIZE));
  return (n + page - 1) / page * page;
}

// Closes a file descriptor on scope exit.
struct Fd {
  int fd = -1;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

// Reads the header of an existing segment without trusting it: returns false when the object is
// too small or cannot be mapped.
bool peek_header(const std::string& name, SegmentHeader& out, std::uint64_t& size_out) {
  Fd f{shm_open(name.c_str(), O_RDONLY, 0)};
  if (f.fd < 0) return false;
  struct stat st {};
  if (fstat(f.fd, &st) != 0 || static_cast<std::size_t>(st.st_size) < sizeof(SegmentHeader)) return false;
  void* p = mmap(nullptr, sizeof(SegmentHeader), PROT_READ, MAP_SHARED, f.fd, 0);
  if (p == MAP_FAILED) return false;
  std::memcpy(static_cast<void*>(&out), p, sizeof(SegmentHeader));
  munmap(p, sizeof(SegmentHeader));
  size_out = static_cast<std::uint64_t>(st.st_size);
  return true;
}

}  // namespace

namespace {

// State letter (field 3) and start time (field 22) of /proc/<pid>/stat; false when unreadable.
bool read_proc_stat(std::int32_t pid, char& state, std::uint64_t& start_ticks) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(in, line)) return false;
  // The command name (field 2) is in parentheses and may contain spaces: parse after the last ')'.
  const auto close = line.rfind(')');
  if (close == std::string::npos) return false;
  std::istringstream rest(line.substr(close + 1));
  std::string field;
  for (int i = 3; i <= 22; ++i) {
    if (!(rest >> field)) return false;
    if (i == 3) state = field.empty() ? '?' : field[0];
  }
  start_ticks = std::strtoull(field.c_str(), nullptr, 10);
  return true;
}

}  // namespace

std::uint64_t process_start_ticks(std::int32_t pid) {
  char state = '?';
  std::uint64_t ticks = 0;
  return read_proc_stat(pid, state, ticks) ? ticks : 0;
}

bool process_alive(std::int32_t pid, std::uint64_t start_ticks) {
  if (pid <= 0) return false;
  if (::kill(pid, 0) != 0 && errno == ESRCH) return false;
  char state = '?';
  std::uint64_t now = 0;
  if (!read_proc_stat(pid, state, now)) return true;  // no /proc: trust kill()
  if (state == 'Z' || state == 'X') return false;     // exited, not yet reaped by its parent
  return start_ticks == 0 || now == start_ticks;      // a reused pid is another process
}

Result<ShmSegment> ShmSegment::create(const std::string& name, std::size_t payload_size,
                                      std::uint64_t layout_hash, const CreateOptions& options) {
  if (name.size() < 2 || name[0] != '/' || name.find('/', 1) != std::string::npos) {
    return Error{ErrorCode::kInvalid, "shared memory name '" + name +
                                          "' is invalid: expected '/' followed by a name without '/'"};
  }
  ShmSegment seg;
  seg.name_ = name;
  Fd f;
  for (int attempt = 0; attempt < 2; ++attempt) {
    f.fd = shm_open(name.c_str(), O_CREAT | O_EXCL | O_RDWR, 0600);
    if (f.fd >= 0) break;
    if (errno != EEXIST) {
      return Error{ErrorCode::kSystem, "shm_open(" + name + ", O_CREAT|O_EXCL) failed: " + errno_text(errno)};
    }
    SegmentHeader old{};
    std::uint64_t old_size = 0;
    // An object without a valid header may belong to a creator that has just made it with O_EXCL
    // and not yet sized and stamped it: give it header_grace_ms before judging it garbage.
    bool readable = peek_header(name, old, old_size);
    const auto grace_end = std::chrono::steady_clock::now() + std::chrono::milliseconds(options.header_grace_ms);
    while (!(readable && old.magic == kSegmentMagic) && std::chrono::steady_clock::now() < grace_end) {
      ::usleep(10'000);
      readable = peek_header(name, old, old_size);
    }
    if (readable && old.magic == kSegmentMagic && process_alive(old.creator_pid, old.creator_start_ticks)) {
      return Error{ErrorCode::kInUse, "shared memory segment " + name + " is in use by " +
                                          std::string(old.creator_name) + " (pid " +
                                          std::to_string(old.creator_pid) +
                                          "); stop it first or pick another name with --shm"};
    }
    if (!options.replace_stale) {
      return Error{ErrorCode::kStale, "shared memory segment " + name +
                                          " exists but its creator is gone; remove /dev/shm" + name};
    }
    if (shm_unlink(name.c_str()) != 0) {
      if (errno == ENOENT) continue;  // its owner removed it meanwhile: just try again
      return Error{ErrorCode::kSystem, "cannot remove stale segment " + name + ": " + errno_text(errno)};
    }
    seg.notes_.push_back(readable && old.magic == kSegmentMagic
                             ? "removed stale segment " + name + " left by pid " + std::to_string(old.creator_pid) +
                                   " (no longer running)"
                             : "removed unrecognised object " + name + " (not a Lancet segment)");
  }
  if (f.fd < 0) return Error{ErrorCode::kInUse, "shared memory segment " + name + " keeps reappearing; another creator races us"};

  const std::size_t total = round_up_page(kSegmentPayloadOffset + payload_size);
  if (ftruncate(f.fd, static_cast<off_t>(total)) != 0) {
    const int err = errno;
    shm_unlink(name.c_str());
    return Error{ErrorCode::kSystem, "ftruncate(" + name + ", " + std::to_string(total) + ") failed: " + errno_text(err)};
  }
  void* p = mmap(nullptr, total, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_POPULATE, f.fd, 0);
  if (p == MAP_FAILED) {
    const int err = errno;
    shm_unlink(name.c_str());
    return Error{ErrorCode::kSystem, "mmap of " + name + " failed: " + errno_text(err)};
  }
  seg.base_ = static_cast<unsigned char*>(p);
  seg.size_ = total;
  seg.creator_ = true;
  struct stat st {};
  if (fstat(f.fd, &st) == 0) seg.inode_ = st.st_ino;
  // Prefault: touch every page for writing so the first real-time access does not fault.
  std::memset(seg.base_, 0, total);
  if (options.lock_memory) {
    if (mlock(seg.base_, total) == 0) {
      seg.locked_ = true;
    } else {
      seg.notes_.push_back("mlock of " + std::to_string(total) + " bytes refused (" + errno_text(errno) +
                           "): the segment may be paged out; run as root or raise RLIMIT_MEMLOCK (ulimit -l)");
    }
  }
  auto* h = new (seg.base_) SegmentHeader{};
  h->magic = kSegmentMagic;
  h->header_version = kSegmentHeaderVersion;
  h->creator_pid = static_cast<std::int32_t>(getpid());
  h->creator_start_ticks = process_start_ticks(h->creator_pid);
  h->layout_hash = layout_hash;
  h->total_size = total;
  h->payload_offset = kSegmentPayloadOffset;
  h->payload_size = payload_size;
  h->state.store(static_cast<std::uint32_t>(SegmentState::kInitialising), std::memory_order_relaxed);
  std::snprintf(h->creator_name, sizeof h->creator_name, "%s", options.creator_name.c_str());
  seg.creator_pid_ = h->creator_pid;
  seg.creator_start_ticks_ = h->creator_start_ticks;
  return seg;
}

Result<ShmSegment> ShmSegment::open(const std::string& name, std::size_t payload_size, std::uint64_t layout_hash) {
  Fd f{shm_open(name.c_str(), O_RDWR, 0)};
  if (f.fd < 0) {
    if (errno == ENOENT) {
      return Error{ErrorCode::kNotFound, "shared memory segment " + name + " does not exist: is lancet-rt running?"};
    }
    return Error{ErrorCode::kSystem, "shm_open(" + name + ") failed: " + errno_text(errno)};
  }
  struct stat st {};
  if (fstat(f.fd, &st) != 0) return Error{ErrorCode::kSystem, "fstat(" + name + ") failed: " + errno_text(errno)};
  const auto actual = static_cast<std::size_t>(st.st_size);
  if (actual < kSegmentPayloadOffset) {
    return Error{ErrorCode::kNotReady, "segment " + name + " is " + std::to_string(actual) +
                                           " bytes, smaller than its header: still being created?"};
  }
  void* p = mmap(nullptr, actual, PROT_READ | PROT_WRITE, MAP_SHARED, f.fd, 0);
  if (p == MAP_FAILED) return Error{ErrorCode::kSystem, "mmap of " + name + " failed: " + errno_text(errno)};
  ShmSegment seg;
  seg.name_ = name;
  seg.base_ = static_cast<unsigned char*>(p);
  seg.size_ = actual;
  seg.inode_ = st.st_ino;
  const SegmentHeader& h = seg.header();
  // The header is the peer's: never trust its string to be terminated.
  const std::string creator_name(h.creator_name, strnlen(h.creator_name, sizeof h.creator_name));
  if (h.magic != kSegmentMagic) {
    return Error{ErrorCode::kMismatch, "segment " + name + " is not a Lancet segment: magic " + hex(h.magic) +
                                           ", expected " + hex(kSegmentMagic)};
  }
  if (h.header_version != kSegmentHeaderVersion) {
    return Error{ErrorCode::kMismatch, "segment " + name + " has header version " + std::to_string(h.header_version) +
                                           ", expected " + std::to_string(kSegmentHeaderVersion)};
  }
  const auto state = static_cast<SegmentState>(h.state.load(std::memory_order_acquire));
  if (state == SegmentState::kInitialising) {
    if (!process_alive(h.creator_pid, h.creator_start_ticks)) {
      return Error{ErrorCode::kStale, "segment " + name + " was left half-built by pid " +
                                          std::to_string(h.creator_pid) + ", which is gone"};
    }
    return Error{ErrorCode::kNotReady, "segment " + name + " is still being initialised by pid " +
                                           std::to_string(h.creator_pid)};
  }
  if (h.layout_hash != layout_hash) {
    return Error{ErrorCode::kMismatch, "segment " + name + " layout hash mismatch: the segment (made by " +
                                           creator_name + ", pid " + std::to_string(h.creator_pid) +
                                           ") has " + hex(h.layout_hash) + ", this process expects " +
                                           hex(layout_hash) + "; rebuild both processes from the same source"};
  }
  if (h.payload_size != payload_size || h.total_size != actual || h.payload_offset != kSegmentPayloadOffset) {
    return Error{ErrorCode::kMismatch, "segment " + name + " size mismatch: payload " + std::to_string(h.payload_size) +
                                           " bytes (expected " + std::to_string(payload_size) + "), total " +
                                           std::to_string(h.total_size) + " (file is " + std::to_string(actual) + ")"};
  }
  if (state != SegmentState::kReady || !process_alive(h.creator_pid, h.creator_start_ticks)) {
    return Error{ErrorCode::kStale, "segment " + name + " is stale: its creator " + creator_name +
                                        " (pid " + std::to_string(h.creator_pid) + ") is no longer running"};
  }
  // Remember who made it: the header may be overwritten later, the creator's identity may not.
  seg.creator_pid_ = h.creator_pid;
  seg.creator_start_ticks_ = h.creator_start_ticks;
  return seg;
}

ShmSegment::ShmSegment(ShmSegment&& o) noexcept
    : name_(std::move(o.name_)),
      base_(std::exchange(o.base_, nullptr)),
      size_(std::exchange(o.size_, 0)),
      creator_(std::exchange(o.creator_, false)),
      locked_(std::exchange(o.locked_, false)),
      inode_(o.inode_),
      creator_pid_(o.creator_pid_),
      creator_start_ticks_(o.creator_start_ticks_),
      notes_(std::move(o.notes_)) {}

ShmSegment& ShmSegment::operator=(ShmSegment&& o) noexcept {
  if (this != &o) {
    release();
    name_ = std::move(o.name_);
    base_ = std::exchange(o.base_, nullptr);
    size_ = std::exchange(o.size_, 0);
    creator_ = std::exchange(o.creator_, false);
    locked_ = std::exchange(o.locked_, false);
    inode_ = o.inode_;
    creator_pid_ = o.creator_pid_;
    creator_start_ticks_ = o.creator_start_ticks_;
    notes_ = std::move(o.notes_);
  }
  return *this;
}

ShmSegment::~ShmSegment() { release(); }

void ShmSegment::unlink_name() noexcept {
  if (base_ == nullptr || !creator_) return;
  auto* h = reinterpret_cast<SegmentHeader*>(base_);
  h->state.store(static_cast<std::uint32_t>(SegmentState::kClosed), std::memory_order_release);
  // Unlink only our own segment: a successor may already have replaced the name.
  struct stat st {};
  Fd f{shm_open(name_.c_str(), O_RDONLY, 0)};
  if (f.fd >= 0 && fstat(f.fd, &st) == 0 && st.st_ino == inode_) shm_unlink(name_.c_str());
}

void ShmSegment::release() noexcept {
  if (base_ == nullptr) return;
  unlink_name();
  if (locked_) munlock(base_, size_);
  munmap(base_, size_);
  base_ = nullptr;
}

void ShmSegment::mark_ready() noexcept {
  reinterpret_cast<SegmentHeader*>(base_)->state.store(static_cast<std::uint32_t>(SegmentState::kReady),
                                                       std::memory_order_release);
}

bool ShmSegment::creator_alive() const {
  const SegmentHeader& h = header();
  if (h.state.load(std::memory_order_acquire) == static_cast<std::uint32_t>(SegmentState::kClosed)) return false;
  return process_alive(creator_pid_, creator_start_ticks_);
}

bool ShmSegment::replaced() const {
  Fd f{shm_open(name_.c_str(), O_RDONLY, 0)};
  if (f.fd < 0) return true;
  struct stat st {};
  return fstat(f.fd, &st) != 0 || st.st_ino != inode_;
}

}  // namespace lancet
