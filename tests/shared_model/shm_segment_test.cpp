// ShmSegment and SharedChannel in one process: create/open round trips through two mappings,
// every refusal (in use, layout hash, size, missing, not ready, bad name) with a message that
// says why, cleanup by the creator, and the permissions of the object.
// Segments left behind by a dead creator: shm_segment_stale_test.cpp (forks).

#include "lancet/shared_model/shm_segment.hpp"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cerrno>
#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>

#include "ipc_test_support.hpp"
#include "lancet/shared_model/shared_state.hpp"

namespace lancet {
namespace {

using test::dev_shm_path;
using test::unique_shm_name;

constexpr std::uint64_t kHash = 0x1234abcd5678ef90ull;
constexpr std::size_t kPayload = 10000;  // not a page multiple on purpose

bool exists(const std::string& name) {
  struct stat st {};
  return ::stat(dev_shm_path(name).c_str(), &st) == 0;
}

std::string hex(std::uint64_t v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "0x%016" PRIx64, v);
  return buf;
}

ShmSegment::CreateOptions no_lock() {
  ShmSegment::CreateOptions o;
  o.lock_memory = false;
  o.creator_name = "shm-test";
  return o;
}

// Creates a ready segment or fails the test.
ShmSegment make_ready(const std::string& name, std::size_t payload = kPayload, std::uint64_t hash = kHash) {
  auto r = ShmSegment::create(name, payload, hash, no_lock());
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
  ShmSegment seg = std::move(r).value();
  seg.mark_ready();
  return seg;
}

TEST(ShmSegment, CreateThenOpenSharesThePayload) {
  const std::string name = unique_shm_name();
  ShmSegment creator = make_ready(name);
  EXPECT_TRUE(creator.is_creator());
  EXPECT_EQ(creator.name(), name);
  EXPECT_TRUE(exists(name));

  const SegmentHeader& h = creator.header();
  EXPECT_EQ(h.magic, kSegmentMagic);
  EXPECT_EQ(h.header_version, kSegmentHeaderVersion);
  EXPECT_EQ(h.creator_pid, static_cast<std::int32_t>(::getpid()));
  EXPECT_NE(h.creator_start_ticks, 0u);
  EXPECT_EQ(h.layout_hash, kHash);
  EXPECT_EQ(h.payload_size, kPayload);
  EXPECT_EQ(h.payload_offset, kSegmentPayloadOffset);
  EXPECT_GE(h.total_size, kSegmentPayloadOffset + kPayload);
  EXPECT_EQ(h.total_size % static_cast<std::uint64_t>(::sysconf(_SC_PAGESIZE)), 0u);
  EXPECT_STREQ(h.creator_name, "shm-test");

  // The creator zero-fills; then it writes, and the opener sees it.
  auto* cp = static_cast<unsigned char*>(creator.payload());
  for (std::size_t i = 0; i < kPayload; ++i) ASSERT_EQ(cp[i], 0) << "byte " << i;
  for (std::size_t i = 0; i < kPayload; ++i) cp[i] = static_cast<unsigned char>(i * 7 + 3);

  auto opened = ShmSegment::open(name, kPayload, kHash);
  ASSERT_TRUE(opened.ok()) << opened.error().message;
  ShmSegment peer = std::move(opened).value();
  EXPECT_FALSE(peer.is_creator());
  EXPECT_TRUE(peer.creator_alive());
  EXPECT_FALSE(peer.replaced());
  auto* pp = static_cast<unsigned char*>(peer.payload());
  EXPECT_NE(pp, cp) << "two mappings of one object";
  EXPECT_EQ(std::memcmp(pp, cp, kPayload), 0);

  // And back: the opener writes, the creator sees it.
  pp[0] = 0xee;
  pp[kPayload - 1] = 0xdd;
  EXPECT_EQ(cp[0], 0xee);
  EXPECT_EQ(cp[kPayload - 1], 0xdd);
}

TEST(ShmSegment, ObjectIsPrivateToTheUser) {
  const std::string name = unique_shm_name();
  ShmSegment seg = make_ready(name);
  struct stat st {};
  ASSERT_EQ(::stat(dev_shm_path(name).c_str(), &st), 0) << std::strerror(errno);
  EXPECT_EQ(st.st_mode & 0777, 0600u) << "mode is 0" << std::oct << (st.st_mode & 0777);
  EXPECT_EQ(st.st_uid, ::getuid());
}

TEST(ShmSegment, CreatorDestructorUnlinksOpenerDoesNot) {
  const std::string name = unique_shm_name();
  {
    ShmSegment creator = make_ready(name);
    {
      auto peer = ShmSegment::open(name, kPayload, kHash);
      ASSERT_TRUE(peer.ok()) << peer.error().message;
    }
    EXPECT_TRUE(exists(name)) << "an opener going away must not remove the segment";
  }
  EXPECT_FALSE(exists(name)) << dev_shm_path(name) << " is still there after the creator went away";
  auto again = ShmSegment::open(name, kPayload, kHash);
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.error().code, ErrorCode::kNotFound);
}

TEST(ShmSegment, OpenerSeesTheCreatorLeave) {
  const std::string name = unique_shm_name();
  auto creator = std::make_unique<ShmSegment>(make_ready(name));
  auto opened = ShmSegment::open(name, kPayload, kHash);
  ASSERT_TRUE(opened.ok()) << opened.error().message;
  const ShmSegment& peer = opened.value();
  EXPECT_TRUE(peer.creator_alive());
  creator.reset();
  EXPECT_FALSE(peer.creator_alive()) << "a clean exit marks the header closed";
  EXPECT_TRUE(peer.replaced()) << "the name is gone: the opener should reopen";

  // A successor under the same name is a different object.
  ShmSegment successor = make_ready(name);
  EXPECT_TRUE(peer.replaced());
  auto fresh = ShmSegment::open(name, kPayload, kHash);
  ASSERT_TRUE(fresh.ok()) << fresh.error().message;
  EXPECT_FALSE(fresh.value().replaced());
}

TEST(ShmSegment, MovedCreatorKeepsOwnership) {
  const std::string name = unique_shm_name();
  {
    ShmSegment a = make_ready(name);
    ShmSegment b = std::move(a);
    EXPECT_TRUE(b.is_creator());
    EXPECT_FALSE(a.is_creator());  // NOLINT(bugprone-use-after-move): checking the moved-from state
    ShmSegment c = make_ready(unique_shm_name());
    c = std::move(b);  // releases c's own segment, takes over name
    EXPECT_EQ(c.name(), name);
    EXPECT_TRUE(exists(name));
  }
  EXPECT_FALSE(exists(name));
}

TEST(ShmSegment, CreateWhileTheCreatorLivesIsInUse) {
  const std::string name = unique_shm_name();
  ShmSegment first = make_ready(name);
  auto second = ShmSegment::create(name, kPayload, kHash, no_lock());
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.error().code, ErrorCode::kInUse);
  const std::string& msg = second.error().message;
  EXPECT_NE(msg.find("pid " + std::to_string(::getpid())), std::string::npos) << msg;
  EXPECT_NE(msg.find(name), std::string::npos) << msg;
  EXPECT_NE(msg.find("shm-test"), std::string::npos) << msg;
  EXPECT_TRUE(exists(name)) << "a refused create must not remove the live segment";
}

TEST(ShmSegment, OpenWithAnotherLayoutHashIsMismatchNamingBothHashes) {
  const std::string name = unique_shm_name();
  ShmSegment creator = make_ready(name);
  constexpr std::uint64_t kOther = 0x0fedcba987654321ull;
  auto r = ShmSegment::open(name, kPayload, kOther);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kMismatch);
  const std::string& msg = r.error().message;
  EXPECT_NE(msg.find(hex(kHash)), std::string::npos) << "the segment's hash is missing: " << msg;
  EXPECT_NE(msg.find(hex(kOther)), std::string::npos) << "the expected hash is missing: " << msg;
}

TEST(ShmSegment, OpenWithAnotherPayloadSizeIsMismatch) {
  const std::string name = unique_shm_name();
  ShmSegment creator = make_ready(name);
  for (std::size_t size : {kPayload - 8, kPayload + 8, kPayload * 2}) {
    auto r = ShmSegment::open(name, size, kHash);
    ASSERT_FALSE(r.ok()) << "payload " << size;
    EXPECT_EQ(r.error().code, ErrorCode::kMismatch);
    EXPECT_NE(r.error().message.find(std::to_string(kPayload)), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find(std::to_string(size)), std::string::npos) << r.error().message;
  }
}

TEST(ShmSegment, OpenOfAMissingNameIsNotFound) {
  const std::string name = unique_shm_name();
  auto r = ShmSegment::open(name, kPayload, kHash);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_NE(r.error().message.find(name), std::string::npos) << r.error().message;
}

TEST(ShmSegment, OpenBeforeMarkReadyIsNotReady) {
  const std::string name = unique_shm_name();
  auto r = ShmSegment::create(name, kPayload, kHash, no_lock());
  ASSERT_TRUE(r.ok()) << r.error().message;
  auto early = ShmSegment::open(name, kPayload, kHash);
  ASSERT_FALSE(early.ok());
  EXPECT_EQ(early.error().code, ErrorCode::kNotReady) << early.error().message;
  r.value().mark_ready();
  EXPECT_TRUE(ShmSegment::open(name, kPayload, kHash).ok());
}

TEST(ShmSegment, OpenOfAForeignObjectIsMismatch) {
  // Something else under the name (not a Lancet segment): refused by its magic, left alone.
  const std::string name = unique_shm_name();
  const int fd = ::shm_open(name.c_str(), O_CREAT | O_EXCL | O_RDWR, 0600);
  ASSERT_GE(fd, 0) << std::strerror(errno);
  ASSERT_EQ(::ftruncate(fd, 2 * static_cast<off_t>(kSegmentPayloadOffset)), 0);
  ::close(fd);
  auto r = ShmSegment::open(name, kPayload, kHash);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kMismatch);
  EXPECT_NE(r.error().message.find("magic"), std::string::npos) << r.error().message;
  EXPECT_TRUE(exists(name));
  ::shm_unlink(name.c_str());
}

TEST(ShmSegment, InvalidNamesAreRefused) {
  for (const std::string bad : {"", "/", "lancet", "no-slash/", "/a/b", "//"}) {
    auto r = ShmSegment::create(bad, kPayload, kHash, no_lock());
    ASSERT_FALSE(r.ok()) << "'" << bad << "'";
    EXPECT_EQ(r.error().code, ErrorCode::kInvalid) << "'" << bad << "': " << r.error().message;
    EXPECT_NE(r.error().message.find("'" + bad + "'"), std::string::npos) << r.error().message;
  }
}

TEST(ShmSegment, LockMemoryIsDoneOrNoted) {
  // mlock may be refused (RLIMIT_MEMLOCK); then notes() must say so instead of failing.
  const std::string name = unique_shm_name();
  auto r = ShmSegment::create(name, kPayload, kHash);
  ASSERT_TRUE(r.ok()) << r.error().message;
  const ShmSegment& seg = r.value();
  if (!seg.locked()) {
    ASSERT_FALSE(seg.notes().empty());
    EXPECT_NE(seg.notes().front().find("mlock"), std::string::npos) << seg.notes().front();
  } else {
    EXPECT_TRUE(seg.notes().empty());
  }
}

// --- SharedChannel: the real SharedState in a segment ---------------------------------------

static_assert(kSharedLayoutHash != 0);
static_assert(kSharedLayoutHash == shared_layout_hash(), "the hash is a compile-time constant");
static_assert(std::is_trivially_destructible_v<SharedState>, "nothing to destroy in shared memory");

TEST(SharedChannel, CreateThenOpenSharesTheState) {
  const std::string name = unique_shm_name();
  auto created = SharedChannel::create(name, no_lock());
  ASSERT_TRUE(created.ok()) << created.error().message;
  auto opened = SharedChannel::open(name);
  ASSERT_TRUE(opened.ok()) << opened.error().message;
  SharedChannel& rt = created.value();
  SharedChannel& viz = opened.value();

  EXPECT_NE(kSharedLayoutHash, 0u);
  EXPECT_EQ(rt.segment().header().layout_hash, kSharedLayoutHash);
  EXPECT_EQ(viz.segment().header().layout_hash, kSharedLayoutHash);
  EXPECT_EQ(viz.segment().header().payload_size, sizeof(SharedState));
  EXPECT_NE(&rt.state(), &viz.state()) << "each side has its own mapping";

  // rt → viz: a ToolSample through the ring, RtStatus through a seqlock, a heartbeat.
  ToolSample s{};
  s.seq = 41;
  s.force = {1.0, 2.0, 3.0};
  ASSERT_TRUE(rt.state().samples.try_push(s));
  RtStatus status{};
  status.tick = 1000;
  rt.state().rt_status.write(status);
  rt.state().rt_heartbeat.beat(123456789, static_cast<std::int32_t>(::getpid()));

  ToolSample got{};
  ASSERT_TRUE(viz.state().samples.try_pop(got));
  EXPECT_EQ(got.seq, 41u);
  EXPECT_EQ(got.force, (Vec3{1.0, 2.0, 3.0}));
  RtStatus seen{};
  ASSERT_EQ(viz.state().rt_status.try_read(seen), ReadStatus::kOk);
  EXPECT_EQ(seen.tick, 1000u);
  EXPECT_EQ(viz.state().rt_heartbeat.last_ns(), 123456789);
  EXPECT_EQ(viz.state().rt_heartbeat.pid(), static_cast<std::int32_t>(::getpid()));

  // viz → rt: a Command and a StylusTarget.
  Command c{};
  c.seq = 7;
  c.kind = CommandKind::kSetToolMode;
  c.mode = ToolMode::kDrill;
  ASSERT_TRUE(viz.state().commands.try_push(c));
  StylusTarget t{};
  t.active = 1;
  t.hand = Hand::kLeft;
  t.target.position = {0.1, 0.2, 0.3};
  viz.state().stylus_target[hand_index(Hand::kLeft)].write(t);

  Command cmd{};
  ASSERT_TRUE(rt.state().commands.try_pop(cmd));
  EXPECT_EQ(cmd.seq, 7u);
  EXPECT_EQ(cmd.mode, ToolMode::kDrill);
  StylusTarget target{};
  EXPECT_EQ(rt.state().stylus_target[hand_index(Hand::kRight)].try_read(target), ReadStatus::kEmpty) << "each hand has its own";
  ASSERT_EQ(rt.state().stylus_target[hand_index(Hand::kLeft)].try_read(target), ReadStatus::kOk);
  EXPECT_EQ(target.target.position, (Vec3{0.1, 0.2, 0.3}));
  EXPECT_EQ(target.hand, Hand::kLeft);
  // The patches were never written.
  auto patch = std::make_unique<TissuePatch>();
  for (auto& p : rt.state().patch) EXPECT_EQ(p.try_read(*patch), ReadStatus::kEmpty);
}

TEST(SharedChannel, OpenWithoutACreatorIsNotFound) {
  auto r = SharedChannel::open(unique_shm_name());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
}

TEST(SharedChannel, OpenOfASegmentWithAnotherLayoutIsRefused) {
  // A peer built from other sources: same name, different hash.
  const std::string name = unique_shm_name();
  ShmSegment other = make_ready(name, sizeof(SharedState), kSharedLayoutHash ^ 1);
  auto r = SharedChannel::open(name);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kMismatch);
  EXPECT_NE(r.error().message.find(hex(kSharedLayoutHash)), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find(hex(kSharedLayoutHash ^ 1)), std::string::npos) << r.error().message;
}

}  // namespace
}  // namespace lancet
