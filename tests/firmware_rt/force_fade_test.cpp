#include "haptics/force_fade.hpp"

#include <gtest/gtest.h>

namespace lancet::haptics {
namespace {

TEST(ForceFade, RampsInAndOutAtTheConfiguredRate) {
  ForceFadeParams p;
  p.fade_ns = 100'000'000;  // 100 ms
  const std::int64_t dt = 1'000'000;
  ForceFade f;
  EXPECT_EQ(f.scale(), 0.0);  // starts faded out
  int ticks = 0;
  while (f.update(true, dt, p) < 1.0) ++ticks;
  EXPECT_EQ(ticks + 1, 100);
  // Lost: exactly zero after fade_ns, and never negative.
  ticks = 0;
  while (f.update(false, dt, p) > 0.0) ++ticks;
  EXPECT_EQ(ticks + 1, 100);
  EXPECT_EQ(f.update(false, dt, p), 0.0);
}

TEST(ForceFade, ZeroFadeTimeSwitchesAtOnce) {
  ForceFadeParams p;
  p.fade_ns = 0;
  ForceFade f;
  EXPECT_EQ(f.update(true, 1'000'000, p), 1.0);
  EXPECT_EQ(f.update(false, 1'000'000, p), 0.0);
}

}  // namespace
}  // namespace lancet::haptics
