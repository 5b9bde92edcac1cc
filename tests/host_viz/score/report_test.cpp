// The report: the HTML page has its plots, its metric names and its verdict, escapes what comes
// from files, stays small for a long recording and is the same for the same input; the JSON is
// valid (checked by a small parser here), has stable keys and writes null for what was not measured.

#include "score/report.hpp"

#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <string>
#include <string_view>
#include <vector>

#include "synthetic_recording.hpp"

namespace lancet::score {

namespace test = record::test;
namespace {

using test::make_recording;
using test::parse_or_fail;

std::size_t count(std::string_view text, std::string_view needle) {
  std::size_t n = 0;
  for (std::size_t at = text.find(needle); at != std::string_view::npos; at = text.find(needle, at + needle.size())) ++n;
  return n;
}

// ---- a minimal JSON checker (RFC 8259 grammar; no numbers other than finite ones exist in it) --

class JsonChecker {
 public:
  explicit JsonChecker(std::string_view s) : s_(s) {}
  /// True when the whole text is one JSON value; otherwise `error` says where.
  bool check(std::string& error) {
    ws();
    const bool ok = value() && (ws(), i_ == s_.size());
    if (!ok) error = "JSON error near offset " + std::to_string(i_) + ": \"" + std::string(s_.substr(i_, 40)) + "\"";
    return ok;
  }

 private:
  std::string_view s_;
  std::size_t i_ = 0;
  int depth_ = 0;

  void ws() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\n' || s_[i_] == '\r' || s_[i_] == '\t')) ++i_;
  }
  bool lit(std::string_view w) {
    if (s_.substr(i_, w.size()) != w) return false;
    i_ += w.size();
    return true;
  }
  bool value() {
    if (i_ >= s_.size() || ++depth_ > 64) return false;
    bool ok = false;
    switch (s_[i_]) {
      case '{': ok = object(); break;
      case '[': ok = array(); break;
      case '"': ok = string(); break;
      case 't': ok = lit("true"); break;
      case 'f': ok = lit("false"); break;
      case 'n': ok = lit("null"); break;
      default: ok = number();
    }
    --depth_;
    return ok;
  }
  bool object() {
    ++i_;
    ws();
    if (i_ < s_.size() && s_[i_] == '}') return ++i_, true;
    while (true) {
      ws();
      if (i_ >= s_.size() || s_[i_] != '"' || !string()) return false;
      ws();
      if (!lit(":")) return false;
      ws();
      if (!value()) return false;
      ws();
      if (lit("}")) return true;
      if (!lit(",")) return false;
    }
  }
  bool array() {
    ++i_;
    ws();
    if (i_ < s_.size() && s_[i_] == ']') return ++i_, true;
    while (true) {
      ws();
      if (!value()) return false;
      ws();
      if (lit("]")) return true;
      if (!lit(",")) return false;
    }
  }
  bool string() {
    ++i_;
    while (i_ < s_.size()) {
      const auto c = static_cast<unsigned char>(s_[i_]);
      if (c == '"') return ++i_, true;
      if (c < 0x20) return false;
      if (c == '\\') {
        ++i_;
        if (i_ >= s_.size()) return false;
        const char e = s_[i_];
        if (e == 'u') {
          for (int k = 1; k <= 4; ++k) {
            if (i_ + k >= s_.size() || !std::isxdigit(static_cast<unsigned char>(s_[i_ + k]))) return false;
          }
          i_ += 4;
        } else if (std::string_view("\"\\/bfnrt").find(e) == std::string_view::npos) {
          return false;
        }
      }
      ++i_;
    }
    return false;
  }
  bool number() {
    const std::size_t start = i_;
    if (i_ < s_.size() && s_[i_] == '-') ++i_;
    if (i_ >= s_.size() || !std::isdigit(static_cast<unsigned char>(s_[i_]))) return false;
    if (s_[i_] == '0') {
      ++i_;
    } else {
      while (i_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[i_]))) ++i_;
    }
    if (i_ < s_.size() && s_[i_] == '.') {
      ++i_;
      if (i_ >= s_.size() || !std::isdigit(static_cast<unsigned char>(s_[i_]))) return false;
      while (i_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[i_]))) ++i_;
    }
    if (i_ < s_.size() && (s_[i_] == 'e' || s_[i_] == 'E')) {
      ++i_;
      if (i_ < s_.size() && (s_[i_] == '+' || s_[i_] == '-')) ++i_;
      if (i_ >= s_.size() || !std::isdigit(static_cast<unsigned char>(s_[i_]))) return false;
      while (i_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[i_]))) ++i_;
    }
    return i_ > start;
  }
};

::testing::AssertionResult valid_json(const std::string& text) {
  std::string error;
  if (JsonChecker(text).check(error)) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << error;
}

TEST(JsonChecker, CatchesBrokenJson) {  // the checker itself can fail
  EXPECT_TRUE(valid_json(R"({"a": [1, -2.5e3, true, null, "x\u00e9\n"], "b": {}})"));
  for (const char* bad : {"{\"a\": nan}", "{\"a\": 1,}", "{\"a\" 1}", "[1 2]", "\"\x01\"", "{\"a\": inf}", "01", "{} x"}) {
    EXPECT_FALSE(valid_json(bad)) << bad;
  }
}

// ---- an attempt to report ----------------------------------------------------------------------

// `seconds` of a scalpel moving along the incision line with a force ramp, cut progress every 0.5 mm.
Recording attempt(double seconds) {
  const auto n = static_cast<std::size_t>(seconds * 1000) + 1;
  Recording rec = make_recording(n, [&](std::size_t i, double t, ToolSample& s) {
    const double u = t / seconds;
    s.tool.position = Vec3{-0.015 + 0.03 * u, -0.012 + 0.001 * std::sin(20 * u), -0.003};
    s.stage = u < 0.1 || u > 0.9 ? Stage::kFree : i % 1000 < 50 ? Stage::kRupture : Stage::kCutting;
    s.force = Vec3{0, 0, 4 * std::sin(std::numbers::pi * u) + 0.3 * std::sin(50 * t)};
  });
  test::mark_cut_progress(rec);
  rec.frames.resize(3);
  rec.frames.back().damaged = 0b10;
  rec.frames.back().blood_lost_ml = 0.7;
  rec.scenario_toml = test::incision_toml("[score]\nforce_limit_n = 3.5\n[score.bands]\ntask_time_s = { mean = 4, sd = 1 }\n"
                                          "incision_coverage_pct = { mean = 95, sd = 2 }\n");
  rec.scenario_name = "synthetic-incision";
  return rec;
}

ReportInput input(const std::string& file, const Recording& rec) {
  const scenario::Scenario s = parse_or_fail(rec.scenario_toml);
  return ReportInput{file, &rec, compute_metrics(rec, &s)};
}

TEST(ReportHtml, HasThePlotsTheMetricsAndTheVerdict) {
  const Recording rec = attempt(5);
  const std::string page = report_html({input("attempt1.h5", rec)});
  EXPECT_EQ(page.rfind("<!DOCTYPE html>", 0), 0u);
  EXPECT_NE(page.find("<title>Lancet report: synthetic-incision, 2025-01-02</title>"), std::string::npos);
  EXPECT_EQ(count(page, "<svg"), 2u);  // the path and the force
  EXPECT_EQ(count(page, "</svg>"), 2u);
  EXPECT_GE(count(page, "<polyline"), 3u);
  EXPECT_NE(page.find("class=\"limit\""), std::string::npos);  // the force limit line
  EXPECT_NE(page.find("limit 3.5 N"), std::string::npos);
  EXPECT_NE(page.find("class=\"task\""), std::string::npos);  // the planned incision line
  for (const Metric& m : input("x", rec).metrics.metrics) EXPECT_NE(page.find(m.name), std::string::npos) << m.name;
  // Time 4 s passes <= 6 s; the cut covers only the middle 80 % of the line: coverage fails >= 91 %.
  EXPECT_NE(page.find("Not yet proficient: 1 of 2 banded metrics outside their bands (incision_coverage_pct)"), std::string::npos);
  EXPECT_NE(page.find("nerve &lt;b&gt;"), std::string::npos);     // the damaged structure's name, escaped
  EXPECT_NE(page.find("20 mm/s"), std::string::npos);             // the movement threshold and filter are stated
  EXPECT_NE(page.find("10 Hz"), std::string::npos);
  // Self-contained: nothing to fetch, nothing to run.
  EXPECT_EQ(page.find("<script"), std::string::npos);
  EXPECT_EQ(page.find("src="), std::string::npos);
  EXPECT_EQ(page.find("href="), std::string::npos);
  EXPECT_EQ(page.find("@import"), std::string::npos);
}

TEST(ReportHtml, EscapesFileNamesAndRecordedText) {
  Recording rec = attempt(2);
  rec.scenario_name = "a & b <i>";
  rec.lancet_version = "v1\"><img>";
  const std::string page = report_html({input("<script>alert(1)</script>.h5", rec)});
  EXPECT_EQ(page.find("<script"), std::string::npos);
  EXPECT_NE(page.find("&lt;script&gt;alert(1)&lt;/script&gt;.h5"), std::string::npos);
  EXPECT_NE(page.find("a &amp; b &lt;i&gt;"), std::string::npos);
  EXPECT_EQ(page.find("<img>"), std::string::npos);
  EXPECT_EQ(page.find("<i>"), std::string::npos);
}

TEST(ReportHtml, SixtySecondsStaysSmall) {
  const Recording rec = attempt(60);  // 60 001 ticks
  const std::string page = report_html({input("long.h5", rec)});
  EXPECT_LT(page.size(), 200'000u) << "the plots are downsampled to at most " << kMaxPlotPoints << " points each";
  // No plot draws more than kMaxPlotPoints points (each point is one "x,y").
  std::size_t plots = 0;
  for (std::size_t at = page.find("<svg"); at != std::string::npos; at = page.find("<svg", at + 1)) {
    const std::string_view svg = std::string_view(page).substr(at, page.find("</svg>", at) - at);
    std::size_t points = 0;
    for (std::size_t p = svg.find("points=\""); p != std::string_view::npos; p = svg.find("points=\"", p + 1)) {
      points += count(svg.substr(p, svg.find('"', p + 8) - p), ",");
    }
    EXPECT_LE(points, kMaxPlotPoints);
    EXPECT_GT(points, kMaxPlotPoints / 4);  // ... and not much fewer: the shape survives
    ++plots;
  }
  EXPECT_EQ(plots, 2u);
}

TEST(ReportHtml, SeveralAttemptsGetAComparison) {
  const Recording a = attempt(3), b = attempt(8);
  const std::string page = report_html({input("first.h5", a), input("second.h5", b)});
  EXPECT_NE(page.find("<h2>Comparison</h2>"), std::string::npos);
  EXPECT_NE(page.find("<th>1: first.h5</th><th>2: second.h5</th>"), std::string::npos);
  EXPECT_EQ(count(page, "<section class=\"attempt\">"), 2u);
  EXPECT_EQ(count(page, "<svg"), 4u);
  // Clip paths are named per attempt: ids never repeat.
  EXPECT_EQ(count(page, "id=\"a0-path\""), 1u);
  EXPECT_EQ(count(page, "id=\"a1-path\""), 1u);
  EXPECT_NE(page.find("Attempt 1: first.h5"), std::string::npos);
  // Attempt 1 (window 2.4 s) passes its time band (<= 6 s), attempt 2 (window 6.4 s) does not.
  EXPECT_NE(page.find("<td class=\"num\">\u2264 6 (4 + 2\u00d71)</td><td class=\"pass num\">2.4</td><td class=\"fail num\">6.4</td>"),
            std::string::npos);
}

TEST(ReportHtml, SameInputSamePage) {
  const Recording rec = attempt(4);
  EXPECT_EQ(report_html({input("x.h5", rec)}), report_html({input("x.h5", rec)}));
}

TEST(ReportHtml, NoScenarioAndNoSamples) {
  Recording empty;
  const std::string page = report_html({ReportInput{"empty.h5", &empty, compute_metrics(empty, nullptr)}});
  EXPECT_NE(page.find("Not assessed"), std::string::npos);
  EXPECT_EQ(count(page, "<svg"), 2u);
  EXPECT_EQ(page.find("nan"), std::string::npos);
  EXPECT_EQ(page.find("inf"), std::string::npos);
}

// ---- JSON --------------------------------------------------------------------------------------

TEST(ReportJson, IsValidWithStableKeys) {
  const Recording a = attempt(3), b = attempt(5);
  const std::string json = report_json({input("first.h5", a), input("second.h5", b)});
  ASSERT_TRUE(valid_json(json)) << json.substr(0, 2000);
  for (const char* key : {"\"format\": \"lancet-report\"", "\"version\": 1", "\"attempts\": [", "\"file\": \"first.h5\"",
                          "\"scenario\": \"synthetic-incision\"", "\"task\": \"incision\"", "\"verdict\": ", "\"settings\": {",
                          "\"force_limit_n\": 3.5", "\"movement_speed_mm_s\": 20", "\"damaged\": [\"nerve <b>\"]", "\"metrics\": {",
                          "\"task_time_s\": {\"value\": ", "\"band\": {\"mean\": 4, \"sd\": 1, \"k\": 2, \"limit\": 6}"}) {
    EXPECT_NE(json.find(key), std::string::npos) << key;
  }
  EXPECT_EQ(count(json, "\"incision_coverage_pct\": {"), 2u);
}

TEST(ReportJson, NotMeasuredIsNullAndStringsAreEscaped) {
  Recording rec = make_recording(10, [](std::size_t, double, ToolSample& s) { s.stage = Stage::kFree; });
  rec.scenario_name = "quote\" back\\slash \x01 bad\xff utf8 \xc3\xa9";
  const std::string json = report_json({ReportInput{"tab\there.h5", &rec, compute_metrics(rec, nullptr)}});
  ASSERT_TRUE(valid_json(json)) << json;
  EXPECT_NE(json.find("\"task_time_s\": {\"value\": null"), std::string::npos);
  EXPECT_NE(json.find("\"window_s\": [null, null]"), std::string::npos);
  EXPECT_NE(json.find("\"task\": null"), std::string::npos);
  EXPECT_NE(json.find("quote\\\" back\\\\slash \\u0001 bad\\ufffd utf8 \xc3\xa9"), std::string::npos);
  EXPECT_NE(json.find("tab\\u0009here.h5"), std::string::npos);
  EXPECT_EQ(json.find("nan"), std::string::npos);
  EXPECT_EQ(json.find("inf"), std::string::npos);
  EXPECT_NE(json.find("\"verdict\": \"not_assessed\""), std::string::npos);
}

}  // namespace
}  // namespace lancet::score
