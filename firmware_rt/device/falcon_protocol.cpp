#include "device/falcon_protocol.hpp"

#include <algorithm>

namespace lancet::device::falcon {

namespace {

constexpr std::uint8_t kNibbleBase = 0x41;

void put16(std::uint8_t* p, std::int16_t v) noexcept {
  const auto u = static_cast<std::uint16_t>(v);
  for (int i = 0; i < 4; ++i) p[i] = static_cast<std::uint8_t>(kNibbleBase + ((u >> (4 * i)) & 0xF));
}

bool nibble(std::uint8_t b) noexcept { return b >= kNibbleBase && b <= kNibbleBase + 0xF; }

std::int16_t get16(const std::uint8_t* p) noexcept {
  std::uint16_t u = 0;
  for (int i = 0; i < 4; ++i) u = static_cast<std::uint16_t>(u | ((p[i] - kNibbleBase) & 0xF) << (4 * i));
  return static_cast<std::int16_t>(u);
}

}  // namespace

std::array<std::uint8_t, kPacketSize> encode(const Command& c) noexcept {
  std::array<std::uint8_t, kPacketSize> p{};
  p[0] = '<';
  for (int m = 0; m < 3; ++m) put16(&p[static_cast<std::size_t>(1 + 4 * m)], c.motor[static_cast<std::size_t>(m)]);
  const auto bits = static_cast<std::uint8_t>((c.leds & (kLedGreen | kLedBlue | kLedRed)) | (c.homing ? kHomingMode : 0));
  p[13] = static_cast<std::uint8_t>(kNibbleBase + bits);
  p[14] = kNibbleBase;
  p[15] = '>';
  return p;
}

std::optional<Reply> decode_reply(std::span<const std::uint8_t, kPacketSize> p, Malformed* why) noexcept {
  const auto fail = [&](Malformed m) -> std::optional<Reply> {
    if (why != nullptr) *why = m;
    return std::nullopt;
  };
  if (p[0] != '<' || p[15] != '>') return fail(Malformed::kFraming);
  for (std::size_t i = 1; i <= 12; ++i)
    if (!nibble(p[i])) return fail(Malformed::kNibble);
  // Byte 13 carries seven bits (homed << 4 | grip); byte 14 is not used, but must be in range.
  if (p[13] < kNibbleBase || p[13] > kNibbleBase + 0x7F || !nibble(p[14])) return fail(Malformed::kNibble);
  Reply r;
  for (int m = 0; m < 3; ++m) r.encoder[static_cast<std::size_t>(m)] = get16(&p[static_cast<std::size_t>(1 + 4 * m)]);
  const auto info = static_cast<std::uint8_t>(p[13] - kNibbleBase);
  r.grip = info & 0x0F;
  r.homed = static_cast<std::uint8_t>((info >> 4) & kAllHomed);
  if (why != nullptr) *why = Malformed::kNone;
  return r;
}

Scan scan_replies(std::span<const std::uint8_t> rx) noexcept {
  Scan s;
  std::size_t at = 0;
  while (at < rx.size()) {
    if (rx[at] != '<') {  // junk between packets: one malformed run, up to the next '<'
      ++s.malformed;
      const auto next = std::find(rx.begin() + static_cast<std::ptrdiff_t>(at), rx.end(), std::uint8_t{'<'});
      at = static_cast<std::size_t>(next - rx.begin());
      continue;
    }
    if (rx.size() - at < kPacketSize) break;  // the rest of this packet has not come yet
    const auto window = rx.subspan(at).first<kPacketSize>();
    if (auto r = decode_reply(window)) {
      s.newest = r;
      ++s.replies;
      at += kPacketSize;
    } else {
      ++s.malformed;  // resynchronise on the next '<'
      const auto next = std::find(rx.begin() + static_cast<std::ptrdiff_t>(at) + 1, rx.end(), std::uint8_t{'<'});
      at = static_cast<std::size_t>(next - rx.begin());
    }
  }
  s.consumed = at;
  return s;
}

bool is_loader_hello_reply(std::span<const std::uint8_t> got) noexcept {
  const std::span<const std::uint8_t> want(kLoaderHelloReply);
  if (got.size() == want.size() + 1 && got[0] == 0x00) got = got.subspan(1);
  return got.size() == want.size() && std::equal(got.begin(), got.end(), want.begin());
}

}  // namespace lancet::device::falcon
