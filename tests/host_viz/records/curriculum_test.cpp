// Curriculum files: the example names the project's scenarios; bad files are errors naming the
// line, the field and the scenario.

#include <gtest/gtest.h>

#include "records/content_hash.hpp"
#include "records/curriculum.hpp"

#include <string>
#include <vector>

namespace lancet::records {
namespace {

const std::string kSource = std::string(LANCET_SOURCE_DIR) + "/docs/examples/here.toml";

TEST(Curriculum, ExampleLoadsTheProjectsScenarios) {
  auto c = load_curriculum(std::string(LANCET_SOURCE_DIR) + "/docs/examples/curriculum.toml");
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c.value().name, "Lancet basics");
  ASSERT_EQ(c.value().steps.size(), 3u);
  EXPECT_EQ(c.value().steps[0].scenario, "skin-incision");
  EXPECT_EQ(c.value().steps[0].required, 3);
  EXPECT_EQ(c.value().steps[0].consecutive, 2);
  EXPECT_EQ(c.value().steps[1].scenario, "ct-incision");
  EXPECT_EQ(c.value().steps[2].scenario, "bone-drilling");
  EXPECT_EQ(c.value().steps[2].consecutive, 1);
  EXPECT_EQ(c.value().steps[0].scenario_hash.size(), 64u);
}

// A curriculum's text: the header (lines 1-2), then each step as three lines and its `extra` ones.
struct Step {
  std::string file;
  int required = 1;
  std::string extra;
};
std::string curriculum_text(const std::vector<Step>& steps) {
  std::string s = "schema_version = 1\nname = \"x\"\n";
  for (const Step& st : steps) s += "[[step]]\nscenario = \"" + st.file + "\"\nrequired = " + std::to_string(st.required) + "\n" + st.extra;
  return s;
}
const std::string kSkin = "../../host_viz/scenarios/skin_incision.toml";
const std::string kCt = "../../host_viz/scenarios/ct_incision.toml";

TEST(Curriculum, ConsecutiveDefaultsToRequired) {
  auto c = parse_curriculum(curriculum_text({{kSkin, 4, ""}}), kSource);
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c.value().steps[0].consecutive, 4);
}

TEST(Curriculum, MissingScenarioIsNamed) {
  auto c = parse_curriculum(curriculum_text({{kSkin, 1, ""}, {"no_such_scenario.toml", 1, ""}}), kSource);
  ASSERT_FALSE(c.ok());
  const std::string& m = c.error().message;
  EXPECT_NE(m.find("here.toml:7:"), std::string::npos) << m;  // the second step's scenario line
  EXPECT_NE(m.find("step[1].scenario"), std::string::npos) << m;
  EXPECT_NE(m.find("no_such_scenario.toml"), std::string::npos) << m;
}

TEST(Curriculum, BadRulesAndUnknownKeysAreErrors) {
  auto c = parse_curriculum(curriculum_text({{kSkin, 2, "consecutive = 3\n"}, {kCt, 0, ""}, {kSkin, 1, "consecutve = 1\n"}}), kSource);
  ASSERT_FALSE(c.ok());
  const std::string& m = c.error().message;
  EXPECT_NE(m.find("step[0].consecutive"), std::string::npos) << m;
  EXPECT_NE(m.find("step[1].required"), std::string::npos) << m;
  EXPECT_NE(m.find("consecutve"), std::string::npos) << m;  // unknown key, with a "did you mean"
}

TEST(Curriculum, RepeatedScenarioIsAnError) {
  auto c = parse_curriculum(curriculum_text({{kSkin, 1, ""}, {kSkin, 2, ""}}), kSource);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("\"skin-incision\" again"), std::string::npos) << c.error().message;
}

TEST(ContentHash, Sha256OfKnownTexts) {
  EXPECT_EQ(sha256_hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  auto missing = sha256_file("/nonexistent/lancet.h5");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("/nonexistent/lancet.h5"), std::string::npos);
}

}  // namespace
}  // namespace lancet::records
