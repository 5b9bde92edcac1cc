// PDO parameter objects and mapping entries.

#include "device/canopen/pdo.hpp"

#include <gtest/gtest.h>

namespace lancet::device::canopen {
namespace {

TEST(CanopenPdo, ParameterIndexes) {
  EXPECT_EQ(rpdo_communication_index(1), 0x1400);
  EXPECT_EQ(rpdo_mapping_index(4), 0x1603);
  EXPECT_EQ(tpdo_communication_index(2), 0x1801);
  EXPECT_EQ(tpdo_mapping_index(1), 0x1A00);
  for (int n = 1; n <= kMaxPdos; ++n) {
    for (const bool tx : {true, false}) {
      for (const bool map : {true, false}) {
        const std::uint16_t index = tx ? (map ? tpdo_mapping_index(n) : tpdo_communication_index(n))
                                       : (map ? rpdo_mapping_index(n) : rpdo_communication_index(n));
        const auto p = pdo_parameter(index);
        ASSERT_TRUE(p) << std::hex << index;
        EXPECT_EQ(p->tpdo, tx);
        EXPECT_EQ(p->mapping, map);
        EXPECT_EQ(p->number, n);
      }
    }
  }
  EXPECT_FALSE(pdo_parameter(0x1404)) << "PDO 5 is not in the predefined set";
  EXPECT_FALSE(pdo_parameter(0x1000));
  EXPECT_FALSE(pdo_parameter(0x6041));
}

TEST(CanopenPdo, MappingEntries) {
  // Statusword, 16 bits: 0x60410010; position actual, 32 bits: 0x60640020.
  EXPECT_EQ(encode_mapping({0x6041, 0, 16}), 0x60410010u);
  EXPECT_EQ(encode_mapping({0x6064, 0, 32}), 0x60640020u);
  const MappingEntry e = decode_mapping(0x60C20208u);
  EXPECT_EQ(e.index, 0x60C2);
  EXPECT_EQ(e.sub, 2);
  EXPECT_EQ(e.bits, 8);
  EXPECT_EQ(mapped_bytes(0x60640020u), 4);
  const std::uint32_t map[] = {0x60410010u, 0x60640020u, 0x60600008u};
  EXPECT_EQ(mapped_bits(map, 3), 56);
  EXPECT_EQ(mapped_bits(map, 0), 0);
  EXPECT_EQ(kPdoInvalid | 0x183u, 0x80000183u);
}

}  // namespace
}  // namespace lancet::device::canopen
