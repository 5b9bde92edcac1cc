// The progress and cohort pages end to end: a store filled with attempts made by hand (no
// recordings to score), `lancet-records progress/cohort` with and without -o on both back ends,
// their bad input (exit 2), and both pages rendered by headless chromium (SQLite only): no console
// error, the expected elements in the DOM, a screenshot that is not blank. Set
// LANCET_KEEP_SCREENSHOTS=DIR to keep the screenshots for a look.

#include <gtest/gtest.h>
#include <stb/stb_image.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "headless_chromium.hpp"
#include "records/store.hpp"
#include "records_cli.hpp"
#include "synthetic_attempts.hpp"

namespace lancet::records::test {
namespace {

class PagesCliTest : public CliTest {
 protected:
  // Cohort "k&1": "t1" learning incision (24 attempts) and on to suture (3); "t2" stuck on
  // incision (12 failures); "t3" with no attempts. "t4" in another cohort.
  void fill() {
    auto opened = Store::open(db_);
    ASSERT_TRUE(opened.ok()) << opened.error().message;
    Store& s = *opened.value();
    ASSERT_TRUE(s.set_curriculum(Curriculum{"Basics", {{"incision", "h-incision", 3, 2}, {"suture", "h-suture", 2, 2}, {"knot", "h-knot", 1, 1}}}).ok());
    for (const Trainee& t : {Trainee{"t1", "Ann <Lee>", "k&1"}, Trainee{"t2", "Bo", "k&1"}, Trainee{"t3", "Cy", "k&1"}, Trainee{"t4", "Di", "other"}}) {
      ASSERT_TRUE(s.add_trainee(t).ok());
    }
    for (int i = 0; i < 24; ++i) ASSERT_TRUE(s.add_attempt(learning_attempt("t1", "incision", i)).ok());
    for (int i = 0; i < 3; ++i) ASSERT_TRUE(s.add_attempt(learning_attempt("t1", "suture", i, 1)).ok());
    for (int i = 0; i < 12; ++i) ASSERT_TRUE(s.add_attempt(learning_attempt("t2", "incision", 0, i)).ok());
  }
  int runs_ = 0;
};

TEST_P(PagesCliTest, ProgressAndCohortAsTextAndPages) {
  fill();
  const CliRun text = cli({"progress", "t1"});
  EXPECT_EQ(text.status, 0) << text.output;
  EXPECT_NE(text.output.find("next: suture"), std::string::npos) << text.output;

  const std::string progress_page = dir_ + "/progress.html";
  const CliRun page = cli({"progress", "t1", "-o", progress_page});
  ASSERT_EQ(page.status, 0) << page.output;
  const std::string html = lancet::test::read_file(progress_page);
  EXPECT_NE(html.find("Ann &lt;Lee&gt;"), std::string::npos);
  EXPECT_NE(html.find("<b id=\"next\">suture</b>"), std::string::npos);
  EXPECT_NE(html.find("<figure class=\"cusum\">"), std::string::npos);
  EXPECT_NE(html.find("data-metric=\"task_time_s\""), std::string::npos);

  const CliRun cohort_text = cli({"cohort", "k&1", "--stuck-after", "12"});
  EXPECT_EQ(cohort_text.status, 0) << cohort_text.output;
  EXPECT_NE(cohort_text.output.find("3 trainees"), std::string::npos) << cohort_text.output;
  EXPECT_EQ(cohort_text.output.find("t4"), std::string::npos) << cohort_text.output;
  EXPECT_NE(cohort_text.output.find("STUCK"), std::string::npos) << cohort_text.output;
  EXPECT_EQ(cli({"cohort", "k&1", "--stuck-after", "13"}).output.find("STUCK"), std::string::npos);

  const std::string cohort_page = dir_ + "/cohort.html";
  ASSERT_EQ(cli({"cohort", "k&1", "-o", cohort_page}).status, 0);
  const std::string cohort_html = lancet::test::read_file(cohort_page);
  EXPECT_NE(cohort_html.find("Cohort k&amp;1"), std::string::npos);
  EXPECT_NE(cohort_html.find("<tr class=\"stuck\"><td>t2</td>"), std::string::npos);
}

TEST_P(PagesCliTest, BadInputIsAClearErrorWithStatus2) {
  fill();
  const CliRun nobody = cli({"progress", "nobody", "-o", dir_ + "/p.html"});
  EXPECT_EQ(nobody.status, 2);
  EXPECT_NE(nobody.output.find("trainee \"nobody\" does not exist"), std::string::npos) << nobody.output;
  EXPECT_FALSE(std::filesystem::exists(dir_ + "/p.html"));
  const CliRun empty = cli({"cohort", "ghosts"});
  EXPECT_EQ(empty.status, 2);
  EXPECT_NE(empty.output.find("cohort \"ghosts\" has no trainees"), std::string::npos) << empty.output;
  EXPECT_EQ(cli({"cohort", "k&1", "--stuck-after", "0"}).status, 2);
  const CliRun unwritable = cli({"progress", "t1", "-o", dir_ + "/no/such/folder/p.html"});
  EXPECT_EQ(unwritable.status, 2);
  EXPECT_NE(unwritable.output.find("cannot write the page"), std::string::npos) << unwritable.output;
}

INSTANTIATE_TEST_SUITE_P(Backends, PagesCliTest, ::testing::Values(Backend::kSqlite, Backend::kPostgres), backend_name);

// The share of a screenshot's pixels near an RGB colour.
double share_near(const std::string& png, int r8, int g8, int b8, double* ink) {
  const std::string bytes = lancet::test::read_bytes(png);
  int w = 0, h = 0, n = 0;
  unsigned char* rgb = stbi_load_from_memory(reinterpret_cast<const unsigned char*>(bytes.data()), static_cast<int>(bytes.size()), &w, &h, &n, 3);
  if (rgb == nullptr) return -1;
  std::size_t near = 0, inked = 0;
  for (int i = 0; i < w * h; ++i) {
    const unsigned char* p = rgb + 3 * static_cast<std::size_t>(i);
    if (std::abs(p[0] - r8) < 40 && std::abs(p[1] - g8) < 40 && std::abs(p[2] - b8) < 40) ++near;
    if (p[0] < 200 || p[1] < 200 || p[2] < 200) ++inked;
  }
  stbi_image_free(rgb);
  *ink = static_cast<double>(inked) / (w * h);
  return static_cast<double>(near) / (w * h);
}

// Renders `html`, checks the log and the DOM for `ids`, keeps the screenshot when asked.
void check_in_chromium(const std::string& chromium, const std::filesystem::path& dir, const std::string& html, const std::string& name,
                       const std::vector<std::string>& ids, int height, const int rgb[3], const char* colour) {
  const std::string png = (dir / (name + ".png")).string();
  const lancet::test::Render r = lancet::test::render(chromium, dir, html, png, 1280, height);
  ASSERT_TRUE(r.exited) << "chromium did not finish within 120 s; its log:\n" << r.log;
  EXPECT_EQ(r.status, 0) << r.log;
  EXPECT_TRUE(lancet::test::page_errors(r.log).empty()) << "the page logged errors:\n" << r.log;
  const std::string dom = lancet::test::dump_dom(chromium, dir, html);
  for (const std::string& id : ids) EXPECT_NE(dom.find(id), std::string::npos) << name << ": no " << id << " in the DOM";
  double ink = 0;
  EXPECT_GT(share_near(png, rgb[0], rgb[1], rgb[2], &ink), 1e-4) << name << ": no " << colour << " on the page";
  EXPECT_GT(ink, 0.01) << name << ": the page looks blank";
  if (const char* keep = std::getenv("LANCET_KEEP_SCREENSHOTS"); keep != nullptr && *keep != '\0') {
    std::filesystem::copy_file(png, std::filesystem::path(keep) / (name + ".png"), std::filesystem::copy_options::overwrite_existing);
  }
}

class PagesBrowserTest : public PagesCliTest {};
constexpr int kGreen[3] = {0x1b, 0x7a, 0x35}, kRed[3] = {0xd6, 0x27, 0x28};

TEST_P(PagesBrowserTest, ChromiumRendersBothPages) {
  const std::string chromium = lancet::test::chromium_or_skip();
  if (chromium.empty()) return;
  fill();
  const std::string progress_page = dir_ + "/progress.html", cohort_page = dir_ + "/cohort.html";
  ASSERT_EQ(cli({"progress", "t1", "-o", progress_page}).status, 0);
  ASSERT_EQ(cli({"cohort", "k&1", "-o", cohort_page}).status, 0);
  check_in_chromium(chromium, dir_, progress_page, "records_progress",
                    {"id=\"curriculum\"", "id=\"step-1\"", "class=\"cusum\"", "class=\"curve\"", "id=\"attempts\"", "<circle class=\"pass\""}, 2400,
                    kGreen, "green (passes, the rule met)");
  check_in_chromium(chromium, dir_, cohort_page, "records_cohort", {"id=\"trainees\"", "id=\"steps-chart\"", "class=\"stuck\""}, 900, kRed,
                    "red (the stuck on the chart)");
}

INSTANTIATE_TEST_SUITE_P(Sqlite, PagesBrowserTest, ::testing::Values(Backend::kSqlite), backend_name);

}  // namespace
}  // namespace lancet::records::test
