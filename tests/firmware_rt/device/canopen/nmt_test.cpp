// NMT commands, heartbeats and boot-up messages, heartbeat consumer entries.

#include "device/canopen/nmt.hpp"

#include <gtest/gtest.h>

namespace lancet::device::canopen {
namespace {

TEST(CanopenNmt, CommandFrames) {
  const Frame start = nmt_frame(NmtCommand::kStart, 2);
  EXPECT_EQ(start.cob_id, 0x000u);
  ASSERT_EQ(start.len, 2);
  EXPECT_EQ(start.data[0], 0x01);
  EXPECT_EQ(start.data[1], 0x02);
  const Frame reset_all = nmt_frame(NmtCommand::kResetCommunication, 0);
  EXPECT_EQ(reset_all.data[0], 0x82);
  EXPECT_EQ(reset_all.data[1], 0x00);
  EXPECT_EQ(nmt_frame(NmtCommand::kEnterPreOperational, 5).data[0], 0x80);
}

TEST(CanopenNmt, DecodeRoundTripsAndRejectsBadFrames) {
  const auto rq = decode_nmt(nmt_frame(NmtCommand::kStop, 9));
  ASSERT_TRUE(rq);
  EXPECT_EQ(rq->command, NmtCommand::kStop);
  EXPECT_EQ(rq->node_id, 9);
  Frame unknown = nmt_frame(NmtCommand::kStart, 1);
  unknown.data[0] = 0x55;  // no such command: still passed on, as the byte sent
  ASSERT_TRUE(decode_nmt(unknown));
  EXPECT_EQ(static_cast<std::uint8_t>(decode_nmt(unknown)->command), 0x55);
  Frame shrt = nmt_frame(NmtCommand::kStart, 1);
  shrt.len = 1;
  EXPECT_FALSE(decode_nmt(shrt)) << "short frame";
  Frame other = nmt_frame(NmtCommand::kStart, 1);
  other.cob_id = 0x001;
  EXPECT_FALSE(decode_nmt(other)) << "wrong COB-ID";
}

TEST(CanopenNmt, HeartbeatAndBootUp) {
  const Frame hb = heartbeat_frame(4, NmtState::kOperational);
  EXPECT_EQ(hb.cob_id, 0x704u);
  ASSERT_EQ(hb.len, 1);
  EXPECT_EQ(hb.data[0], 0x05);
  const Frame boot = heartbeat_frame(4, NmtState::kBootUp);
  EXPECT_EQ(boot.data[0], 0x00);
  EXPECT_EQ(decode_heartbeat(boot), NmtState::kBootUp);
  EXPECT_EQ(decode_heartbeat(heartbeat_frame(7, NmtState::kPreOperational)), NmtState::kPreOperational);
  EXPECT_EQ(decode_heartbeat(heartbeat_frame(7, NmtState::kStopped)), NmtState::kStopped);
  Frame toggled = hb;
  toggled.data[0] = 0x85;  // node guarding's toggle bit
  EXPECT_EQ(decode_heartbeat(toggled), NmtState::kOperational);
  Frame junk = hb;
  junk.data[0] = 0x33;
  EXPECT_EQ(decode_heartbeat(junk), NmtState::kUnknown);
  Frame empty = hb;
  empty.len = 0;
  EXPECT_FALSE(decode_heartbeat(empty)) << "short frame";
  Frame tpdo = hb;
  tpdo.cob_id = 0x184;
  EXPECT_FALSE(decode_heartbeat(tpdo)) << "wrong COB-ID";
  EXPECT_STREQ(to_string(NmtState::kPreOperational), "pre-operational");
}

TEST(CanopenNmt, ConsumerEntry) {
  const std::uint32_t e = heartbeat_consumer_entry(127, 2000);
  EXPECT_EQ(e, 0x007F07D0u);
  EXPECT_EQ(consumer_producer_id(e), 127);
  EXPECT_EQ(consumer_time_ms(e), 2000u);
  EXPECT_EQ(consumer_producer_id(0xFFFF'FFFFu), 127) << "bits above the node id are not the producer";
}

}  // namespace
}  // namespace lancet::device::canopen
