// The Modbus register codec of ModbusArm (modbus_arm.hpp): fields in registers (width, signedness,
// word order), errno and exception codes in words, the planning of register blocks.

#include "device/modbus_arm.hpp"

#include <errno.h>
#include <modbus.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

namespace lancet::device {

namespace modbus {

namespace {

struct Range {
  double lo, hi;
};

Range range_of(arm::FieldType t) noexcept {
  switch (t) {
    case arm::FieldType::kU8: return {0, 0xFF};
    case arm::FieldType::kI8: return {-0x80, 0x7F};
    case arm::FieldType::kU16: return {0, 0xFFFF};
    case arm::FieldType::kI16: return {-0x8000, 0x7FFF};
    case arm::FieldType::kU32: return {0, 4294967295.0};
    case arm::FieldType::kI32: return {-2147483648.0, 2147483647.0};
    case arm::FieldType::kF32: return {-std::numeric_limits<float>::max(), std::numeric_limits<float>::max()};
  }
  return {0, 0};
}

std::uint16_t swapped(std::uint16_t r, bool swap) noexcept {
  return swap ? static_cast<std::uint16_t>((r >> 8) | (r << 8)) : r;
}

}  // namespace

Layout layout_of(const arm::RegisterField& f) noexcept { return {f.type, f.high_word_first, f.byte_order == arm::ByteOrder::kLittle}; }

int register_count(arm::FieldType type) noexcept {
  switch (type) {
    case arm::FieldType::kU16:
    case arm::FieldType::kI16: return 1;
    case arm::FieldType::kU32:
    case arm::FieldType::kI32:
    case arm::FieldType::kF32: return 2;
    case arm::FieldType::kU8:
    case arm::FieldType::kI8: return 0;
  }
  return 0;
}

std::uint32_t decode_word(const Layout& l, std::span<const std::uint16_t> regs) noexcept {
  const int rc = register_count(l.type);
  assert(rc > 0 && regs.size() >= static_cast<std::size_t>(rc) && "modbus::decode_word: span too short or 8-bit type");
  if (rc == 1) return swapped(regs[0], l.swap_bytes);
  const std::uint32_t hi = swapped(regs[l.high_word_first ? 0 : 1], l.swap_bytes);
  const std::uint32_t lo = swapped(regs[l.high_word_first ? 1 : 0], l.swap_bytes);
  return (hi << 16) | lo;
}

double decode_value(const Layout& l, std::span<const std::uint16_t> regs) noexcept {
  const std::uint32_t u = decode_word(l, regs);
  switch (l.type) {
    case arm::FieldType::kI16: return static_cast<std::int16_t>(u);
    case arm::FieldType::kI32: return static_cast<std::int32_t>(u);
    case arm::FieldType::kF32: return std::bit_cast<float>(u);
    default: return u;
  }
}

void encode_word(const Layout& l, std::uint32_t word, std::span<std::uint16_t> regs) noexcept {
  const int rc = register_count(l.type);
  assert(rc > 0 && regs.size() >= static_cast<std::size_t>(rc) && "modbus::encode_word: span too short or 8-bit type");
  if (rc == 1) {
    regs[0] = swapped(static_cast<std::uint16_t>(word & 0xFFFFu), l.swap_bytes);
    return;
  }
  const std::uint16_t hi = swapped(static_cast<std::uint16_t>(word >> 16), l.swap_bytes);
  const std::uint16_t lo = swapped(static_cast<std::uint16_t>(word & 0xFFFFu), l.swap_bytes);
  regs[0] = l.high_word_first ? hi : lo;
  regs[1] = l.high_word_first ? lo : hi;
}

double encode_value(const Layout& l, double raw, std::span<std::uint16_t> regs, bool* clamped) noexcept {
  const Range r = range_of(l.type);
  // + 0.0: a zero is sent as +0 (a float setpoint of −0 is zero too, but reads oddly on the wire).
  const double v = (std::isnan(raw) ? 0.0 : l.type == arm::FieldType::kF32 ? raw : std::nearbyint(raw)) + 0.0;
  const double c = std::clamp(v, r.lo, r.hi);
  if (clamped != nullptr) *clamped = c != v || std::isnan(raw);
  if (l.type == arm::FieldType::kF32) {
    const auto f = static_cast<float>(c);
    encode_word(l, std::bit_cast<std::uint32_t>(f), regs);
    return f;
  }
  // Two's complement bit pattern of the (clamped) value, low 32 bits.
  encode_word(l, static_cast<std::uint32_t>(static_cast<std::uint64_t>(static_cast<std::int64_t>(c)) & 0xFFFF'FFFFu), regs);
  return c;
}

IoStatus io_status_from_errno(int err) noexcept {
  switch (err) {
    case 0: return IoStatus::kOk;
    case ETIMEDOUT:
    case EAGAIN:
    case EINTR: return IoStatus::kTimeout;  // no complete reply in time
    case EMBBADCRC: return IoStatus::kCrcError;
    case ECONNRESET:
    case EPIPE:
    case ECONNREFUSED:
    case ECONNABORTED:
    case EBADF:
    case ENOTCONN:
    case ENOTSOCK:
    case EIO:
    case ENXIO:
    case ENODEV:
    case ENETDOWN:
    case ENETUNREACH:
    case EHOSTUNREACH:
    case EHOSTDOWN:
    case ESHUTDOWN: return IoStatus::kDisconnected;
    default: return IoStatus::kProtocolError;  // EMBBADDATA, EMBBADEXC, EMBMDATA, EMBBADSLAVE, EMBX*, …
  }
}

const char* exception_name(int code) noexcept {
  switch (code) {
    case 0x01: return "illegal function";
    case 0x02: return "illegal data address";
    case 0x03: return "illegal data value";
    case 0x04: return "server device failure";
    case 0x05: return "acknowledge";
    case 0x06: return "server device busy";
    case 0x08: return "memory parity error";
    case 0x0A: return "gateway path unavailable";
    case 0x0B: return "gateway target device failed to respond";
    default: return "unknown exception";
  }
}

std::vector<RegisterBlock> plan_blocks(std::vector<RegisterSpan> spans, int max_registers) {
  std::sort(spans.begin(), spans.end(), [](const RegisterSpan& a, const RegisterSpan& b) {
    return a.table != b.table ? a.table < b.table : a.address < b.address;
  });
  std::vector<RegisterBlock> blocks;
  int offset = 0;
  for (const RegisterSpan& s : spans) {
    if (s.count == 0) continue;
    if (!blocks.empty()) {
      RegisterBlock& b = blocks.back();
      const int end = b.address + b.count;
      const int new_end = std::max(end, s.address + s.count);
      if (b.table == s.table && s.address <= end && new_end - b.address <= max_registers) {
        offset += new_end - end;
        b.count = static_cast<std::uint16_t>(new_end - b.address);
        continue;
      }
    }
    blocks.push_back({s.table, s.address, s.count, static_cast<std::uint16_t>(offset)});
    offset += s.count;
  }
  return blocks;
}

}  // namespace modbus

}  // namespace lancet::device
