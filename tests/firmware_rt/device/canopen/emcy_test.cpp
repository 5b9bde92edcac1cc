// Emergency messages: the frame, its decoding, and the words for a code.

#include "device/canopen/emcy.hpp"

#include <gtest/gtest.h>

namespace lancet::device::canopen {
namespace {

using Bytes = std::array<std::uint8_t, 8>;

TEST(CanopenEmcy, FrameOfCia301) {
  // Node 1, 0x2310 continuous over-current, error register 0x03: 10 23 03 00 00 00 00 00 on 0x081.
  const Frame f = emcy_frame(1, 0x2310, 0x03);
  EXPECT_EQ(f.cob_id, 0x081u);
  EXPECT_EQ(f.len, 8);
  EXPECT_EQ(f.data, (Bytes{0x10, 0x23, 0x03, 0, 0, 0, 0, 0}));
}

TEST(CanopenEmcy, DecodeRoundTripsAndRejectsBadFrames) {
  const auto e = decode_emcy(emcy_frame(42, kEmcyHeartbeat, kErrorRegisterGeneric | kErrorRegisterCommunication));
  ASSERT_TRUE(e);
  EXPECT_EQ(e->node_id, 42);
  EXPECT_EQ(e->error_code, 0x8130);
  EXPECT_EQ(e->error_register, 0x11);
  EXPECT_EQ(e->t_ns, 0);

  Frame vendor{0x085, 5, {0x00, 0xFF, 0x01, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE}};
  const auto v = decode_emcy(vendor);
  ASSERT_TRUE(v);
  EXPECT_EQ(v->error_code, 0xFF00);
  EXPECT_EQ(v->vendor[0], 0xAA);
  EXPECT_EQ(v->vendor[1], 0xBB);
  EXPECT_EQ(v->vendor[2], 0x00) << "bytes the frame lacks read 0";

  Frame shrt = emcy_frame(1, 0x2310, 0x03);
  shrt.len = 2;
  EXPECT_FALSE(decode_emcy(shrt)) << "short frame";
  Frame sync = emcy_frame(1, 0x2310, 0x03);
  sync.cob_id = 0x080;
  EXPECT_FALSE(decode_emcy(sync)) << "SYNC is no EMCY";
  Frame tpdo = emcy_frame(1, 0x2310, 0x03);
  tpdo.cob_id = 0x181;
  EXPECT_FALSE(decode_emcy(tpdo)) << "wrong COB-ID";
}

TEST(CanopenEmcy, MeaningByCodeThenClass) {
  EXPECT_STREQ(emcy_meaning(0x0000).text, "error reset or no error");
  EXPECT_TRUE(emcy_meaning(0x8130).specific);
  EXPECT_STREQ(emcy_meaning(0x8130).text, "heartbeat / life guard error");
  EXPECT_STREQ(emcy_meaning(0x8199).text, "monitoring: communication");
  EXPECT_FALSE(emcy_meaning(0x8199).specific);
  EXPECT_STREQ(emcy_meaning(0xA123).text, "reserved class");
  Emcy e{};
  e.node_id = 3;
  e.error_code = 0x4310;
  e.error_register = 0x09;
  char buf[120];
  EXPECT_STREQ(format_emcy(buf, sizeof buf, e), "node 3: EMCY 0x4310 drive over-temperature, error register 0x09");
  EXPECT_EQ(format_emcy(nullptr, 0, e), nullptr);
}

}  // namespace
}  // namespace lancet::device::canopen
