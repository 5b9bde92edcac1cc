// The config schema reader on its own: each getter on a good value, a wrong type, a value out of
// range and a missing key; unknown keys with their "did you mean"; the error text with
// file:line:column and the field path; the value describers.

#include "config/schema.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace lancet::config {
namespace {

// Parses `text` as t.toml and reads its root with `read`; returns the errors, sorted.
std::vector<ConfigError> read(const std::string& text, const std::function<void(Section&)>& fn) {
  Sink sink{"t.toml", {}};
  const auto root = parse_toml(text, sink);
  if (root) {
    Section top(sink, *root, "");
    fn(top);
  }
  sort_errors(sink.errors);
  return sink.errors;
}

std::string report(const std::vector<ConfigError>& errors) { return format_errors(errors); }

// --- errors and their text -------------------------------------------------------------------

TEST(ConfigSchema, AnErrorNamesFileLineColumnFieldExpectedAndFound) {
  const auto errors = read("a = 1\nb = \"x\"\n", [](Section& s) {
    (void)s.integer("a", kReq, 0, 10);
    (void)s.integer("b", kReq, 0, 10);
  });
  ASSERT_EQ(errors.size(), 1u) << report(errors);
  const ConfigError& e = errors[0];
  EXPECT_EQ(e.file, "t.toml");
  EXPECT_EQ(e.line, 2);
  EXPECT_EQ(e.column, 5);
  EXPECT_EQ(e.field, "b");
  EXPECT_EQ(e.expected, "an integer in 0..10");
  EXPECT_EQ(e.found, "string \"x\"");
  EXPECT_EQ(report(errors), "t.toml:2:5: b: expected an integer in 0..10, found string \"x\"\n");
}

TEST(ConfigSchema, ErrorsAreReportedInFileOrderWhateverOrderTheyWereFound) {
  const auto errors = read("a = \"x\"\nb = \"y\"\n", [](Section& s) {
    (void)s.integer("b", kReq, 0, 1);
    (void)s.integer("a", kReq, 0, 1);
  });
  ASSERT_EQ(errors.size(), 2u);
  EXPECT_EQ(errors[0].field, "a");
  EXPECT_EQ(errors[1].field, "b");
}

TEST(ConfigSchema, AFileWideErrorHasNoLineAndASyntaxErrorNoField) {
  ConfigError whole;
  whole.file = "gone.toml";
  whole.message = "cannot open: No such file or directory";
  EXPECT_EQ(format_errors({whole}), "gone.toml: cannot open: No such file or directory\n");

  Sink sink{"t.toml", {}};
  EXPECT_FALSE(parse_toml("a = 1\nb = = 2\n", sink).has_value());
  ASSERT_EQ(sink.errors.size(), 1u);
  EXPECT_EQ(sink.errors[0].line, 2) << format_errors(sink.errors);
  EXPECT_TRUE(sink.errors[0].field.empty());
  EXPECT_EQ(format_errors(sink.errors).rfind("t.toml:2:5: TOML syntax error: ", 0), 0u) << format_errors(sink.errors);
  EXPECT_NE(sink.errors[0].message.find("TOML syntax error: "), std::string::npos);
  EXPECT_EQ(format_errors({}), "");
}

TEST(ConfigSchema, AMissingRequiredKeyIsReportedAtItsTableAndAnOptionalOneIsNot) {
  const auto errors = read("x = 1\n[t]\nother = 2\n", [](Section& top) {
    const toml::table* t = top.table("t", kReq);
    ASSERT_NE(t, nullptr);
    Section s(top.sink(), *t, "t");
    EXPECT_FALSE(s.number("need", kReq, kAny));
    EXPECT_FALSE(s.number("may", kOpt, kAny));
    (void)s.integer("other", kReq, 0, 5);
    s.finish();
    (void)top.integer("x", kReq, 0, 5);
  });
  ASSERT_EQ(errors.size(), 1u) << report(errors);
  EXPECT_EQ(report(errors), "t.toml:2:1: t.need: required key is missing; expected a finite number\n");
  EXPECT_EQ(errors[0].found, "nothing");
}

// --- getters --------------------------------------------------------------------------------

TEST(ConfigSchema, IntegerChecksTypeAndRangeAndShowsHexWhenAsked) {
  std::optional<std::int64_t> a, b, c, d;
  const auto errors = read("a = 7\nb = 11\nc = 7.0\nd = 0x12090\ne = 2\n", [&](Section& s) {
    a = s.integer("a", kReq, 0, 10);
    b = s.integer("b", kReq, 0, 10);
    c = s.integer("c", kReq, 0, 10);
    d = s.integer("d", kReq, 0, 0xFFFF, true);
    (void)s.integer("e", kReq, 1, 1);
  });
  EXPECT_EQ(a, 7);
  EXPECT_FALSE(b || c || d);
  ASSERT_EQ(errors.size(), 4u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected an integer in 0..10, found integer 11");
  EXPECT_EQ(errors[1].message, "expected an integer in 0..10, found float 7");
  EXPECT_EQ(errors[2].message, "expected an integer in 0x0000..0xFFFF, found integer 0x12090");
  EXPECT_EQ(errors[3].message, "expected the integer 1, found integer 2");
}

TEST(ConfigSchema, IntegerInAcceptsOnlyTheListedValues) {
  const std::int64_t allowed[] = {-1, 1};
  std::optional<std::int64_t> a;
  const auto errors = read("a = -1\nb = 0\n", [&](Section& s) {
    a = s.integer_in("a", kReq, allowed);
    EXPECT_FALSE(s.integer_in("b", kReq, allowed));
    EXPECT_FALSE(s.integer_in("c", kReq, allowed));
  });
  EXPECT_EQ(a, -1);
  ASSERT_EQ(errors.size(), 2u) << report(errors);
  EXPECT_EQ(errors[0].message, "required key is missing; expected one of -1, 1");
  EXPECT_EQ(errors[1].message, "expected one of -1, 1, found integer 0");
}

TEST(ConfigSchema, NumberTakesIntegersAndFloatsWithinItsRangeAndNeverNanOrInf) {
  std::optional<double> a, b;
  const auto errors = read("a = 3\nb = 2.5\nc = 0.0\nd = nan\ne = inf\nf = 11\ng = -1\nh = true\n", [&](Section& s) {
    a = s.number("a", kReq, kPositive);
    b = s.number("b", kReq, positive_up_to(10));
    (void)s.number("c", kReq, positive_up_to(10));
    (void)s.number("d", kReq, kAny);
    (void)s.number("e", kReq, kAny);
    (void)s.number("f", kReq, Range{-10, 10});
    (void)s.number("g", kReq, Range{0, 1, false, true});
    (void)s.number("h", kReq, Range{0, std::numeric_limits<double>::infinity()});
  });
  EXPECT_EQ(a, 3.0);
  EXPECT_EQ(b, 2.5);
  ASSERT_EQ(errors.size(), 6u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected a number in (0, 10], found float 0");
  EXPECT_EQ(errors[1].message, "expected a finite number, found float nan");
  EXPECT_EQ(errors[2].message, "expected a finite number, found float inf");
  EXPECT_EQ(errors[3].message, "expected a number in [-10, 10], found integer 11");
  EXPECT_EQ(errors[4].message, "expected a number in [0, 1), found integer -1");
  EXPECT_EQ(errors[5].message, "expected a number >= 0, found boolean true");
  EXPECT_EQ(kPositive.text(), "a number > 0");
  EXPECT_EQ((Range{-std::numeric_limits<double>::infinity(), 5, false, true}.text()), "a number < 5");
}

TEST(ConfigSchema, TextIsANonEmptyStringOfBoundedLength) {
  std::optional<std::string> a;
  const auto errors = read("a = \"arm\"\nb = \"\"\nc = \"toolong\"\nd = 4\n", [&](Section& s) {
    a = s.text("a", kReq, 4);
    EXPECT_FALSE(s.text("b", kReq, 4));
    EXPECT_FALSE(s.text("c", kReq, 4));
    EXPECT_FALSE(s.text("d", kOpt, 4));
  });
  EXPECT_EQ(a, "arm");
  ASSERT_EQ(errors.size(), 3u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected a non-empty string of at most 4 characters, found string \"\"");
  EXPECT_EQ(errors[1].found, "string \"toolong\"");
  EXPECT_EQ(errors[2].found, "integer 4");
}

TEST(ConfigSchema, BooleanIsTrueOrFalse) {
  std::optional<bool> a;
  const auto errors = read("a = true\nb = 1\n", [&](Section& s) {
    a = s.boolean("a", kReq);
    EXPECT_FALSE(s.boolean("b", kReq));
  });
  EXPECT_EQ(a, true);
  ASSERT_EQ(errors.size(), 1u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected true or false, found integer 1");
}

enum class Colour { kRed, kGreen };

TEST(ConfigSchema, ChoiceNamesTheOptionsAndTheNearestOneForATypo) {
  std::optional<Colour> a;
  const auto errors = read("a = \"green\"\nb = \"gren\"\nc = \"blue\"\nd = 1\n", [&](Section& s) {
    const std::initializer_list<Choice<Colour>> colours{{"red", Colour::kRed}, {"green", Colour::kGreen}};
    a = s.choice<Colour>("a", kReq, colours);
    EXPECT_FALSE(s.choice<Colour>("b", kReq, colours));
    EXPECT_FALSE(s.choice<Colour>("c", kReq, colours));
    EXPECT_FALSE(s.choice<Colour>("d", kReq, colours));
  });
  EXPECT_EQ(a, Colour::kGreen);
  ASSERT_EQ(errors.size(), 3u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected one of \"red\", \"green\", found string \"gren\" (did you mean \"green\"?)");
  EXPECT_EQ(errors[1].message, "expected one of \"red\", \"green\", found string \"blue\"");
  EXPECT_EQ(errors[2].message, "expected one of \"red\", \"green\", found integer 1");
}

TEST(ConfigSchema, Vec3IsThreeNumbersScaledIntoSi) {
  std::optional<Vec3> a;
  const auto errors = read("a = [1, 2.5, -3]\nb = [1, 2]\nc = [1, true, 3]\n", [&](Section& s) {
    a = s.vec3("a", kReq, 1e-3);
    EXPECT_FALSE(s.vec3("b", kReq, 1));
    EXPECT_FALSE(s.vec3("c", kReq, 1));
  });
  ASSERT_TRUE(a);
  EXPECT_DOUBLE_EQ(a->x, 1e-3);
  EXPECT_DOUBLE_EQ(a->y, 2.5e-3);
  EXPECT_DOUBLE_EQ(a->z, -3e-3);
  ASSERT_EQ(errors.size(), 2u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected an array of 3 numbers [x, y, z], found array of 2");
  EXPECT_EQ(errors[1].field, "c[1]");
  EXPECT_EQ(errors[1].column, 9);
}

TEST(ConfigSchema, TablesAndArraysCheckTheirShape) {
  const auto errors = read("t = 1\na = [1, 2, 3]\nb = [1]\n[[list]]\nk = 1\n[[list]]\n", [&](Section& s) {
    EXPECT_EQ(s.table("t", kReq), nullptr);
    EXPECT_NE(s.array("a", kReq, 1, 3, "an array of 1..3 things"), nullptr);
    EXPECT_EQ(s.array("b", kReq, 2, 3, "an array of 2..3 things"), nullptr);
    const auto list = s.tables("list", kReq, 1, 4);
    ASSERT_TRUE(list);
    EXPECT_EQ(list->size(), 2u);
    EXPECT_FALSE(s.tables("none", kOpt, 1, 4));
    EXPECT_FALSE(s.tables("a", kReq, 1, 2));
  });
  ASSERT_EQ(errors.size(), 3u) << report(errors);
  EXPECT_EQ(errors[0].message, "expected a table [t], found integer 1");
  EXPECT_EQ(errors[1].message, "expected an array of 1..2 tables [[a]], found array of 3");
  EXPECT_EQ(errors[2].message, "expected an array of 2..3 things, found array of 1");
}

TEST(ConfigSchema, ArrayOfTablesKeepsFileIndicesForElementsThatAreNotTables) {
  const auto errors = read("list = [{ k = 1 }, 2, { k = 3 }]\n", [&](Section& s) {
    const auto list = s.tables("list", kReq, 1, 4);
    ASSERT_TRUE(list);
    ASSERT_EQ(list->size(), 3u);
    EXPECT_NE((*list)[0], nullptr);
    EXPECT_EQ((*list)[1], nullptr);
    EXPECT_NE((*list)[2], nullptr);
  });
  ASSERT_EQ(errors.size(), 1u) << report(errors);
  EXPECT_EQ(report(errors), "t.toml:1:20: list[1]: expected a table, found integer 2\n");
}

TEST(ConfigSchema, NestedSectionsNameTheirFieldsByDottedPath) {
  const auto errors = read("[a.b]\nc = \"x\"\n", [&](Section& top) {
    const toml::table* a = top.table("a", kReq);
    ASSERT_NE(a, nullptr);
    Section sa(top.sink(), *a, "a");
    const toml::table* b = sa.table("b", kReq);
    ASSERT_NE(b, nullptr);
    Section sb(top.sink(), *b, sa.field("b"));
    (void)sb.integer("c", kReq, 0, 1);
    EXPECT_EQ(sb.field("d"), "a.b.d");
  });
  ASSERT_EQ(errors.size(), 1u) << report(errors);
  EXPECT_EQ(errors[0].field, "a.b.c");
}

// --- unknown keys, forbidden keys ---------------------------------------------------------------

TEST(ConfigSchema, FinishReportsUnknownKeysAtTheKeyWithTheKnownOnesAndTheNearest) {
  const auto errors = read("name = \"a\"\nnmae = \"b\"\n  colour = 1\n", [&](Section& s) {
    (void)s.text("name", kReq);
    (void)s.number("size", kOpt, kAny);
    s.finish();
  });
  ASSERT_EQ(errors.size(), 2u) << report(errors);
  EXPECT_EQ(report(errors),
            "t.toml:2:1: nmae: unknown key \"nmae\" (did you mean \"name\"?); known keys here: name, size\n"
            "t.toml:3:3: colour: unknown key \"colour\"; known keys here: name, size\n");
  EXPECT_EQ(errors[0].expected, "one of: name, size");
  EXPECT_EQ(errors[0].found, "unknown key \"nmae\"");
}

TEST(ConfigSchema, ATableWithNoSchemaKeysSaysSo) {
  const auto errors = read("x = 1\n", [&](Section& s) { s.finish(); });
  ASSERT_EQ(errors.size(), 1u);
  EXPECT_EQ(errors[0].message, "unknown key \"x\"; this table takes no keys");
  EXPECT_EQ(errors[0].expected, "no keys");
}

TEST(ConfigSchema, SkippedKeysAreKnownAndForbiddenKeysAreReported) {
  const auto errors = read("a = 1\nb = 2\nc = 3\n", [&](Section& s) {
    s.skip({"a"});
    s.forbid("b", "kind = \"other\"");
    s.forbid("absent", "kind = \"other\"");
    s.finish();
  });
  ASSERT_EQ(errors.size(), 2u) << report(errors);
  EXPECT_EQ(report(errors),
            "t.toml:2:5: b: expected no b (it is only for kind = \"other\"), found integer 2\n"
            "t.toml:3:1: c: unknown key \"c\"; known keys here: a, b, absent\n");
}

TEST(ConfigSchema, WhereIsTheValueOrElseTheTable) {
  (void)read("[t]\nk = 1\n", [&](Section& top) {
    const toml::table* t = top.table("t", kReq);
    ASSERT_NE(t, nullptr);
    Section s(top.sink(), *t, "t");
    EXPECT_EQ(s.where("k").begin.line, 2u);
    EXPECT_EQ(s.where("absent").begin.line, 1u);
    EXPECT_TRUE(s.has("k"));
    EXPECT_FALSE(s.has("absent"));
  });
}

TEST(ConfigSchema, UniqueValuesReportsARepeatAtTheLaterEntryOncePerEarlierOne) {
  const auto errors = read("[[item]]\nname = \"a\"\n[[item]]\nname = \"b\"\n[[item]]\nname = \"a\"\n[[item]]\nname = \"a\"\n",
                           [&](Section& top) {
                             const auto items = top.tables("item", kReq, 1, 8);
                             ASSERT_TRUE(items);
                             UniqueValues<std::string> names("item", "name");
                             for (std::size_t i = 0; i < items->size(); ++i) {
                               Section s(top.sink(), *(*items)[i], indexed("item", i));
                               if (auto v = s.text("name", kReq)) names.check(s, "name", *v, i);
                               s.finish();
                             }
                           });
  ASSERT_EQ(errors.size(), 3u) << report(errors);
  EXPECT_EQ(report(errors),
            "t.toml:6:8: item[2].name: expected a name not used by item[0], found string \"a\"\n"
            "t.toml:8:8: item[3].name: expected a name not used by item[0], found string \"a\"\n"
            "t.toml:8:8: item[3].name: expected a name not used by item[2], found string \"a\"\n");
}

// --- describers ------------------------------------------------------------------------------

TEST(ConfigDescribe, QuotedEscapesAndCuts) {
  EXPECT_EQ(quote("a\"b\\c"), "\"a\\\"b\\\\c\"");
  EXPECT_EQ(quote(std::string("x\ny\x7f", 4)), "\"x\\x0Ay\\x7F\"");
  EXPECT_EQ(quote(std::string(60, 'z')), "\"" + std::string(48, 'z') + "...\"");
}

TEST(ConfigDescribe, NumbersAndRanges) {
  EXPECT_EQ(num(2.5), "2.5");
  EXPECT_EQ(num(std::int64_t{-3}), "-3");
  EXPECT_EQ(num(std::int64_t{0x81}, true), "0x0081");
  EXPECT_EQ(num(std::int64_t{-1}, true), "-1");
  EXPECT_EQ(int_range_text(1, 127), "an integer in 1..127");
  EXPECT_EQ(int_range_text(0x81, 0x8F, true), "an integer in 0x0081..0x008F");
  EXPECT_EQ(int_range_text(1, 1), "the integer 1");
  EXPECT_EQ(indexed("joints", 2), "joints[2]");
}

TEST(ConfigDescribe, DescribeNamesEachNodeType) {
  Sink sink{"t.toml", {}};
  const auto root = parse_toml("s = \"x\"\ni = 17\nf = 0.5\nb = false\na = [1, 2]\nt = {}\nd = 2024-01-02\n", sink);
  ASSERT_TRUE(root);
  EXPECT_EQ(describe(*root->get("s")), "string \"x\"");
  EXPECT_EQ(describe(*root->get("i")), "integer 17");
  EXPECT_EQ(describe(*root->get("i"), true), "integer 0x0011");
  EXPECT_EQ(describe(*root->get("f")), "float 0.5");
  EXPECT_EQ(describe(*root->get("b")), "boolean false");
  EXPECT_EQ(describe(*root->get("a")), "array of 2");
  EXPECT_EQ(describe(*root->get("t")), "table");
  EXPECT_EQ(describe(*root->get("d")), "date");
}

TEST(ConfigDescribe, EditDistanceCountsASwapAsOneEditAndNearestNeedsAPlausibleTypo) {
  EXPECT_EQ(edit_distance("name", "name"), 0u);
  EXPECT_EQ(edit_distance("nmae", "name"), 1u);
  EXPECT_EQ(edit_distance("gear_ration", "gear_ratio"), 1u);
  EXPECT_EQ(edit_distance("", "abc"), 3u);
  const std::vector<std::string> keys{"name", "gear_ratio", "id"};
  EXPECT_EQ(nearest("gear_ration", keys), "gear_ratio");
  EXPECT_EQ(nearest("nmae", keys), "name");
  EXPECT_EQ(nearest("ix", keys), "") << "one edit of a two-letter key is too far";
  EXPECT_EQ(nearest("colour", keys), "");
}

}  // namespace
}  // namespace lancet::config
