// A curriculum file (records/curriculum.hpp), read against its schema.

#include "records/curriculum.hpp"

#include <filesystem>
#include <optional>

#include "config/error.hpp"
#include "config/schema.hpp"
#include "config/text_file.hpp"
#include "records/content_hash.hpp"
#include "records/proficiency.hpp"
#include "scenarios/scenario.hpp"

namespace lancet::records {
namespace {

using config::kOpt;
using config::kReq;
using config::Section;
using config::Sink;

constexpr std::int64_t kCurriculumSchemaVersion = 1;
constexpr std::int64_t kMaxRequired = 100;
constexpr std::size_t kMaxSteps = 256;
constexpr std::size_t kMaxFileBytes = 1 << 20;

// One [[step]]: its scenario file loaded, its rule checked.
std::optional<CurriculumStep> parse_step(Section& s, const std::string& source_name) {
  std::optional<CurriculumStep> out;
  const auto file = s.text("scenario", kReq, 4096);
  const auto required = s.integer("required", kReq, 1, kMaxRequired);
  const auto consecutive = s.integer("consecutive", kOpt, 1, kMaxRequired);
  if (required && consecutive && *consecutive > *required) {
    s.sink().add(s.where("consecutive"), s.field("consecutive"), "an integer in 1..required (" + std::to_string(*required) + ")",
                 "integer " + std::to_string(*consecutive));
  }
  if (!file) return out;
  std::filesystem::path path(*file);
  if (path.is_relative()) path = std::filesystem::path(source_name).parent_path() / path;
  auto text = scenario::read_scenario_text(path.string());
  std::optional<scenario::Scenario> sc;
  if (text.ok()) {
    auto parsed = scenario::parse_scenario(text.value(), path.string());
    if (parsed.ok()) sc = std::move(parsed.value());
    else text = parsed.error();
  }
  if (!sc) {
    s.sink().add(s.where("scenario"), s.field("scenario"), "", "", "scenario " + path.string() + " does not load: " + text.error().message);
    return out;
  }
  if (!required || (consecutive && *consecutive > *required)) return out;
  out = CurriculumStep{sc->name, sha256_hex(text.value()), *required, consecutive.value_or(*required)};
  return out;
}

Curriculum parse_root(const toml::table& root, Sink& sink, const std::string& source_name) {
  Curriculum c;
  Section top(sink, root, "");
  (void)top.integer("schema_version", kReq, kCurriculumSchemaVersion, kCurriculumSchemaVersion);
  c.name = top.text("name", kReq, 128).value_or("");
  if (const auto steps = top.tables("step", kReq, 1, kMaxSteps)) {
    for (std::size_t i = 0; i < steps->size(); ++i) {
      Section s(sink, *(*steps)[i], "step[" + std::to_string(i) + "]");
      auto step = parse_step(s, source_name);
      s.finish();
      if (!step) continue;
      for (const CurriculumStep& before : c.steps) {
        if (before.scenario == step->scenario)
          sink.add(s.where("scenario"), s.field("scenario"), "a scenario no earlier step takes", "\"" + step->scenario + "\" again");
      }
      c.steps.push_back(std::move(*step));
    }
  }
  top.finish();
  return c;
}

}  // namespace

Result<Curriculum> parse_curriculum(std::string_view text, const std::string& source_name) {
  Sink sink{source_name, {}};
  std::optional<Curriculum> c;
  if (const auto root = config::parse_toml(text, sink)) c = parse_root(*root, sink, source_name);
  if (!sink.errors.empty()) {
    config::sort_errors(sink.errors);
    return Error{ErrorCode::kInvalid, config::format_errors(sink.errors)};
  }
  return std::move(*c);
}

Result<Curriculum> load_curriculum(const std::string& path) {
  auto text = config::read_text_file(path, kMaxFileBytes, "a curriculum");
  if (!text.ok()) return Error{text.error().code, path + ": " + text.error().message};
  return parse_curriculum(text.value(), path);
}

}  // namespace lancet::records
