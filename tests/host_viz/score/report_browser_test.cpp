// The report in a real browser: Debian's chromium renders the page of a synthetic 20 s attempt
// headless and takes a screenshot. Checks: chromium exits 0, the PNG has the window's size, the
// page is not blank (the plots' colours are on it), and the page logged no script error. A page
// that throws shows the log check can fail. Without chromium on PATH the tests are skipped,
// except under CI=true, where that is a failure (as for the shared test volumes).

#include <gtest/gtest.h>
#include <stb/stb_image.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "headless_chromium.hpp"
#include "process.hpp"
#include "score/report.hpp"
#include "shared_data.hpp"
#include "synthetic_recording.hpp"
#include "temp_files.hpp"

namespace lancet::score {

namespace test = record::test;
namespace {

using lancet::test::chromium_or_skip;
using lancet::test::page_errors;
using lancet::test::read_bytes;
using lancet::test::render;
using lancet::test::Render;

constexpr int kWidth = 1200, kHeight = 1600;

std::uint32_t big_endian_u32(const std::string& b, std::size_t at) {
  std::uint32_t v = 0;
  for (std::size_t i = 0; i < 4; ++i) v = v << 8 | static_cast<unsigned char>(b[at + i]);
  return v;
}

// A 20 s attempt: free approach, a cut along the line with cut progress events, free exit.
Recording twenty_seconds() {
  Recording rec = test::make_recording(20'001, [](std::size_t, double t, ToolSample& s) {
    const double u = t / 20;
    s.tool.position = Vec3{-0.02 + 0.04 * u, -0.012 + 0.0015 * std::sin(9 * u), -0.003};
    s.stage = u < 0.15 || u > 0.85 ? Stage::kFree : Stage::kCutting;
    s.force = Vec3{0.4 * std::sin(13 * t), 0, 3.2 * std::sin(std::numbers::pi * u)};
  });
  test::mark_cut_progress(rec);
  rec.frames.resize(2);
  rec.frames.back().blood_lost_ml = 0.9;
  rec.scenario_toml = test::incision_toml("[score.bands]\ntask_time_s = { mean = 12, sd = 3 }\nincision_coverage_pct = { mean = 95, sd = 2 }\n");
  rec.scenario_name = "synthetic-incision";
  return rec;
}

class ReportBrowser : public lancet::test::TempDirTest {};

TEST_F(ReportBrowser, ChromiumRendersTheReport) {
  const std::string chromium = chromium_or_skip();
  if (chromium.empty()) return;
  const Recording rec = twenty_seconds();
  const scenario::Scenario s = test::parse_or_fail(rec.scenario_toml);
  const std::string page = report_html({ReportInput{"twenty_seconds.h5", &rec, compute_metrics(rec, &s)}});
  const std::string html = write("report.html", page);
  const std::string png = (dir_ / "report.png").string();

  const Render r = render(chromium, dir_, html, png, kWidth, kHeight);
  ASSERT_TRUE(r.exited) << "chromium did not finish within 120 s; its log:\n" << r.log;
  EXPECT_EQ(r.status, 0) << r.log;
  EXPECT_TRUE(page_errors(r.log).empty()) << "the page logged errors:\n" << r.log;

  // The PNG: its signature and IHDR size, then its pixels.
  const std::string bytes = read_bytes(png);
  ASSERT_GT(bytes.size(), 24u) << "no screenshot at " << png << "; chromium's log:\n" << r.log;
  EXPECT_EQ(bytes.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
  EXPECT_EQ(bytes.substr(12, 4), "IHDR");
  EXPECT_EQ(big_endian_u32(bytes, 16), static_cast<std::uint32_t>(kWidth));
  EXPECT_EQ(big_endian_u32(bytes, 20), static_cast<std::uint32_t>(kHeight));

  int w = 0, h = 0, n = 0;
  unsigned char* rgb = stbi_load_from_memory(reinterpret_cast<const unsigned char*>(bytes.data()), static_cast<int>(bytes.size()),
                                             &w, &h, &n, 3);
  ASSERT_NE(rgb, nullptr) << "stb cannot decode the screenshot";
  std::size_t ink = 0, cut = 0, force = 0;
  const auto near = [](const unsigned char* p, int r8, int g8, int b8) {
    return std::abs(p[0] - r8) < 40 && std::abs(p[1] - g8) < 40 && std::abs(p[2] - b8) < 40;
  };
  for (int i = 0; i < w * h; ++i) {
    const unsigned char* p = rgb + 3 * static_cast<std::size_t>(i);
    if (p[0] < 200 || p[1] < 200 || p[2] < 200) ++ink;
    if (near(p, 0xd8, 0x1b, 0x60)) ++cut;    // the cutting stage's colour on the path plot
    if (near(p, 0x1e, 0x88, 0xe5)) ++force;  // the force curve
  }
  stbi_image_free(rgb);
  EXPECT_GT(ink, static_cast<std::size_t>(w * h) / 100) << "the page looks blank";
  EXPECT_GT(cut, 200u) << "no cut drawn on the path plot";
  EXPECT_GT(force, 200u) << "no force curve drawn";
}

TEST_F(ReportBrowser, TheLogCheckSeesAScriptError) {
  // The same flags on a page that throws: the check above would catch a broken page.
  const std::string chromium = chromium_or_skip();
  if (chromium.empty()) return;
  const std::string html = write("throws.html", "<!DOCTYPE html><html><body><p>x</p><script>throw new Error('boom');</script></body></html>");
  const Render r = render(chromium, dir_, html, (dir_ / "throws.png").string(), kWidth, kHeight);
  ASSERT_TRUE(r.exited) << r.log;
  EXPECT_FALSE(page_errors(r.log).empty()) << "chromium's log shows no script error; the check would miss one:\n" << r.log;
}

}  // namespace
}  // namespace lancet::score
