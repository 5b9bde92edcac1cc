#pragma once
// A 64-bit hash that mixes words in, for the state hashes that must agree bit for bit between
// two runs (the servo's in lancet-rt, the scene's in lancet-viz, both checked by a replay).

#include <bit>
#include <cstdint>

#include "lancet/shared_model/geometry.hpp"

namespace lancet {

/// A 64-bit hash built word by word (a multiply-xorshift mix, as in splitmix64). Doubles and
/// floats go in by their bits, so equal hashes mean bit-identical values. Real-time safe.
class WordHasher {
 public:
  explicit constexpr WordHasher(std::uint64_t seed = 0x9e3779b97f4a7c15ull) noexcept : h_(seed) {}
  constexpr void word(std::uint64_t w) noexcept {
    h_ ^= w + 0x9e3779b97f4a7c15ull + (h_ << 6) + (h_ >> 2);
    h_ ^= h_ >> 31;
    h_ *= 0xbf58476d1ce4e5b9ull;
  }
  void f(double x) noexcept { word(std::bit_cast<std::uint64_t>(x)); }
  void f(float x) noexcept { word(std::bit_cast<std::uint32_t>(x)); }
  void v(Vec3 p) noexcept { f(p.x), f(p.y), f(p.z); }
  constexpr void b(bool x) noexcept { word(x ? 1 : 0); }
  /// The hash, never 0 (0 means "no hash" where hashes are stored).
  [[nodiscard]] constexpr std::uint64_t value() const noexcept { return h_ != 0 ? h_ : 1; }

 private:
  std::uint64_t h_;
};

}  // namespace lancet
