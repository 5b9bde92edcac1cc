// The text helpers every tool writes JSON, XML and numbers with: what each escapes, what it
// replaces, and that no locale or "-0" leaks into a number.

#include <gtest/gtest.h>

#include <clocale>
#include <cmath>
#include <limits>
#include <string>

#include "text/text.hpp"

namespace lancet::text {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

TEST(JsonString, EscapesQuotesBackslashesAndControlBytes) {
  EXPECT_EQ(json_string("a\"b\\c"), "\"a\\\"b\\\\c\"");
  EXPECT_EQ(json_string(std::string("x\ny\x01", 4)), "\"x\\u000ay\\u0001\"");
  EXPECT_EQ(json_string("\x7f"), "\"\\u007f\"");
}

TEST(JsonString, KeepsWellFormedUtf8AndReplacesTheRest) {
  EXPECT_EQ(json_string("µs \xE2\x86\x92"), "\"µs \xE2\x86\x92\"");
  EXPECT_EQ(json_string("a\xFF" "b"), "\"a\\ufffdb\"");
  EXPECT_EQ(json_string("\xE2\x86"), "\"\\ufffd\\ufffd\"");  // cut short
  EXPECT_EQ(json_string("\xE0\x80\xAF"), "\"\\ufffd\\ufffd\\ufffd\"");  // an overlong '/'
  EXPECT_EQ(json_string("\xED\xA0\x80"), "\"\\ufffd\\ufffd\\ufffd\"");  // a surrogate
  EXPECT_EQ(json_string("\xC2\x85"), "\"\xC2\x85\"");  // a C1 control is well-formed UTF-8 (XML refuses it)
}

TEST(JsonNumber, NullForWhatJsonCannotHold) {
  EXPECT_EQ(json_number(1.25, 1), "1.2");
  EXPECT_EQ(json_number(std::nan(""), 3), "null");
  EXPECT_EQ(json_number(-kInf), "null");
  EXPECT_EQ(json_number(0.1), "0.1");
  EXPECT_EQ(json_number(123456789.125), "123456789.125");
}

TEST(XmlEscape, EscapesMarkupAndReplacesWhatXmlForbids) {
  EXPECT_EQ(xml_escape("<a href=\"x\">&'</a>"), "&lt;a href=&quot;x&quot;&gt;&amp;&apos;&lt;/a&gt;");
  EXPECT_EQ(xml_escape("bell\x07"), "bell?");
  EXPECT_EQ(xml_escape("\xC0\xAF"), "??");            // an overlong '/'
  EXPECT_EQ(xml_escape("\xED\xA0\x80"), "???");       // a surrogate
  EXPECT_EQ(xml_escape("65 \xC2\xB5s"), "65 \xC2\xB5s");
}

TEST(Fixed, NeverALocaleCommaNorANegativeZero) {
  const char* before = std::setlocale(LC_NUMERIC, nullptr);
  const std::string saved = before != nullptr ? before : "C";
  std::setlocale(LC_NUMERIC, "de_DE.UTF-8");  // where installed, printf would write 12,5
  EXPECT_EQ(fixed(12.5, 1), "12.5");
  std::setlocale(LC_NUMERIC, saved.c_str());
  EXPECT_EQ(fixed(-0.0001, 2), "0.00");
  EXPECT_EQ(fixed(-0.0, 0), "0");
  EXPECT_EQ(fixed(-1.5, 1), "-1.5");
}

TEST(Format, WritesOutputOfAnyLength) {
  EXPECT_EQ(format("%g ms", 2.5), "2.5 ms");
  const std::string long_word(300, 'x');
  EXPECT_EQ(format("[%s]", long_word.c_str()), "[" + long_word + "]");
}

}  // namespace
}  // namespace lancet::text
