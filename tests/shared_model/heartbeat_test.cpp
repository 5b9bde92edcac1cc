// Heartbeat, single thread: beats, freshness against a timeout, clean stop.

#include "lancet/shared_model/heartbeat.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <type_traits>

namespace lancet {
namespace {

static_assert(std::is_standard_layout_v<Heartbeat>);
static_assert(std::is_trivially_destructible_v<Heartbeat>);

TEST(Heartbeat, NeverBeatenIsNotFresh) {
  Heartbeat hb;
  EXPECT_EQ(hb.last_ns(), 0);
  EXPECT_EQ(hb.count(), 0u);
  EXPECT_EQ(hb.pid(), 0);
  EXPECT_FALSE(hb.fresh(0, 1'000'000));
  EXPECT_FALSE(hb.fresh(1'000'000, 1'000'000'000));
}

TEST(Heartbeat, FreshUntilTheTimeoutPasses) {
  Heartbeat hb;
  hb.beat(5'000'000, 4321);
  EXPECT_EQ(hb.last_ns(), 5'000'000);
  EXPECT_EQ(hb.pid(), 4321);
  EXPECT_EQ(hb.count(), 1u);
  EXPECT_TRUE(hb.fresh(5'000'000, 100));
  EXPECT_TRUE(hb.fresh(5'000'100, 100)) << "exactly timeout_ns old is still fresh";
  EXPECT_FALSE(hb.fresh(5'000'101, 100));
  hb.beat(6'000'000, 4321);
  EXPECT_TRUE(hb.fresh(6'000'050, 100));
  EXPECT_EQ(hb.count(), 2u);
}

TEST(Heartbeat, StopMakesThePeerGoneAtOnce) {
  Heartbeat hb;
  hb.beat(1'000, 1);
  hb.stop();
  EXPECT_EQ(hb.last_ns(), 0);
  EXPECT_FALSE(hb.fresh(1'000, 1'000'000));
  EXPECT_EQ(hb.count(), 1u) << "stop does not rewrite the beat count";
}

TEST(Heartbeat, ABeatFromTheFutureIsNotFresh) {
  Heartbeat hb;
  const std::int64_t now = 10'000'000'000;
  hb.beat(now + Heartbeat::kFutureSlackNs / 2, 1);
  EXPECT_TRUE(hb.fresh(now, 1'000'000)) << "a peer that stamped a moment later is fine";
  hb.beat(now + 3'600'000'000'000, 1);  // an hour ahead: only garbage gets there
  EXPECT_FALSE(hb.fresh(now, 1'000'000)) << "would otherwise look alive for an hour";
}

}  // namespace
}  // namespace lancet
