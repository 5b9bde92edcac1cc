// COB-IDs of the predefined connection set, and the frame helpers (byte order, SocketCAN).

#include "device/canopen/cob_id.hpp"

#include <gtest/gtest.h>

#include "device/canopen/frame.hpp"
#include "device/canopen/socketcan.hpp"

namespace lancet::device::canopen {
namespace {

TEST(CanopenCobId, KnownIdentifiersOfCia301) {
  EXPECT_EQ(emcy_cob_id(1), 0x081u);
  EXPECT_EQ(sdo_tx_cob_id(5), 0x585u);
  EXPECT_EQ(sdo_rx_cob_id(5), 0x605u);
  EXPECT_EQ(heartbeat_cob_id(127), 0x77Fu);
  EXPECT_EQ(tpdo_cob_id(1, 3), 0x183u);
  EXPECT_EQ(tpdo_cob_id(4, 3), 0x483u);
  EXPECT_EQ(rpdo_cob_id(1, 3), 0x203u);
  EXPECT_EQ(rpdo_cob_id(4, 3), 0x503u);
}

TEST(CanopenCobId, DecodeNamesFunctionNodeAndPdo) {
  auto is = [](std::uint32_t cob, Function fn, int node, int pdo) {
    const CobId c = decode_cob_id(cob);
    return c.function == fn && c.node_id == node && c.pdo_number == pdo;
  };
  EXPECT_TRUE(is(0x000, Function::kNmt, 0, 0));
  EXPECT_TRUE(is(0x080, Function::kSync, 0, 0));
  EXPECT_TRUE(is(0x081, Function::kEmcy, 1, 0));
  EXPECT_TRUE(is(0x181, Function::kTpdo, 1, 1));
  EXPECT_TRUE(is(0x482, Function::kTpdo, 2, 4));
  EXPECT_TRUE(is(0x203, Function::kRpdo, 3, 1));
  EXPECT_TRUE(is(0x57F, Function::kRpdo, 127, 4));
  EXPECT_TRUE(is(0x585, Function::kSdoTx, 5, 0));
  EXPECT_TRUE(is(0x605, Function::kSdoRx, 5, 0));
  EXPECT_TRUE(is(0x77F, Function::kHeartbeat, 127, 0));
  // Left to other services: TIME, LSS, an NMT identifier with a node id.
  EXPECT_EQ(decode_cob_id(0x100).function, Function::kOther);
  EXPECT_EQ(decode_cob_id(0x7E5).function, Function::kOther);
  EXPECT_EQ(decode_cob_id(0x005).function, Function::kOther);
  // Only the 11 identifier bits count.
  EXPECT_TRUE(is(0x8000'0000u | 0x183, Function::kTpdo, 3, 1));
}

TEST(CanopenCobId, EveryPdoAndNodeRoundTrips) {
  for (int id = 1; id <= kMaxNodeId; ++id) {
    for (int n = 1; n <= 4; ++n) {
      const CobId t = decode_cob_id(tpdo_cob_id(n, id));
      const CobId r = decode_cob_id(rpdo_cob_id(n, id));
      ASSERT_TRUE(t.function == Function::kTpdo && t.node_id == id && t.pdo_number == n) << "TPDO" << n << " node " << id;
      ASSERT_TRUE(r.function == Function::kRpdo && r.node_id == id && r.pdo_number == n) << "RPDO" << n << " node " << id;
    }
    ASSERT_EQ(decode_cob_id(emcy_cob_id(id)).node_id, id);
    ASSERT_EQ(decode_cob_id(heartbeat_cob_id(id)).function, Function::kHeartbeat);
  }
  EXPECT_FALSE(valid_node_id(0));
  EXPECT_TRUE(valid_node_id(1));
  EXPECT_TRUE(valid_node_id(127));
  EXPECT_FALSE(valid_node_id(128));
}

TEST(CanopenFrame, LittleEndianPacking) {
  std::uint8_t b[4] = {};
  put_le(b, 0x12345678, 4);
  EXPECT_EQ(b[0], 0x78);
  EXPECT_EQ(b[3], 0x12);
  EXPECT_EQ(get_le(b, 4), 0x12345678u);
  EXPECT_EQ(get_le(b, 2), 0x5678u);
  EXPECT_EQ(get_le(b, 0), 0u);
}

TEST(CanopenFrame, SocketCanRoundTrip) {
  Frame f{0x183, 6, {1, 2, 3, 4, 5, 6, 0, 0}};
  const ::can_frame c = to_can_frame(f);
  EXPECT_EQ(c.can_id, 0x183u);
  EXPECT_EQ(c.len, 6);
  const Frame back = from_can_frame(c);
  EXPECT_EQ(back.cob_id, f.cob_id);
  EXPECT_EQ(back.len, f.len);
  EXPECT_EQ(back.data, f.data);
  Frame too_long{0x201, 12, {9, 9, 9, 9, 9, 9, 9, 9}};
  EXPECT_EQ(to_can_frame(too_long).len, 8) << "a classic frame has at most 8 bytes";
}

}  // namespace
}  // namespace lancet::device::canopen
