// The progression rule: proficient on N attempts, of which M in a row.

#include <gtest/gtest.h>

#include <vector>

#include "records/proficiency.hpp"

namespace lancet::records {
namespace {

Standing run(std::size_t required, std::size_t consecutive, std::vector<int> results) {
  bool buf[64] = {};
  for (std::size_t i = 0; i < results.size(); ++i) buf[i] = results[i] != 0;
  return evaluate(ProficiencyRule{required, consecutive}, std::span<const bool>(buf, results.size()));
}

TEST(Proficiency, NoAttemptsIsNotProficient) {
  const Standing s = run(1, 1, {});
  EXPECT_FALSE(s.proficient);
  EXPECT_EQ(s.attempts, 0u);
  EXPECT_EQ(s.proficient_at, 0u);
}

TEST(Proficiency, OnePassMeetsOneOfOne) {
  const Standing s = run(1, 1, {0, 0, 1});
  EXPECT_TRUE(s.proficient);
  EXPECT_EQ(s.proficient_at, 3u);
  EXPECT_EQ(s.passes, 1u);
}

TEST(Proficiency, AllInARowNeedsAnUnbrokenRun) {
  EXPECT_FALSE(run(3, 3, {1, 1, 0, 1, 1}).proficient);
  const Standing s = run(3, 3, {1, 1, 0, 1, 1, 1});
  EXPECT_TRUE(s.proficient);
  EXPECT_EQ(s.proficient_at, 6u);
  EXPECT_EQ(s.longest_run, 3u);
}

TEST(Proficiency, AnyNOfThemWhenOneInARow) {
  const Standing s = run(3, 1, {1, 0, 1, 0, 0, 1});
  EXPECT_TRUE(s.proficient);
  EXPECT_EQ(s.proficient_at, 6u);
  EXPECT_EQ(s.longest_run, 1u);
}

TEST(Proficiency, NOfWhichMConsecutiveNeedsBoth) {
  // Five passes but never two in a row.
  EXPECT_FALSE(run(5, 2, {1, 0, 1, 0, 1, 0, 1, 0, 1}).proficient);
  // Two in a row early, but only four passes in all.
  EXPECT_FALSE(run(5, 2, {1, 1, 0, 1, 0, 1}).proficient);
  // The fifth pass comes later than the run: proficient there.
  const Standing s = run(5, 2, {1, 1, 0, 1, 0, 1, 0, 0, 1});
  EXPECT_TRUE(s.proficient);
  EXPECT_EQ(s.proficient_at, 9u);
  // The run comes after the fifth pass: proficient when the run is complete.
  const Standing t = run(4, 3, {1, 0, 1, 0, 1, 1, 1});
  EXPECT_TRUE(t.proficient);
  EXPECT_EQ(t.proficient_at, 7u);
}

TEST(Proficiency, OnceProficientStaysProficient) {
  const Standing s = run(2, 2, {1, 1, 0, 0, 0});
  EXPECT_TRUE(s.proficient);
  EXPECT_EQ(s.proficient_at, 2u);
  EXPECT_EQ(s.current_run, 0u);
  EXPECT_EQ(s.attempts, 5u);
}

TEST(Proficiency, RuleValidity) {
  EXPECT_TRUE(valid(ProficiencyRule{3, 2}));
  EXPECT_TRUE(valid(ProficiencyRule{1, 1}));
  EXPECT_FALSE(valid(ProficiencyRule{0, 0}));
  EXPECT_FALSE(valid(ProficiencyRule{2, 3}));
  EXPECT_FALSE(valid(ProficiencyRule{2, 0}));
}

}  // namespace
}  // namespace lancet::records
