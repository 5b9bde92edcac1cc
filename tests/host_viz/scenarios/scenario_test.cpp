// Scenarios: the shipped files load in SI units; each kind of error on its own, with its line,
// field path and expected / found text; several errors at once; task progress and the avoid
// shapes' contact test.

#include "scenarios/scenario.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <vector>

#ifndef LANCET_SOURCE_DIR
#define LANCET_SOURCE_DIR "."
#endif

namespace lancet::scenario {
namespace {

constexpr double kDeg = std::numbers::pi / 180;
constexpr double kMm = 1e-3;

std::string scenario_dir() { return std::string(LANCET_SOURCE_DIR) + "/host_viz/scenarios/"; }

// A small valid scenario the error tests mutate.
const std::string kBase = R"(schema_version = 1
name = "t"
tools = ["probe", "scalpel"]
start_tool = "probe"

[tissue]
source = "phantom"

[task]
kind = "incision"
line_mm = [[-10, 0, 0], [10, 0, 0]]
tolerance_mm = 2
)";

// Replaces the first occurrence of `from` (which must exist).
std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "test setup: no \"" << from << "\" in the text";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// 1-based line of the first occurrence of `needle`.
int line_of(const std::string& text, const std::string& needle) {
  const auto at = text.find(needle);
  EXPECT_NE(at, std::string::npos) << needle;
  return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n'));
}

// The error message's lines.
std::vector<std::string> lines_of(const Result<Scenario>& r) {
  std::vector<std::string> out;
  if (r.ok()) return out;
  const std::string& m = r.error().message;
  std::size_t start = 0;
  while (start < m.size()) {
    const auto end = m.find('\n', start);
    out.push_back(m.substr(start, end == std::string::npos ? std::string::npos : end - start));
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return out;
}

// One error line: "t.toml:<line>:<col>: <field>: <message>" with the message containing `text`.
::testing::AssertionResult is_error(const std::string& got, int line, const std::string& field, const std::string& text) {
  const std::string prefix = "t.toml:" + std::to_string(line) + ":";
  if (got.rfind(prefix, 0) != 0) return ::testing::AssertionFailure() << "not at line " << line << ": " << got;
  const auto col_end = got.find(": ", prefix.size());
  if (col_end == std::string::npos || col_end == prefix.size()) return ::testing::AssertionFailure() << "no column: " << got;
  const std::string rest = got.substr(col_end + 2);
  const std::string want_field = field.empty() ? std::string() : field + ": ";
  if (rest.rfind(want_field, 0) != 0) return ::testing::AssertionFailure() << "field is not " << field << ": " << got;
  if (rest.find(text, want_field.size()) == std::string::npos) return ::testing::AssertionFailure() << "no \"" << text << "\" in: " << got;
  return ::testing::AssertionSuccess();
}

// The text fails with exactly one error, at this line and field, with this text in its message.
void expect_one(const std::string& text, int line, const std::string& field, const std::string& message) {
  const auto r = parse_scenario(text, "t.toml");
  ASSERT_FALSE(r.ok()) << text;
  EXPECT_EQ(r.error().code, ErrorCode::kInvalid);
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 1u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], line, field, message));
}

// --- shipped files ------------------------------------------------------------------------------

TEST(Scenario, BaseTextLoads) {
  auto r = parse_scenario(kBase, "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Scenario& s = r.value();
  EXPECT_EQ(s.file, "t.toml");
  EXPECT_EQ(s.tissue.surface, SurfaceKind::kSkin);
  EXPECT_NEAR(s.tissue.cut_depth, 0.006, 1e-12);
  EXPECT_FLOAT_EQ(s.tissue.skin_iso, -300);
  EXPECT_FLOAT_EQ(s.tissue.bone_iso, 300);
  EXPECT_NEAR(s.camera.yaw, 0.6, 1e-12);  // defaults without [camera]
  EXPECT_NEAR(s.camera.distance, 0.26, 1e-12);
  EXPECT_TRUE(s.avoid.empty());
}

TEST(Scenario, EveryShippedFileLoads) {
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(scenario_dir())) {
    if (entry.path().extension() != ".toml") continue;
    ++files;
    auto r = load_scenario(entry.path().string());
    EXPECT_TRUE(r.ok()) << (r.ok() ? std::string() : r.error().message);
  }
  EXPECT_GE(files, 3);
}

TEST(Scenario, SkinIncisionLoads) {
  auto r = load_scenario(scenario_dir() + "skin_incision.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Scenario& s = r.value();
  EXPECT_EQ(s.file, scenario_dir() + "skin_incision.toml");
  EXPECT_EQ(s.name, "skin-incision");
  EXPECT_FALSE(s.description.empty());
  EXPECT_EQ(s.tissue.source, TissueSource::kPhantom);
  EXPECT_EQ(s.tissue.surface, SurfaceKind::kSkin);
  EXPECT_NEAR(s.tissue.cut_depth, 6 * kMm, 1e-12);
  EXPECT_EQ(s.tools, (std::vector<ToolMode>{ToolMode::kProbe, ToolMode::kScalpel, ToolMode::kRetractor, ToolMode::kSwab}));
  EXPECT_EQ(s.start_tool, ToolMode::kProbe);
  EXPECT_NEAR(s.camera.target.y, -0.012, 1e-12);  // over the line (the view itself is tuned by eye)
  ASSERT_EQ(s.task, TaskKind::kIncision);
  ASSERT_EQ(s.incision.line.size(), 2u);
  EXPECT_NEAR(s.incision.line[0].x, -0.015, 1e-12);
  EXPECT_NEAR(s.incision.line[0].y, -0.012, 1e-12);
  EXPECT_NEAR(s.incision.line[1].x, 0.015, 1e-12);
  EXPECT_NEAR(s.incision.line[1].y, -0.012, 1e-12);
  EXPECT_NEAR(s.incision.tolerance, 0.003, 1e-12);
  ASSERT_EQ(s.avoid.size(), 1u);
  EXPECT_EQ(s.avoid[0].name, "radial artery");
  EXPECT_EQ(s.avoid[0].kind, ShapeKind::kLabel);
  EXPECT_EQ(s.avoid[0].label, 6);
}

TEST(Scenario, BoneDrillingLoads) {
  auto r = load_scenario(scenario_dir() + "bone_drilling.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Scenario& s = r.value();
  EXPECT_EQ(s.name, "bone-drilling");
  EXPECT_EQ(s.tissue.source, TissueSource::kPhantom);
  EXPECT_EQ(s.tissue.surface, SurfaceKind::kBone);
  EXPECT_EQ(s.tools, (std::vector<ToolMode>{ToolMode::kProbe, ToolMode::kDrill}));
  ASSERT_EQ(s.task, TaskKind::kDrill);
  EXPECT_NEAR(s.drill.centre.x, 0, 1e-12);
  EXPECT_NEAR(s.drill.centre.y, 0.006, 1e-12);
  EXPECT_NEAR(s.drill.centre.z, -0.032, 1e-12);
  EXPECT_NEAR(s.drill.radius, 0.005, 1e-12);
  EXPECT_NEAR(s.drill.depth, 0.004, 1e-12);
  EXPECT_TRUE(s.incision.line.empty());
  ASSERT_EQ(s.avoid.size(), 1u);
  const Structure& nerve = s.avoid[0];
  EXPECT_EQ(nerve.name, "nerve canal");
  EXPECT_EQ(nerve.kind, ShapeKind::kCapsule);
  EXPECT_NEAR(nerve.a.x, -0.040, 1e-12);
  EXPECT_NEAR(nerve.b.x, 0.040, 1e-12);
  EXPECT_NEAR(nerve.a.y, 0.006, 1e-12);
  EXPECT_NEAR(nerve.b.z, -0.045, 1e-12);
  EXPECT_NEAR(nerve.radius, 0.002, 1e-12);
  // The window's 4 mm does not reach the canal's top (45 - 2 = 43 mm deep); 12 mm would.
  EXPECT_FALSE(touches(nerve, s.drill.centre - Vec3{0, 0, s.drill.depth}, 0.001));
  EXPECT_TRUE(touches(nerve, s.drill.centre - Vec3{0, 0, 0.012}, 0.001));
}

TEST(Scenario, CtIncisionLoads) {
  auto r = load_scenario(scenario_dir() + "ct_incision.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Scenario& s = r.value();
  EXPECT_EQ(s.tissue.source, TissueSource::kFile);
  EXPECT_TRUE(s.tissue.volume_path.empty());  // from --volume
  // Isovalues and axes are tuned to the scan the file is written for; here only their form.
  EXPECT_LT(s.tissue.skin_iso, s.tissue.bone_iso);
  std::array<int, 3> axes = s.tissue.axis;
  std::sort(axes.begin(), axes.end());
  EXPECT_EQ(axes, (std::array<int, 3>{0, 1, 2}));
  for (const int sign : s.tissue.sign) EXPECT_TRUE(sign == 1 || sign == -1);
  EXPECT_EQ(s.tools.size(), 5u);
  ASSERT_EQ(s.task, TaskKind::kIncision);
  ASSERT_EQ(s.incision.line.size(), 2u);
  EXPECT_NEAR(s.incision.line[0].x, -0.020, 1e-12);
  EXPECT_NEAR(s.incision.line[1].x, 0.020, 1e-12);
  EXPECT_NEAR(s.incision.tolerance, 0.004, 1e-12);
  EXPECT_TRUE(s.avoid.empty());
}

TEST(Scenario, CameraInRadiansAndMetres) {
  const std::string text =
      kBase + "\n[camera]\nyaw_deg = 90\npitch_deg = -45\ndistance_mm = 110\ntarget_mm = [1, -12, -4]\n";
  auto r = parse_scenario(text, "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Camera& c = r.value().camera;
  EXPECT_NEAR(c.yaw, std::numbers::pi / 2, 1e-12);
  EXPECT_NEAR(c.pitch, -std::numbers::pi / 4, 1e-12);
  EXPECT_NEAR(c.distance, 0.110, 1e-12);
  EXPECT_NEAR(c.target.x, 0.001, 1e-12);
  EXPECT_NEAR(c.target.y, -0.012, 1e-12);
  EXPECT_NEAR(c.target.z, -0.004, 1e-12);
}

TEST(Scenario, MissingFileIsNotFound) {
  auto r = load_scenario(scenario_dir() + "no_such_scenario.toml");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
  EXPECT_NE(r.error().message.find("no_such_scenario.toml: cannot open: "), std::string::npos) << r.error().message;
}

// --- each kind of error -------------------------------------------------------------------------

TEST(ScenarioErrors, TomlSyntaxError) {
  const std::string text = replaced(kBase, "name = \"t\"", "name = \"t");
  expect_one(text, line_of(text, "name ="), "", "TOML syntax error");
}

TEST(ScenarioErrors, MalformedTomlThatTrippedTomlPlusPlusAssertsIsASyntaxError) {
  // toml++ 3.3 asserted on these in builds without NDEBUG (see common/config/schema.hpp).
  for (const std::string tail : {"[\n", "[[ # x\n", "a = [}]\n"}) {
    const auto r = parse_scenario(kBase + tail, "t.toml");
    ASSERT_FALSE(r.ok()) << tail;
    EXPECT_NE(r.error().message.find("TOML syntax error"), std::string::npos) << r.error().message;
  }
}

TEST(ScenarioErrors, UnknownKeyWithSuggestion) {
  const std::string text = replaced(kBase, "tolerance_mm = 2", "tolerence_mm = 2");
  expect_one(text, line_of(text, "tolerence_mm"), "task.tolerence_mm",
             "unknown key \"tolerence_mm\" (did you mean \"tolerance_mm\"?); known keys here: kind, line_mm, tolerance_mm");
}

TEST(ScenarioErrors, UnknownTopLevelKey) {
  const std::string text = kBase + "colour = \"red\"\n";  // lands in [task]: after a table header
  expect_one(text, line_of(text, "colour"), "task.colour", "unknown key \"colour\"");
  const std::string top = "nmae = \"x\"\n" + kBase;
  const auto r = parse_scenario(top, "t.toml");
  ASSERT_FALSE(r.ok());
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 1u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], 1, "nmae", "unknown key \"nmae\" (did you mean \"name\"?)"));
}

TEST(ScenarioErrors, MissingRequiredKey) {
  const std::string text = replaced(kBase, "kind = \"incision\"\n", "");
  expect_one(text, line_of(text, "[task]"), "task.kind",
             "required key is missing; expected one of \"incision\", \"drill\"");
  const std::string no_name = replaced(kBase, "name = \"t\"\n", "");
  const auto r = parse_scenario(no_name, "t.toml");
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(is_error(lines_of(r).at(0), 1, "name", "required key is missing; expected a non-empty string"));
}

TEST(ScenarioErrors, MissingTable) {
  const std::string text = replaced(kBase, "[tissue]\nsource = \"phantom\"\n", "");
  expect_one(text, 1, "tissue", "required key is missing; expected a table [tissue]");
}

TEST(ScenarioErrors, WrongType) {
  const std::string text = replaced(kBase, "tolerance_mm = 2", "tolerance_mm = \"2\"");
  expect_one(text, line_of(text, "tolerance_mm"), "task.tolerance_mm",
             "expected a number in (0, 50], found string \"2\"");
  const std::string point = replaced(kBase, "[10, 0, 0]", "[10, 0, true]");
  expect_one(point, line_of(point, "line_mm"), "task.line_mm[1][2]", "expected a finite number, found boolean true");
}

TEST(ScenarioErrors, OutOfRange) {
  const std::string text = replaced(kBase, "tolerance_mm = 2", "tolerance_mm = 80");
  expect_one(text, line_of(text, "tolerance_mm"), "task.tolerance_mm",
             "expected a number in (0, 50], found integer 80");
  const std::string depth = replaced(kBase, "source = \"phantom\"", "source = \"phantom\"\ncut_depth_mm = 0");
  expect_one(depth, line_of(depth, "cut_depth_mm"), "tissue.cut_depth_mm", "expected a number in (0, 30], found integer 0");
  const std::string nan = replaced(kBase, "tolerance_mm = 2", "tolerance_mm = nan");
  expect_one(nan, line_of(nan, "tolerance_mm"), "task.tolerance_mm", "expected a number in (0, 50], found float nan");
}

TEST(ScenarioErrors, BadEnumString) {
  const std::string text = replaced(kBase, "source = \"phantom\"", "source = \"phantm\"");
  expect_one(text, line_of(text, "phantm"), "tissue.source",
             "expected one of \"phantom\", \"block\", \"file\", found string \"phantm\" (did you mean \"phantom\"?)");
  const std::string tool = replaced(kBase, "\"scalpel\"]", "\"knife\"]");
  expect_one(tool, line_of(tool, "knife"), "tools[1]",
             "expected one of \"probe\", \"scalpel\", \"retractor\", \"drill\", \"swab\", found string \"knife\"");
}

TEST(ScenarioErrors, TaskKindDisagreesWithSection) {
  std::string text = replaced(kBase, "kind = \"incision\"", "kind = \"drill\"\ncentre_mm = [0, 0, -5]");
  text = replaced(text, "[\"probe\", \"scalpel\"]", "[\"probe\", \"drill\"]");
  const auto r = parse_scenario(text, "t.toml");
  ASSERT_FALSE(r.ok());
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 2u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], line_of(text, "line_mm"), "task.line_mm",
                       "expected no line_mm (it is only for kind = \"incision\"), found array of 2"));
  EXPECT_TRUE(is_error(lines[1], line_of(text, "tolerance_mm"), "task.tolerance_mm",
                       "expected no tolerance_mm (it is only for kind = \"incision\"), found integer 2"));
}

TEST(ScenarioErrors, TaskToolNotOffered) {
  const std::string text = replaced(kBase, "[\"probe\", \"scalpel\"]", "[\"probe\", \"retractor\"]");
  expect_one(text, line_of(text, "tools ="), "tools",
             "expected tools including \"scalpel\" (task.kind = \"incision\" needs it), found [\"probe\", \"retractor\"]");
}

TEST(ScenarioErrors, StartToolNotOffered) {
  const std::string text = replaced(kBase, "start_tool = \"probe\"", "start_tool = \"drill\"");
  expect_one(text, line_of(text, "start_tool"), "start_tool",
             "expected one of the offered tools [\"probe\", \"scalpel\"], found string \"drill\"");
}

TEST(ScenarioErrors, StartToolDefaultsToTheFirstTool) {
  const std::string text = replaced(kBase, "[\"probe\", \"scalpel\"]\nstart_tool = \"probe\"", "[\"scalpel\", \"probe\"]");
  auto r = parse_scenario(text, "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().start_tool, ToolMode::kScalpel);
}

TEST(ScenarioErrors, TheLeftHandsToolsDefaultToTheRightHandsAndAreCheckedTheSameWay) {
  auto same = parse_scenario(kBase, "t.toml");
  ASSERT_TRUE(same.ok()) << same.error().message;
  EXPECT_EQ(same.value().left_tools, same.value().tools);
  EXPECT_EQ(same.value().left_start_tool, ToolMode::kProbe);

  const std::string own = replaced(kBase, "start_tool = \"probe\"", "start_tool = \"probe\"\nleft_tools = [\"retractor\", \"swab\"]\nleft_start_tool = \"swab\"");
  auto r = parse_scenario(own, "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().left_tools, (std::vector<ToolMode>{ToolMode::kRetractor, ToolMode::kSwab}));
  EXPECT_EQ(r.value().left_start_tool, ToolMode::kSwab);
  EXPECT_EQ(r.value().tools, (std::vector<ToolMode>{ToolMode::kProbe, ToolMode::kScalpel}));

  const std::string wrong = replaced(kBase, "start_tool = \"probe\"", "start_tool = \"probe\"\nleft_tools = [\"retractor\"]\nleft_start_tool = \"drill\"");
  expect_one(wrong, line_of(wrong, "left_start_tool"), "left_start_tool", "expected one of the offered tools [\"retractor\"], found string \"drill\"");
  const std::string twice = replaced(kBase, "start_tool = \"probe\"", "start_tool = \"probe\"\nleft_tools = [\"swab\", \"swab\"]");
  expect_one(twice, line_of(twice, "left_tools"), "left_tools[1]", "expected a tool not already listed (left_tools[0]), found string \"swab\"");
}

TEST(ScenarioErrors, DuplicateTool) {
  const std::string text = replaced(kBase, "[\"probe\", \"scalpel\"]", "[\"probe\", \"scalpel\", \"probe\"]");
  expect_one(text, line_of(text, "tools ="), "tools[2]",
             "expected a tool not already listed (tools[0]), found string \"probe\"");
}

TEST(ScenarioErrors, IncisionLineTooShort) {
  const std::string text = replaced(kBase, "[[-10, 0, 0], [10, 0, 0]]", "[[-10, 0, 0]]");
  expect_one(text, line_of(text, "line_mm"), "task.line_mm",
             "expected an array of 2..256 points [x, y, z], found array of 1");
}

TEST(ScenarioErrors, IncisionLineOfZeroLength) {
  // Only x-y counts: a vertical line has no length.
  const std::string text = replaced(kBase, "[[-10, 0, 0], [10, 0, 0]]", "[[1, 2, 0], [1, 2, -5], [1, 2, 3]]");
  expect_one(text, line_of(text, "line_mm"), "task.line_mm",
             "expected a line of nonzero length in x-y, found length 0 mm");
}

TEST(ScenarioErrors, FileSourceNeedsIsovalues) {
  const std::string text = replaced(kBase, "source = \"phantom\"", "source = \"file\"");
  const auto r = parse_scenario(text, "t.toml");
  ASSERT_FALSE(r.ok());
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 2u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], line_of(text, "[tissue]"), "tissue.skin_iso_hu",
                       "required key is missing; expected a number in [-100000, 100000]"));
  EXPECT_TRUE(is_error(lines[1], line_of(text, "[tissue]"), "tissue.bone_iso_hu", "required key is missing"));
}

TEST(ScenarioErrors, IsovaluesOutOfOrder) {
  const std::string text =
      replaced(kBase, "source = \"phantom\"", "source = \"file\"\nskin_iso_hu = 400\nbone_iso_hu = 200");
  expect_one(text, line_of(text, "bone_iso_hu"), "tissue.bone_iso_hu",
             "expected a number > skin_iso_hu (400), found integer 200");
}

TEST(ScenarioErrors, FileFieldsForThePhantom) {
  const std::string text = replaced(kBase, "source = \"phantom\"", "source = \"phantom\"\npath = \"ct.nrrd\"");
  expect_one(text, line_of(text, "path"), "tissue.path",
             "expected no path (it is only for source = \"file\"; this tissue is source = \"phantom\"), found string \"ct.nrrd\"");
}

TEST(ScenarioErrors, LabelsNeedABuiltInVolume) {
  const std::string text = replaced(kBase, "source = \"phantom\"",
                                    "source = \"file\"\nskin_iso_hu = -300\nbone_iso_hu = 300") +
                           "\n[[avoid]]\nname = \"artery\"\nshape = \"label\"\nlabel = 6\n";
  expect_one(text, line_of(text, "shape = \"label\""), "avoid[0].shape",
             "expected \"capsule\" or \"sphere\" (tissue.source = \"file\" has no material labels), found string \"label\"");
}

TEST(ScenarioErrors, AvoidShapeKeys) {
  const std::string text = kBase + "\n[[avoid]]\nname = \"n\"\nshape = \"sphere\"\ncentre_mm = [0, 0, -10]\nradius_mm = 2\nlabel = 3\n" +
                           "\n[[avoid]]\nname = \"n\"\nshape = \"capsule\"\na_mm = [0, 0, -10]\nradius_mm = 2\n";
  const auto r = parse_scenario(text, "t.toml");
  ASSERT_FALSE(r.ok());
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 3u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], line_of(text, "label = 3"), "avoid[0].label",
                       "expected no label (it is only for shape = \"label\"), found integer 3"));
  const int second = line_of(text, "shape = \"capsule\"") - 2;  // the [[avoid]] header
  EXPECT_TRUE(is_error(lines[1], second, "avoid[1].b_mm", "required key is missing; expected an array of 3 numbers"));
  EXPECT_TRUE(is_error(lines[2], second + 1, "avoid[1].name", "expected a name not used by avoid[0], found string \"n\""));
}

TEST(ScenarioErrors, SeveralErrorsAtOnceInFileOrder) {
  std::string text = replaced(kBase, "schema_version = 1", "schema_version = 2");
  text = replaced(text, "start_tool = \"probe\"", "start_tool = \"probe\"\nwhatever = 1");
  text = replaced(text, "source = \"phantom\"", "source = \"phantom\"\nsurface = \"muscle\"");
  text = replaced(text, "tolerance_mm = 2", "tolerance_mm = -1");
  const auto r = parse_scenario(text, "t.toml");
  ASSERT_FALSE(r.ok());
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 4u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], 1, "schema_version", "expected the integer 1, found integer 2"));
  EXPECT_TRUE(is_error(lines[1], line_of(text, "whatever"), "whatever", "unknown key \"whatever\""));
  EXPECT_TRUE(is_error(lines[2], line_of(text, "muscle"), "tissue.surface",
                       "expected one of \"skin\", \"bone\", found string \"muscle\""));
  EXPECT_TRUE(is_error(lines[3], line_of(text, "tolerance_mm"), "task.tolerance_mm", "found integer -1"));
}

// --- tissue details -----------------------------------------------------------------------------

TEST(ScenarioTissue, RelativePathResolvesAgainstTheScenarioFolder) {
  const std::string base =
      replaced(kBase, "source = \"phantom\"", "source = \"file\"\nskin_iso_hu = -300\nbone_iso_hu = 300\npath = \"PATH\"");
  auto rel = parse_scenario(replaced(base, "PATH", "../data/ct.nrrd"), "/opt/lancet/scenarios/s.toml");
  ASSERT_TRUE(rel.ok()) << rel.error().message;
  EXPECT_EQ(rel.value().tissue.volume_path, "/opt/lancet/data/ct.nrrd");
  auto abs = parse_scenario(replaced(base, "PATH", "/scans/ct.mha"), "/opt/lancet/scenarios/s.toml");
  ASSERT_TRUE(abs.ok()) << abs.error().message;
  EXPECT_EQ(abs.value().tissue.volume_path, "/scans/ct.mha");
  auto here = parse_scenario(replaced(base, "PATH", "ct.mha"), "s.toml");
  ASSERT_TRUE(here.ok()) << here.error().message;
  EXPECT_EQ(here.value().tissue.volume_path, "ct.mha");
}

TEST(ScenarioTissue, Axes) {
  const std::string base = replaced(kBase, "source = \"phantom\"",
                                    "source = \"file\"\nskin_iso_hu = -300\nbone_iso_hu = 300\naxes = AXES");
  auto r = parse_scenario(replaced(base, "AXES", "[\"-y\", \"x\", \"+z\"]"), "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  EXPECT_EQ(r.value().tissue.axis, (std::array<int, 3>{1, 0, 2}));
  EXPECT_EQ(r.value().tissue.sign, (std::array<int, 3>{-1, 1, 1}));
  const std::string dup = replaced(base, "AXES", "[\"x\", \"-x\", \"z\"]");
  expect_one(dup, line_of(dup, "axes"), "tissue.axes[1]", "expected a volume axis not used by tissue.axes[0], found string \"-x\"");
  const std::string bad = replaced(base, "AXES", "[\"x\", \"w\", \"z\"]");
  expect_one(bad, line_of(bad, "axes"), "tissue.axes[1]", "expected one of \"x\", \"y\", \"z\", \"-x\", \"-y\", \"-z\", found string \"w\"");
}

// --- incision progress --------------------------------------------------------------------------

IncisionTask line_task() {
  IncisionTask t;
  t.line = {{-0.015, -0.012, 0}, {0.015, -0.012, 0}};
  t.tolerance = 0.003;
  return t;
}

// A cut from (x0, y) to (x1, y) in n steps, z wandering (z does not count).
std::vector<Vec3> cut(double x0, double x1, double y, int n = 30) {
  std::vector<Vec3> c;
  for (int i = 0; i <= n; ++i) {
    const double t = static_cast<double>(i) / n;
    c.push_back({x0 + t * (x1 - x0), y, -0.002 * std::sin(7 * t)});
  }
  return c;
}

TEST(IncisionProgress, StraightCutAlongTheLine) {
  const auto p = incision_progress(line_task(), {cut(-0.015, 0.015, -0.012)});
  EXPECT_NEAR(p.covered, 1.0, 1e-9);
  EXPECT_NEAR(p.max_deviation, 0.0, 1e-12);
  EXPECT_NEAR(p.outside, 0.0, 1e-12);
}

TEST(IncisionProgress, HalfLengthCutInTwoStrokes) {
  const auto p = incision_progress(line_task(), {cut(-0.015, -0.005, -0.011), cut(-0.006, 0.0, -0.013)});
  EXPECT_NEAR(p.covered, 0.5, 1e-3);
  EXPECT_NEAR(p.max_deviation, 0.001, 1e-9);
  EXPECT_NEAR(p.outside, 0.0, 1e-12);
}

TEST(IncisionProgress, CutBesideTheLineBeyondTolerance) {
  const auto p = incision_progress(line_task(), {cut(-0.015, 0.015, -0.012 + 0.005)});
  EXPECT_EQ(p.covered, 0.0);
  EXPECT_NEAR(p.max_deviation, 0.005, 1e-9);
  EXPECT_NEAR(p.outside, 1.0, 1e-12);
}

TEST(IncisionProgress, CutOverrunningTheEnd) {
  // Line x in [-15, 15] mm; the cut runs on to x = 25 mm: 7 mm of its 20 lie farther than 3 mm.
  const auto p = incision_progress(line_task(), {cut(0.005, 0.025, -0.012, 200)});
  EXPECT_NEAR(p.covered, 10.0 / 30.0, 1e-3);
  EXPECT_NEAR(p.outside, 7.0 / 20.0, 5e-3);
  EXPECT_NEAR(p.max_deviation, 0.010, 1e-9);
}

TEST(IncisionProgress, NoCuts) {
  const auto p = incision_progress(line_task(), {});
  EXPECT_EQ(p.covered, 0.0);
  EXPECT_EQ(p.max_deviation, 0.0);
  EXPECT_EQ(p.outside, 0.0);
  const auto dot = incision_progress(line_task(), {{{0.0, -0.012, 0}}});
  EXPECT_EQ(dot.covered, 0.0);
}

// --- avoid shapes -------------------------------------------------------------------------------

TEST(Touches, Capsule) {
  Structure s;
  s.kind = ShapeKind::kCapsule;
  s.a = {-0.04, 0.006, -0.045};
  s.b = {0.04, 0.006, -0.045};
  s.radius = 0.002;
  EXPECT_TRUE(touches(s, {0, 0.006, -0.045}, 0.0));           // on the axis
  EXPECT_TRUE(touches(s, {0.01, 0.006, -0.040}, 0.0031));     // 5 mm above: 2 + 3.1 reaches
  EXPECT_FALSE(touches(s, {0.01, 0.006, -0.040}, 0.0029));
  EXPECT_TRUE(touches(s, {0.0435, 0.006, -0.045}, 0.0016));   // past the end cap: 3.5 mm from b
  EXPECT_FALSE(touches(s, {0.0435, 0.006, -0.045}, 0.0014));
  EXPECT_FALSE(touches(s, {0, 0.02, -0.045}, 0.001));
}

TEST(Touches, Sphere) {
  Structure s;
  s.kind = ShapeKind::kSphere;
  s.a = {0.01, 0, -0.02};
  s.radius = 0.003;
  EXPECT_TRUE(touches(s, {0.01, 0, -0.02}, 0.0));
  EXPECT_TRUE(touches(s, {0.01, 0.004, -0.02}, 0.0011));
  EXPECT_FALSE(touches(s, {0.01, 0.004, -0.02}, 0.0009));
  EXPECT_FALSE(touches(s, {0.0, 0.0, 0.0}, 0.001));
}

TEST(Touches, LabelIsTheCallersJob) {
  Structure s;
  s.kind = ShapeKind::kLabel;
  s.label = 6;
  EXPECT_FALSE(touches(s, {}, 1.0));
}

// --- [score] -----------------------------------------------------------------------------------

TEST(ScenarioScore, DefaultsWithoutTheSection) {
  auto r = parse_scenario(kBase, "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Score& s = r.value().score;
  EXPECT_EQ(s.force_limit, 3.0);
  EXPECT_NEAR(s.movement_speed, 0.020, 1e-15);
  EXPECT_EQ(s.movement_filter_hz, 10.0);
  EXPECT_EQ(s.sd_multiple, 2.0);
  EXPECT_TRUE(s.bands.empty());
  EXPECT_EQ(find_band(s, "task_time_s"), nullptr);
}

TEST(ScenarioScore, ValuesAndBands) {
  const std::string text = kBase +
                           "\n[score]\nforce_limit_n = 4.5\nmovement_speed_mm_s = 25\nmovement_filter_hz = 8\nsd_multiple = 1.5\n"
                           "[score.bands]\nincision_coverage_pct = { mean = 95, sd = 2 }\ntask_time_s = { mean = 12, sd = 3 }\n";
  auto r = parse_scenario(text, "t.toml");
  ASSERT_TRUE(r.ok()) << r.error().message;
  const Score& s = r.value().score;
  EXPECT_EQ(s.force_limit, 4.5);
  EXPECT_NEAR(s.movement_speed, 0.025, 1e-15);  // mm/s in the file, m/s in code
  EXPECT_EQ(s.movement_filter_hz, 8.0);
  EXPECT_EQ(s.sd_multiple, 1.5);
  ASSERT_EQ(s.bands.size(), 2u);
  EXPECT_EQ(s.bands[0].metric, "task_time_s");  // kScoreMetrics order, not file order
  EXPECT_EQ(s.bands[0].mean, 12.0);
  EXPECT_EQ(s.bands[0].sd, 3.0);
  const ScoreBand* cov = find_band(s, "incision_coverage_pct");
  ASSERT_NE(cov, nullptr);
  EXPECT_EQ(cov->mean, 95.0);  // in the metric's own unit: not converted
  EXPECT_EQ(cov->sd, 2.0);
}

TEST(ScenarioScore, ShippedFilesHaveProvisionalBands) {
  for (const char* name : {"skin_incision.toml", "bone_drilling.toml", "ct_incision.toml"}) {
    auto r = load_scenario(scenario_dir() + name);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_FALSE(r.value().score.bands.empty()) << name;
  }
  auto r = load_scenario(scenario_dir() + "skin_incision.toml");
  ASSERT_TRUE(r.ok());
  const ScoreBand* t = find_band(r.value().score, "task_time_s");
  ASSERT_NE(t, nullptr);
  EXPECT_EQ(t->mean, 9.5);  // the scripted demo (the 30 mm incision, retracting and swabbing): four runs
}

TEST(ScenarioScore, MetricNamesAreUniqueAndCarryAUnit) {
  for (std::size_t i = 0; i < kScoreMetrics.size(); ++i) {
    const std::string_view n = kScoreMetrics[i].name;
    EXPECT_TRUE(kScoreMetrics[i].incision || kScoreMetrics[i].drill) << n;
    EXPECT_EQ(n.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789_"), std::string_view::npos) << n;
    for (std::size_t j = 0; j < i; ++j) EXPECT_NE(n, kScoreMetrics[j].name);
  }
}

TEST(ScenarioScoreErrors, UnknownMetricWithSuggestion) {
  const std::string text = kBase + "\n[score.bands]\ntask_time = { mean = 12, sd = 3 }\n";
  expect_one(text, line_of(text, "task_time ="), "score.bands.task_time",
             "unknown key \"task_time\" (did you mean \"task_time_s\"?); known keys here: task_time_s, path_length_mm,");
}

TEST(ScenarioScoreErrors, UnknownKeyInScoreWithSuggestion) {
  const std::string text = kBase + "\n[score]\nforce_limit = 4\n";
  expect_one(text, line_of(text, "force_limit ="), "score.force_limit",
             "unknown key \"force_limit\" (did you mean \"force_limit_n\"?)");
}

TEST(ScenarioScoreErrors, LimitsOutOfRange) {
  const std::string zero = kBase + "\n[score]\nforce_limit_n = 0\n";
  expect_one(zero, line_of(zero, "force_limit_n"), "score.force_limit_n", "expected a number in (0, 1000], found integer 0");
  const std::string neg = kBase + "\n[score]\nmovement_speed_mm_s = -5\n";
  expect_one(neg, line_of(neg, "movement_speed_mm_s"), "score.movement_speed_mm_s",
             "expected a number in (0, 10000], found integer -5");
  const std::string hz = kBase + "\n[score]\nmovement_filter_hz = 600\n";
  expect_one(hz, line_of(hz, "movement_filter_hz"), "score.movement_filter_hz", "expected a number in (0, 500], found integer 600");
  const std::string k = kBase + "\n[score]\nsd_multiple = \"2\"\n";
  expect_one(k, line_of(k, "sd_multiple"), "score.sd_multiple", "expected a number in (0, 10], found string \"2\"");
}

TEST(ScenarioScoreErrors, BandNeedsPositiveSdAndAMean) {
  const std::string sd = kBase + "\n[score.bands]\ntask_time_s = { mean = 12, sd = 0 }\n";
  expect_one(sd, line_of(sd, "task_time_s"), "score.bands.task_time_s.sd", "expected a number > 0, found integer 0");
  const std::string mean = kBase + "\n[score.bands]\ntask_time_s = { sd = 3 }\n";
  expect_one(mean, line_of(mean, "task_time_s"), "score.bands.task_time_s.mean", "required key is missing; expected a finite number");
  const std::string typo = kBase + "\n[score.bands]\ntask_time_s = { mean = 12, sd = 3, mena = 1 }\n";
  expect_one(typo, line_of(typo, "task_time_s"), "score.bands.task_time_s.mena",
             "unknown key \"mena\" (did you mean \"mean\"?); known keys here: mean, sd");
  const std::string bare = kBase + "\n[score.bands]\ntask_time_s = 12\n";
  expect_one(bare, line_of(bare, "task_time_s"), "score.bands.task_time_s",
             "expected a table { mean = x, sd = y }, found integer 12");
}

TEST(ScenarioScoreErrors, BandForAnotherTasksMetric) {
  const std::string text = kBase + "\n[score.bands]\ndrill_progress_pct = { mean = 90, sd = 5 }\n";
  expect_one(text, line_of(text, "drill_progress_pct"), "score.bands.drill_progress_pct",
             "expected a metric of a kind = \"incision\" task, found a metric only for kind = \"drill\"");
}

TEST(ScenarioScoreErrors, SeveralAtOnceSortedByLine) {
  const std::string text = kBase + "\n[score]\nforce_limit_n = -1\nsd_multiple = 20\n[score.bands]\npath_lenght_mm = { mean = 1, sd = 1 }\n";
  const auto r = parse_scenario(text, "t.toml");
  ASSERT_FALSE(r.ok());
  const auto lines = lines_of(r);
  ASSERT_EQ(lines.size(), 3u) << r.error().message;
  EXPECT_TRUE(is_error(lines[0], line_of(text, "force_limit_n"), "score.force_limit_n", "expected a number in (0, 1000]"));
  EXPECT_TRUE(is_error(lines[1], line_of(text, "sd_multiple"), "score.sd_multiple", "expected a number in (0, 10]"));
  EXPECT_TRUE(is_error(lines[2], line_of(text, "path_lenght_mm"), "score.bands.path_lenght_mm",
                       "(did you mean \"path_length_mm\"?)"));
}

}  // namespace
}  // namespace lancet::scenario
