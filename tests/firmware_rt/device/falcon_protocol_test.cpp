// The FTDI chip's arithmetic and the Falcon's packet codec, with no device: byte vectors written
// out by hand from the protocol's description (device/falcon_protocol.hpp, device/ftdi.hpp), the
// divisors libftdi and libnifalcon send for the rates the Falcon uses, round trips, and a fuzz of
// the reply scanner over random and corrupted bytes.

#include "device/falcon_protocol.hpp"
#include "device/ftdi.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace lancet::device {
namespace {

using Bytes = std::vector<std::uint8_t>;

Bytes bytes(std::string_view s) { return Bytes(s.begin(), s.end()); }

// ---------------------------------------------------------------------------------------------
// FTDI

TEST(FtdiBaud, TheDivisorsOfTheFalconsRatesAreTheOnesItsDriversSend) {
  // 9600: 3 MHz / 312.5; libnifalcon sends 0x4138 ("just trust me").
  auto s = ftdi::baud_setting(9600);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->value, 0x4138);
  EXPECT_EQ(s->index, 0);
  EXPECT_DOUBLE_EQ(s->actual, 9600);
  // 140 000: the nearest divisor is 21.375 (code 4: its third bit goes in wIndex), as libftdi picks.
  s = ftdi::baud_setting(140'000);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->value, 0x0015);
  EXPECT_EQ(s->index, 1);
  EXPECT_NEAR(s->actual, 140'351, 1);
  // 1.5 Mbaud: divisor 2, libnifalcon's normal mode.
  s = ftdi::baud_setting(1'500'000);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->value, 2);
  EXPECT_EQ(s->index, 0);
  // The special divisors.
  EXPECT_EQ(ftdi::baud_setting(3'000'000)->value, 0);
  EXPECT_EQ(ftdi::baud_setting(2'000'000)->value, 1);
  EXPECT_EQ(ftdi::baud_setting(115'200)->value, 0x001A);  // 26.04 → 26
}

TEST(FtdiBaud, EveryRateDecodesBackWithinThreePercentAndImpossibleRatesAreRefused) {
  for (const double b : {300.0, 1200.0, 9600.0, 19200.0, 57600.0, 115200.0, 140000.0, 250000.0, 921600.0, 1e6, 1.5e6, 2e6, 3e6}) {
    const auto s = ftdi::baud_setting(b);
    ASSERT_TRUE(s) << b;
    EXPECT_DOUBLE_EQ(ftdi::baud_of(s->value, s->index), s->actual) << b;
    EXPECT_LE(std::abs(s->actual - b), 0.03 * b) << b;
  }
  EXPECT_FALSE(ftdi::baud_setting(0));
  EXPECT_FALSE(ftdi::baud_setting(-9600));
  EXPECT_FALSE(ftdi::baud_setting(NAN));
  EXPECT_FALSE(ftdi::baud_setting(4e6));
  EXPECT_FALSE(ftdi::baud_setting(100));  // below 3 MHz / 16383.875
}

TEST(FtdiPackets, TheTwoStatusBytesOfEveryPacketAreDropped) {
  // Two full 8-byte packets and a short one: [s s d d d d d d] [s s d d d d d d] [s s d].
  const Bytes in = {0x31, 0x60, 1, 2, 3, 4, 5, 6, 0x31, 0x60, 7, 8, 9, 10, 11, 12, 0x31, 0x60, 13};
  Bytes out(32, 0);
  const std::size_t n = ftdi::strip_modem_status(in, 8, out);
  ASSERT_EQ(n, 13u);
  for (std::size_t i = 0; i < n; ++i) EXPECT_EQ(out[i], i + 1);
  // A packet of status bytes alone carries nothing; a too-small output keeps the first bytes.
  EXPECT_EQ(ftdi::strip_modem_status(Bytes{0x31, 0x60}, 64, out), 0u);
  Bytes small(3, 0);
  EXPECT_EQ(ftdi::strip_modem_status(in, 8, small), 3u);
  EXPECT_EQ(small, (Bytes{1, 2, 3}));
}

// ---------------------------------------------------------------------------------------------
// Falcon packets

TEST(FalconPackets, ACommandIsNibblesFromALeastSignificantFirst) {
  falcon::Command c;
  c.motor = {0x1234, -1, 0};
  c.leds = falcon::kLedGreen;
  c.homing = true;
  const auto p = falcon::encode(c);
  EXPECT_EQ(Bytes(p.begin(), p.end()), bytes("<EDCBPPPPAAAADA>"));
  c = {};
  c.leds = falcon::kLedRed | falcon::kLedBlue;
  c.motor = {-32768, 32767, 0x00F0};
  const auto q = falcon::encode(c);
  EXPECT_EQ(Bytes(q.begin(), q.end()), bytes("<AAAIPPPHAPAAMA>"));
}

TEST(FalconPackets, AReplyCarriesEncodersGripAndHomedBits) {
  // Encoders 0x1234, -2 (0xFFFE), 5; homed motors 1 and 3 (0b101), grip buttons 0b0110.
  Bytes r = bytes("<EDCBOPPPFAAAxA>");
  r[13] = static_cast<std::uint8_t>(0x41 + (0x5 << 4 | 0x6));
  const auto d = falcon::decode_reply(std::span<const std::uint8_t, 16>(r.data(), 16));
  ASSERT_TRUE(d);
  EXPECT_EQ(d->encoder[0], 0x1234);
  EXPECT_EQ(d->encoder[1], -2);
  EXPECT_EQ(d->encoder[2], 5);
  EXPECT_EQ(d->grip, 0x6);
  EXPECT_EQ(d->homed, 0x5);
}

TEST(FalconPackets, BadFramingAndBadNibblesAreNamed) {
  falcon::Malformed why{};
  Bytes r = bytes("<AAAAAAAAAAAAAA>");
  r[15] = ')';
  EXPECT_FALSE(falcon::decode_reply(std::span<const std::uint8_t, 16>(r.data(), 16), &why));
  EXPECT_EQ(why, falcon::Malformed::kFraming);
  r = bytes("<AAAAAAZAAAAAAA>");
  EXPECT_FALSE(falcon::decode_reply(std::span<const std::uint8_t, 16>(r.data(), 16), &why));
  EXPECT_EQ(why, falcon::Malformed::kNibble);
  r = bytes("<AAAAAAAAAAAA@A>");  // byte 13 below 'A'
  EXPECT_FALSE(falcon::decode_reply(std::span<const std::uint8_t, 16>(r.data(), 16), &why));
  EXPECT_EQ(why, falcon::Malformed::kNibble);
}

TEST(FalconPackets, TheScanKeepsTheNewestReplySkipsJunkAndWaitsForAPartialPacket) {
  const Bytes a = bytes("<BAAAAAAAAAAAAA>"), b = bytes("<CAAAAAAAAAAAAA>");
  Bytes rx = bytes("xy");  // junk first
  rx.insert(rx.end(), a.begin(), a.end());
  rx.insert(rx.end(), b.begin(), b.end());
  rx.insert(rx.end(), b.begin(), b.begin() + 5);  // the start of a third
  const falcon::Scan s = falcon::scan_replies(rx);
  ASSERT_TRUE(s.newest);
  EXPECT_EQ(s.newest->encoder[0], 2);
  EXPECT_EQ(s.replies, 2u);
  EXPECT_EQ(s.malformed, 1u);               // one run of junk
  EXPECT_EQ(s.consumed, rx.size() - 5);     // the partial packet stays for the next read
  // A broken packet resynchronises on the next '<'.
  Bytes broken = bytes("<AAAA");
  broken.insert(broken.end(), a.begin(), a.end());
  const falcon::Scan t = falcon::scan_replies(broken);
  ASSERT_TRUE(t.newest);
  EXPECT_EQ(t.newest->encoder[0], 1);
  EXPECT_EQ(t.malformed, 1u);
  EXPECT_EQ(t.consumed, broken.size());
}

TEST(FalconPackets, TheLoadersAnswerIsRecognisedWithOrWithoutItsLeadingZero) {
  EXPECT_TRUE(falcon::is_loader_hello_reply(Bytes{0x0A, 0x44, 0x2C, 0x0D}));
  EXPECT_TRUE(falcon::is_loader_hello_reply(Bytes{0x00, 0x0A, 0x44, 0x2C, 0x0D}));
  EXPECT_FALSE(falcon::is_loader_hello_reply(Bytes{0x0A, 0x43, 0x0D}));
  EXPECT_FALSE(falcon::is_loader_hello_reply(Bytes{0x0A, 0x44, 0x2C, 0x0E}));
  EXPECT_FALSE(falcon::is_loader_hello_reply(Bytes{}));
}

// Every command survives the trip through the reply codec (the packets share the nibble layout).
TEST(FalconPackets, EveryMotorValueRoundTrips) {
  for (int v = -32768; v <= 32767; v += 7) {
    falcon::Command c;
    c.motor = {static_cast<std::int16_t>(v), static_cast<std::int16_t>(-v - 1), static_cast<std::int16_t>(v / 3)};
    auto p = falcon::encode(c);
    const auto d = falcon::decode_reply(std::span<const std::uint8_t, 16>(p.data(), 16));
    ASSERT_TRUE(d) << v;
    EXPECT_EQ(d->encoder[0], c.motor[0]);
    EXPECT_EQ(d->encoder[1], c.motor[1]);
    EXPECT_EQ(d->encoder[2], c.motor[2]);
  }
}

// What the wire delivers is input: random bytes, and good streams with bytes flipped, never make
// the scanner read past the buffer, lose track of what it consumed, or accept a packet that does
// not decode.
TEST(FalconPackets, FuzzedStreamsAreScannedSafely) {
  std::mt19937 rng(29);
  std::uniform_int_distribution<int> byte(0, 255), len(0, 200), coin(0, 9);
  for (int round = 0; round < 20'000; ++round) {
    Bytes rx;
    const int n = len(rng);
    for (int i = 0; i < n; ++i) {
      if (coin(rng) == 0) {
        const auto p = falcon::encode(falcon::Command{{static_cast<std::int16_t>(byte(rng)), 0, 0}, 0, false});
        rx.insert(rx.end(), p.begin(), p.end());
      } else {
        rx.push_back(coin(rng) < 3 ? std::uint8_t{'<'} : static_cast<std::uint8_t>(byte(rng)));
      }
    }
    const falcon::Scan s = falcon::scan_replies(rx);
    ASSERT_LE(s.consumed, rx.size());
    // What stays is empty or begins a packet that has not fully come.
    if (s.consumed < rx.size()) {
      EXPECT_EQ(rx[s.consumed], '<');
      EXPECT_LT(rx.size() - s.consumed, falcon::kPacketSize);
    }
    if (s.replies == 0) {
      EXPECT_FALSE(s.newest);
    }
  }
}

}  // namespace
}  // namespace lancet::device
