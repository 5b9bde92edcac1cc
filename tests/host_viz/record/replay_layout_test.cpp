// Which recordings a build replays: those whose recorded messages (ToolSample, TissuePatch, the
// servo model blob) are laid out as this build's, whatever else of the protocol changed since;
// any other is refused with both layouts named.

#include <gtest/gtest.h>

#include <string>

#include "lancet/shared_model/shared_state.hpp"
#include "record/replay.hpp"

namespace lancet::record {
namespace {

bool refused_for_layout(const Recording& rec, std::string* message = nullptr) {
  auto r = Replay::create(rec);
  if (r.ok()) return false;
  if (message != nullptr) *message = r.error().message;
  return r.error().code == ErrorCode::kMismatch;
}

TEST(ReplayLayout, ARecordingOfThisBuildsRecordedLayoutPassesTheCheck) {
  Recording rec;  // no ticks: refused afterwards for that, not for its layout
  rec.layout_hash = 0x1234;  // another shared layout: the command ring or the status may differ
  EXPECT_EQ(rec.recorded_layout_hash, kRecordedLayoutHash);
  std::string why;
  EXPECT_FALSE(refused_for_layout(rec, &why)) << why;
  EXPECT_NE(why.find("no ticks"), std::string::npos) << why;
}

TEST(ReplayLayout, AnotherRecordedLayoutIsRefusedWithBothNamed) {
  Recording rec;
  rec.recorded_layout_hash = kRecordedLayoutHash ^ 0x10;
  rec.protocol = 99;
  std::string why;
  ASSERT_TRUE(refused_for_layout(rec, &why));
  EXPECT_NE(why.find("protocol 99"), std::string::npos) << why;
  EXPECT_NE(why.find("replay it with the build that recorded it"), std::string::npos) << why;
}

// Protocol 10 recorded one hand: its samples' and patches' bytes where the hand is now were
// reserved and 0, the right hand; its recordings replay as the right hand's.
TEST(ReplayLayout, OneHandedRecordingsOfProtocol10PassTheCheck) {
  Recording rec;
  rec.recorded_layout_hash = 0x937ea367a07bda5eull;
  std::string why;
  EXPECT_FALSE(refused_for_layout(rec, &why)) << why;
  EXPECT_NE(rec.recorded_layout_hash, kRecordedLayoutHash) << "this build's differs: it records the hand";
}

TEST(ReplayLayout, FilesWithoutTheAttributeGoByTheirSharedLayout) {
  Recording rec;
  rec.recorded_layout_hash = 0;  // as read from a file written before the attribute existed
  rec.layout_hash = kSharedLayoutHash;
  EXPECT_FALSE(refused_for_layout(rec));
  rec.layout_hash = 0xdfc3b587a1660cf6ull;  // protocol 9: the same recorded messages
  EXPECT_FALSE(refused_for_layout(rec));
  rec.layout_hash = 0x0123456789abcdefull;  // anything else
  EXPECT_TRUE(refused_for_layout(rec));
}

}  // namespace
}  // namespace lancet::record
