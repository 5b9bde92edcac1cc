// ShmSegment with a creator that dies: a forked child creates a segment and _exit()s without
// cleaning up (as a crashed or killed lancet-rt would), leaving the object in /dev/shm. The
// parent must see it as stale: open() refuses it, create() replaces it and says so in notes().
// Also: an opener watches a live creator die (creator_alive()).
//
// These tests also run under ThreadSanitizer: they fork from a process that has no other thread
// and the children start none, which TSan supports (it is fork() after threads that it does not).

#include <fcntl.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <thread>
#include <string>
#include <utility>

#include "ipc_test_support.hpp"
#include "lancet/shared_model/shm_segment.hpp"
#include "wait.hpp"

namespace lancet {
namespace {

using test::dev_shm_path;
using test::unique_shm_name;

constexpr std::uint64_t kHash = 0x00c0ffee00c0ffeeull;
constexpr std::size_t kPayload = 4096;

bool exists(const std::string& name) {
  struct stat st {};
  return ::stat(dev_shm_path(name).c_str(), &st) == 0;
}

// Forks a child that creates `name` (ready or still initialising) and dies without cleanup.
// Returns the child's pid once it has been reaped (so that pid is no longer running).
pid_t leave_segment_behind(const std::string& name, bool mark_ready) {
  const pid_t child = test::fork_child([&] {
    ShmSegment::CreateOptions o;
    o.lock_memory = false;
    o.creator_name = "doomed-child";
    auto r = ShmSegment::create(name, kPayload, kHash, o);
    if (!r.ok()) return 2;
    if (mark_ready) r.value().mark_ready();
    // Die here, with the segment still owned: no destructor runs, so the object stays in
    // /dev/shm with a header that names this (soon dead) process. Returning would unlink it.
    ::_exit(0);
  });
  EXPECT_GT(child, 0) << "fork failed";
  EXPECT_EQ(test::wait_exit_status(child), 0) << "the child could not create " << name;
  return child;
}

class ShmSegmentStale : public ::testing::Test {
 protected:
  void TearDown() override {
    if (!name_.empty()) ::shm_unlink(name_.c_str());  // in case a check failed half-way
  }
  std::string name_ = unique_shm_name();
};

TEST_F(ShmSegmentStale, OpenOfASegmentWhoseCreatorDiedIsStale) {
  const pid_t dead = leave_segment_behind(name_, /*mark_ready=*/true);
  ASSERT_TRUE(exists(name_)) << "the child's segment should have been left behind";

  auto r = ShmSegment::open(name_, kPayload, kHash);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kStale) << r.error().message;
  EXPECT_NE(r.error().message.find("pid " + std::to_string(dead)), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("doomed-child"), std::string::npos) << r.error().message;
}

TEST_F(ShmSegmentStale, OpenOfAHalfBuiltSegmentWhoseCreatorDiedIsStale) {
  const pid_t dead = leave_segment_behind(name_, /*mark_ready=*/false);
  auto r = ShmSegment::open(name_, kPayload, kHash);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kStale) << r.error().message;
  EXPECT_NE(r.error().message.find(std::to_string(dead)), std::string::npos) << r.error().message;
}

TEST_F(ShmSegmentStale, CreateReplacesAStaleSegmentAndSaysSo) {
  const pid_t dead = leave_segment_behind(name_, /*mark_ready=*/true);

  auto r = ShmSegment::create(name_, kPayload, kHash);
  ASSERT_TRUE(r.ok()) << r.error().message;
  ShmSegment seg = std::move(r).value();
  EXPECT_EQ(seg.header().creator_pid, static_cast<std::int32_t>(::getpid()));
  bool noted = false;
  for (const std::string& note : seg.notes()) {
    if (note.find("stale") != std::string::npos && note.find(std::to_string(dead)) != std::string::npos) noted = true;
  }
  EXPECT_TRUE(noted) << "notes() should mention the stale segment of pid " << dead;

  // The replacement is a working segment.
  seg.mark_ready();
  auto peer = ShmSegment::open(name_, kPayload, kHash);
  EXPECT_TRUE(peer.ok()) << peer.error().message;
}

TEST_F(ShmSegmentStale, CreateWithoutReplaceStaleRefuses) {
  leave_segment_behind(name_, /*mark_ready=*/true);
  ShmSegment::CreateOptions o;
  o.lock_memory = false;
  o.replace_stale = false;
  auto r = ShmSegment::create(name_, kPayload, kHash, o);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kStale) << r.error().message;
  EXPECT_TRUE(exists(name_)) << "replace_stale=false must leave the object alone";
}

TEST_F(ShmSegmentStale, OpenerSeesALiveCreatorDie) {
  // The child creates the segment, tells us, and waits until we tell it to die.
  int ready[2];
  int die[2];
  ASSERT_EQ(::pipe(ready), 0);
  ASSERT_EQ(::pipe(die), 0);
  const std::string name = name_;
  const pid_t child = test::fork_child([&] {
    ::close(ready[0]);
    ::close(die[1]);
    ShmSegment::CreateOptions o;
    o.lock_memory = false;
    auto r = ShmSegment::create(name, kPayload, kHash, o);
    if (!r.ok()) return 2;
    r.value().mark_ready();
    char c = 1;
    if (::write(ready[1], &c, 1) != 1) return 3;
    (void)!::read(die[0], &c, 1);  // returns when the parent closes its end
    ::_exit(0);                    // dies without unmapping or unlinking (no destructor runs)
  });
  ASSERT_GT(child, 0) << "fork failed";
  ::close(ready[1]);
  ::close(die[0]);
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1) << "the child did not create the segment";
  ::close(ready[0]);

  auto r = ShmSegment::open(name_, kPayload, kHash);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const ShmSegment& peer = r.value();
  EXPECT_TRUE(peer.creator_alive());
  EXPECT_EQ(peer.header().creator_pid, child);

  ::close(die[1]);
  ASSERT_EQ(test::wait_exit_status(child), 0);
  EXPECT_FALSE(peer.creator_alive()) << "the creator is gone (pid " << child << ")";
  EXPECT_EQ(peer.header().state.load(), static_cast<std::uint32_t>(SegmentState::kReady))
      << "it died without cleanup: only the pid check can tell";
  EXPECT_FALSE(peer.replaced()) << "nobody has replaced the name yet";
}

}  // namespace
}  // namespace lancet

namespace lancet {
namespace {

TEST_F(ShmSegmentStale, ACreatorThatExitedButIsNotReapedCountsAsDead) {
  const pid_t child = test::fork_child([&] {
    ShmSegment::CreateOptions o;
    o.lock_memory = false;
    auto r = ShmSegment::create(name_, kPayload, kHash, o);
    if (!r.ok()) return 2;
    r.value().mark_ready();
    ::_exit(0);
  });
  ASSERT_GT(child, 0);
  // Wait for the child to exit without reaping it (WNOWAIT): it is a zombie now, and kill(pid, 0)
  // still succeeds on it.
  siginfo_t info{};
  ASSERT_EQ(::waitid(P_PID, static_cast<id_t>(child), &info, WEXITED | WNOWAIT), 0);
  ASSERT_EQ(info.si_code, CLD_EXITED);
  ASSERT_EQ(::kill(child, 0), 0) << "an unreaped child still has its pid";
  EXPECT_FALSE(process_alive(child, 0));
  auto r = ShmSegment::open(name_, kPayload, kHash);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kStale) << r.error().message;
  EXPECT_EQ(test::wait_exit_status(child), 0);
}

TEST_F(ShmSegmentStale, AnEmptyLeftoverObjectIsReplaced) {
  // What a creator that died between shm_open(O_EXCL) and ftruncate leaves behind.
  const int fd = ::shm_open(name_.c_str(), O_CREAT | O_EXCL | O_RDWR, 0600);
  ASSERT_GE(fd, 0);
  ::close(fd);
  auto r = ShmSegment::create(name_, kPayload, kHash, {});
  ASSERT_TRUE(r.ok()) << r.error().message;
  bool noted = false;
  for (const auto& n : r.value().notes()) noted |= n.find("not a Lancet segment") != std::string::npos;
  EXPECT_TRUE(noted);
}

TEST_F(ShmSegmentStale, AnObjectStillBeingCreatedIsNotStolen) {
  // Another creator has made the object with O_EXCL and stamps its header 50 ms later (so that
  // create() nearly always finds it still without one). create() waits for the header with a
  // grace far beyond any scheduling delay: it must find the live creator, not steal the object.
  const int fd = ::shm_open(name_.c_str(), O_CREAT | O_EXCL | O_RDWR, 0600);
  ASSERT_GE(fd, 0);
  std::thread other([fd] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (::ftruncate(fd, static_cast<off_t>(kSegmentPayloadOffset + kPayload)) != 0) return;
    void* p = ::mmap(nullptr, sizeof(SegmentHeader), PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    if (p == MAP_FAILED) return;
    auto* h = static_cast<SegmentHeader*>(p);
    h->header_version = kSegmentHeaderVersion;
    h->creator_pid = static_cast<std::int32_t>(::getpid());
    h->creator_start_ticks = process_start_ticks(h->creator_pid);
    std::snprintf(h->creator_name, sizeof h->creator_name, "%s", "slow-creator");
    h->magic = kSegmentMagic;
    ::munmap(p, sizeof(SegmentHeader));
  });
  ShmSegment::CreateOptions o;
  o.lock_memory = false;
  o.header_grace_ms = std::chrono::duration_cast<std::chrono::milliseconds>(test::kHangTimeout).count();
  auto r = ShmSegment::create(name_, kPayload, kHash, o);
  other.join();
  ::close(fd);
  ASSERT_FALSE(r.ok()) << "the second creator stole a segment that was still being created";
  EXPECT_EQ(r.error().code, ErrorCode::kInUse) << r.error().message;
  EXPECT_NE(r.error().message.find("slow-creator"), std::string::npos) << r.error().message;
}

}  // namespace
}  // namespace lancet
