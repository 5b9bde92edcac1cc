// The scenario loader and the task geometry. Structure: the schema reader of
// common/config/schema.hpp (a Sink collects errors; a Section reads one TOML table and reports
// keys the schema did not ask for) with one parse_* function per schema section filling the plain
// Scenario; cross-section checks (the task's tool among the tools, labels against the tissue
// source) come last. Every check records an error and carries on, so one run reports everything.

#include "scenarios/scenario.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <utility>

#include "config/schema.hpp"
#include "config/text_file.hpp"
#include "config/units.hpp"

namespace lancet::scenario {

namespace {

using config::Choice;
using config::describe;
using config::indexed;
using config::kAny;
using config::kDeg;
using config::kMm;
using config::kOpt;
using config::kReq;
using config::Need;
using config::num;
using config::positive_up_to;
using config::quote;
using config::Range;
using config::read_choice;
using config::read_vec3;
using config::Section;
using config::Sink;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr std::size_t kMaxFileBytes = 1u << 20;  // a scenario is a few kB; refuse anything absurd
constexpr std::size_t kMaxLinePoints = 256;
constexpr std::size_t kMaxAvoid = 64;

// ---------------------------------------------------------------------------------------------
// Sections

const std::initializer_list<Choice<ToolMode>> kToolChoices{
    {"probe", ToolMode::kProbe}, {"scalpel", ToolMode::kScalpel}, {"retractor", ToolMode::kRetractor}, {"drill", ToolMode::kDrill},
    {"swab", ToolMode::kSwab}};

std::string tool_list_text(const std::vector<ToolMode>& tools) {
  std::string s = "[";
  for (std::size_t i = 0; i < tools.size(); ++i) s += (i ? ", " : "") + quote(tool_name(tools[i]));
  return s + "]";
}

// `key` (tools, or left_tools): the tools a hand is offered, none twice. Returns false when the key
// is absent (left_tools may be).
bool parse_tools(Section& top, const char* key, config::Need req, std::vector<ToolMode>& out) {
  const std::string expected = "an array of 1..5 tool names (\"probe\", \"scalpel\", \"retractor\", \"drill\", \"swab\")";
  const toml::array* a = top.array(key, req, 1, kToolCount, expected);
  if (a == nullptr) return false;
  std::vector<std::size_t> index_of;  // file index of each entry of out
  for (std::size_t i = 0; i < a->size(); ++i) {
    const toml::node& n = *a->get(i);
    const auto t = read_choice(top.sink(), n, indexed(key, i), kToolChoices);
    if (!t) continue;
    const auto dup = std::find(out.begin(), out.end(), *t);
    if (dup != out.end()) {
      const std::size_t first = index_of[static_cast<std::size_t>(dup - out.begin())];
      top.sink().add(n.source(), indexed(key, i), "a tool not already listed (" + std::string(key) + "[" + std::to_string(first) + "])",
                     describe(n));
      continue;
    }
    out.push_back(*t);
    index_of.push_back(i);
  }
  return true;
}

// A hand's start tool (`key`: start_tool, or left_start_tool): optional (the first tool it is
// offered), but when given it must be among `tools`.
void parse_start_tool(Section& top, const char* key, const std::vector<ToolMode>& tools, bool tools_ok, ToolMode& out) {
  const auto start = top.choice<ToolMode>(key, kOpt, kToolChoices);
  if (!start) {
    if (!tools.empty()) out = tools.front();
    return;
  }
  out = *start;
  if (tools_ok && std::find(tools.begin(), tools.end(), *start) == tools.end()) {
    top.sink().add(top.where(key), key, "one of the offered tools " + tool_list_text(tools), "string " + quote(tool_name(*start)));
  }
}

// "x", "-y", "+z": a volume axis and a direction.
bool parse_axis(std::string_view s, int& axis, int& sign) {
  sign = 1;
  if (!s.empty() && (s[0] == '-' || s[0] == '+')) {
    sign = s[0] == '-' ? -1 : 1;
    s.remove_prefix(1);
  }
  if (s.size() != 1 || s[0] < 'x' || s[0] > 'z') return false;
  axis = s[0] - 'x';
  return true;
}

void parse_axes(Section& t, Tissue& out) {
  const std::string expected = "an array of 3 volume axes, e.g. [\"x\", \"-z\", \"y\"]";
  const toml::array* a = t.array("axes", kOpt, 3, 3, expected);
  if (a == nullptr) return;
  std::array<int, 3> axis{}, sign{};
  bool ok = true;
  for (std::size_t i = 0; i < 3; ++i) {
    const toml::node& n = *a->get(i);
    const auto* v = n.as_string();
    const std::string field = indexed(t.field("axes"), i);
    if (v == nullptr || !parse_axis(v->get(), axis[i], sign[i])) {
      t.sink().add(n.source(), field, "one of \"x\", \"y\", \"z\", \"-x\", \"-y\", \"-z\"", describe(n));
      ok = false;
      continue;
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (a->get(j)->as_string() != nullptr && axis[j] == axis[i] && ok) {
        t.sink().add(n.source(), field, "a volume axis not used by " + indexed(t.field("axes"), j), describe(n));
        ok = false;
      }
    }
  }
  if (ok) {
    out.axis = axis;
    out.sign = sign;
  }
}

// Returns the source when it was read.
std::optional<TissueSource> parse_tissue(Section& t, Tissue& out, const std::string& source_name) {
  const auto source = t.choice<TissueSource>(
      "source", kReq, {{"phantom", TissueSource::kPhantom}, {"block", TissueSource::kBlock}, {"file", TissueSource::kFile}});
  out.surface = t.choice<SurfaceKind>("surface", kOpt, {{"skin", SurfaceKind::kSkin}, {"bone", SurfaceKind::kBone}})
                    .value_or(SurfaceKind::kSkin);
  if (auto v = t.number("cut_depth_mm", kOpt, positive_up_to(30))) out.cut_depth = *v * kMm;

  // A file's intensities are the scanner's: its isovalues must be stated. The built-in volumes
  // are in HU, so the defaults fit them.
  const bool file = source == TissueSource::kFile;
  const Need iso_need = file ? kReq : kOpt;
  const Range hu{-100'000, 100'000};
  const auto skin = t.number("skin_iso_hu", iso_need, hu);
  const auto bone = t.number("bone_iso_hu", iso_need, hu);
  if (skin) out.skin_iso = static_cast<float>(*skin);
  if (bone) out.bone_iso = static_cast<float>(*bone);
  if ((skin || bone) && !(out.skin_iso < out.bone_iso)) {
    const std::string key = bone ? "bone_iso_hu" : "skin_iso_hu";
    const std::string other = bone ? "skin_iso_hu (" + num(out.skin_iso) + ")" : "bone_iso_hu (" + num(out.bone_iso) + ")";
    t.sink().add(t.where(key), t.field(key), std::string(bone ? "a number > " : "a number < ") + other,
                 describe(*t.get(key)));
  }

  if (!source) {
    t.skip({"path", "axes"});
    return source;
  }
  out.source = *source;
  if (!file) {
    const std::string why = "source = \"file\"; this tissue is source = " + quote(source_key(*source));
    t.forbid("path", why);
    t.forbid("axes", why);
    return source;
  }
  if (auto p = t.text("path", kOpt, 4096)) {
    const std::filesystem::path path(*p);
    const std::filesystem::path dir = std::filesystem::path(source_name).parent_path();
    out.volume_path = path.is_absolute() || dir.empty() ? path.lexically_normal().string()
                                                        : (dir / path).lexically_normal().string();
  }
  parse_axes(t, out);
  return source;
}

void parse_camera(Section& c, Camera& out) {
  if (auto v = c.number("yaw_deg", kOpt, Range{-360, 360})) out.yaw = *v * kDeg;
  if (auto v = c.number("pitch_deg", kOpt, Range{-89, 89})) out.pitch = *v * kDeg;
  if (auto v = c.number("distance_mm", kOpt, positive_up_to(5000))) out.distance = *v * kMm;
  if (auto v = c.vec3("target_mm", kOpt, kMm)) out.target = *v;
}

void parse_incision(Section& t, IncisionTask& out) {
  const std::string expected = "an array of 2.." + std::to_string(kMaxLinePoints) + " points [x, y, z]";
  if (const toml::array* a = t.array("line_mm", kReq, 2, kMaxLinePoints, expected)) {
    std::vector<Vec3> line;
    for (std::size_t i = 0; i < a->size(); ++i) {
      if (auto p = read_vec3(t.sink(), *a->get(i), indexed(t.field("line_mm"), i), kMm)) line.push_back(*p);
    }
    if (line.size() == a->size()) {
      double length = 0;
      for (std::size_t i = 1; i < line.size(); ++i) length += std::hypot(line[i].x - line[i - 1].x, line[i].y - line[i - 1].y);
      if (!(length > 0)) {
        t.sink().add(a->source(), t.field("line_mm"), "a line of nonzero length in x-y", "length 0 mm");
      } else {
        out.line = std::move(line);
      }
    }
  }
  if (auto v = t.number("tolerance_mm", kOpt, positive_up_to(50))) out.tolerance = *v * kMm;
}

void parse_drill(Section& t, DrillTask& out) {
  if (auto v = t.vec3("centre_mm", kReq, kMm)) out.centre = *v;
  if (auto v = t.number("radius_mm", kOpt, positive_up_to(50))) out.radius = *v * kMm;
  if (auto v = t.number("depth_mm", kOpt, positive_up_to(100))) out.depth = *v * kMm;
}

// Returns the task kind when it was read.
std::optional<TaskKind> parse_task(Section& t, Scenario& out) {
  const auto kind = t.choice<TaskKind>("kind", kReq, {{"incision", TaskKind::kIncision}, {"drill", TaskKind::kDrill}});
  if (!kind) {
    t.skip({"line_mm", "tolerance_mm", "centre_mm", "radius_mm", "depth_mm"});
    return std::nullopt;
  }
  out.task = *kind;
  if (*kind == TaskKind::kIncision) {
    parse_incision(t, out.incision);
    for (const char* key : {"centre_mm", "radius_mm", "depth_mm"}) t.forbid(key, "kind = \"drill\"");
  } else {
    parse_drill(t, out.drill);
    for (const char* key : {"line_mm", "tolerance_mm"}) t.forbid(key, "kind = \"incision\"");
  }
  return kind;
}

void parse_avoid(Section& top, Scenario& out, std::optional<TissueSource> source) {
  const std::string expected = "an array of 0.." + std::to_string(kMaxAvoid) + " tables [[avoid]]";
  const toml::array* a = top.array("avoid", kOpt, 0, kMaxAvoid, expected);
  if (a == nullptr) return;
  config::UniqueValues<std::string> names("avoid", "name");
  for (std::size_t i = 0; i < a->size(); ++i) {
    const toml::node& e = *a->get(i);
    const std::string path = indexed("avoid", i);
    const toml::table* t = e.as_table();
    if (t == nullptr) {
      top.sink().add(e.source(), path, "a table", describe(e));
      continue;
    }
    Section s(top.sink(), *t, path);
    Structure st;
    if (auto v = s.text("name", kReq, 64)) {
      st.name = *v;
      names.check(s, "name", *v, i);
    }
    const auto shape = s.choice<ShapeKind>(
        "shape", kReq, {{"label", ShapeKind::kLabel}, {"capsule", ShapeKind::kCapsule}, {"sphere", ShapeKind::kSphere}});
    if (!shape) {
      s.skip({"label", "a_mm", "b_mm", "centre_mm", "radius_mm"});
      s.finish();
      continue;
    }
    st.kind = *shape;
    const std::string why_label = "shape = \"label\"", why_capsule = "shape = \"capsule\"", why_sphere = "shape = \"sphere\"";
    switch (*shape) {
      case ShapeKind::kLabel:
        st.label = static_cast<std::uint8_t>(s.integer("label", kReq, 1, 255).value_or(0));
        s.forbid("a_mm", why_capsule);
        s.forbid("b_mm", why_capsule);
        s.forbid("centre_mm", why_sphere);
        s.forbid("radius_mm", why_capsule + " or " + why_sphere);
        // Only the built-in volumes carry material labels.
        if (source == TissueSource::kFile) {
          s.sink().add(s.where("shape"), s.field("shape"),
                       "\"capsule\" or \"sphere\" (tissue.source = \"file\" has no material labels)", "string \"label\"");
        }
        break;
      case ShapeKind::kCapsule:
        st.a = s.vec3("a_mm", kReq, kMm).value_or(Vec3{});
        st.b = s.vec3("b_mm", kReq, kMm).value_or(Vec3{});
        st.radius = s.number("radius_mm", kReq, positive_up_to(100)).value_or(0) * kMm;
        s.forbid("label", why_label);
        s.forbid("centre_mm", why_sphere);
        break;
      case ShapeKind::kSphere:
        st.a = s.vec3("centre_mm", kReq, kMm).value_or(Vec3{});
        st.radius = s.number("radius_mm", kReq, positive_up_to(100)).value_or(0) * kMm;
        s.forbid("label", why_label);
        s.forbid("a_mm", why_capsule);
        s.forbid("b_mm", why_capsule);
        break;
    }
    s.finish();
    out.avoid.push_back(std::move(st));
  }
}

// One band, `{ mean = x, sd = y }`; nullopt after reporting when it does not read.
std::optional<ScoreBand> parse_band(Section& bands, const ScoreMetricInfo& m, std::optional<TaskKind> task) {
  const toml::node* n = bands.get(m.name);
  if (n == nullptr) return std::nullopt;
  const std::string field = bands.field(m.name);
  const auto* t = n->as_table();
  if (t == nullptr) {
    bands.sink().add(n->source(), field, "a table { mean = x, sd = y }", describe(*n));
    return std::nullopt;
  }
  Section b(bands.sink(), *t, field);
  const auto mean = b.number("mean", kReq, kAny);
  const auto sd = b.number("sd", kReq, Range{0, kInf, true, false});
  b.finish();
  // A band for a metric the task never has would silently never be checked.
  if (task && !(*task == TaskKind::kIncision ? m.incision : m.drill)) {
    const std::string_view other = *task == TaskKind::kIncision ? "drill" : "incision";
    bands.sink().add(n->source(), field, "a metric of a kind = " + quote(task_key(*task)) + " task",
                     "a metric only for kind = " + quote(other));
    return std::nullopt;
  }
  if (!mean || !sd) return std::nullopt;
  return ScoreBand{std::string(m.name), *mean, *sd};
}

void parse_score(Section& s, Score& out, std::optional<TaskKind> task) {
  if (auto v = s.number("force_limit_n", kOpt, positive_up_to(1000))) out.force_limit = *v;
  if (auto v = s.number("movement_speed_mm_s", kOpt, positive_up_to(10'000))) out.movement_speed = *v * kMm;
  if (auto v = s.number("movement_filter_hz", kOpt, positive_up_to(500))) out.movement_filter_hz = *v;
  if (auto v = s.number("sd_multiple", kOpt, positive_up_to(10))) out.sd_multiple = *v;
  if (const toml::table* bt = s.table("bands", kOpt)) {
    // Every metric name is a key of this table, so finish() offers the nearest one for a typo.
    Section bands(s.sink(), *bt, s.field("bands"));
    const auto parse_all = [&](const auto& metrics) {
      for (const ScoreMetricInfo& m : metrics) {
        if (auto band = parse_band(bands, m, task)) out.bands.push_back(std::move(*band));
      }
    };
    parse_all(kScoreMetrics);
    parse_all(kTwoHandScoreMetrics);
    bands.finish();
  }
}

Scenario parse_root(const toml::table& root, Sink& sink, const std::string& source_name) {
  Scenario sc;
  sc.file = source_name;
  Section top(sink, root, "");
  (void)top.integer("schema_version", kReq, kSchemaVersion, kSchemaVersion);
  sc.name = top.text("name", kReq, 64).value_or("");
  sc.description = top.text("description", kOpt, 1024).value_or("");
  const std::size_t errors_before_tools = sink.errors.size();
  (void)parse_tools(top, "tools", kReq, sc.tools);
  const bool tools_ok = sink.errors.size() == errors_before_tools && !sc.tools.empty();
  parse_start_tool(top, "start_tool", sc.tools, tools_ok, sc.start_tool);
  // The left hand's: its own list when given, else the same as the right hand's.
  const std::size_t errors_before_left = sink.errors.size();
  if (!parse_tools(top, "left_tools", kOpt, sc.left_tools)) sc.left_tools = sc.tools;
  const bool left_ok = sink.errors.size() == errors_before_left && !sc.left_tools.empty();
  parse_start_tool(top, "left_start_tool", sc.left_tools, left_ok, sc.left_start_tool);

  std::optional<TissueSource> source;
  if (const toml::table* tt = top.table("tissue", kReq)) {
    Section t(sink, *tt, "tissue");
    source = parse_tissue(t, sc.tissue, source_name);
    t.finish();
  }
  if (const toml::table* ct = top.table("camera", kOpt)) {
    Section c(sink, *ct, "camera");
    parse_camera(c, sc.camera);
    c.finish();
  }
  std::optional<TaskKind> task;
  if (const toml::table* tt = top.table("task", kReq)) {
    Section t(sink, *tt, "task");
    task = parse_task(t, sc);
    t.finish();
  }
  parse_avoid(top, sc, source);
  if (const toml::table* st = top.table("score", kOpt)) {
    Section s(sink, *st, "score");
    parse_score(s, sc.score, task);
    s.finish();
  }

  // The task needs its tool.
  if (task && tools_ok) {
    const ToolMode needed = *task == TaskKind::kIncision ? ToolMode::kScalpel : ToolMode::kDrill;
    if (std::find(sc.tools.begin(), sc.tools.end(), needed) == sc.tools.end()) {
      sink.add(top.where("tools"), "tools",
               "tools including " + quote(tool_name(needed)) + " (task.kind = " + quote(task_key(*task)) + " needs it)",
               tool_list_text(sc.tools));
    }
  }
  top.finish();
  return sc;
}

// ---------------------------------------------------------------------------------------------
// Task geometry (x-y only)

struct Xy {
  double x = 0, y = 0;
};
Xy xy(Vec3 v) { return {v.x, v.y}; }

// Distance from p to the segment ab and the parameter t in [0, 1] of the closest point.
double segment_distance(Xy p, Xy a, Xy b, double& t) {
  const double dx = b.x - a.x, dy = b.y - a.y;
  const double len2 = dx * dx + dy * dy;
  t = len2 > 0 ? std::clamp(((p.x - a.x) * dx + (p.y - a.y) * dy) / len2, 0.0, 1.0) : 0.0;
  return std::hypot(p.x - (a.x + t * dx), p.y - (a.y + t * dy));
}

// Distance from p to the polyline and the arc length (x-y) of the closest point.
double polyline_distance(Xy p, const std::vector<Vec3>& line, double& arc) {
  arc = 0;
  if (line.empty()) return kInf;
  if (line.size() == 1) return std::hypot(p.x - line[0].x, p.y - line[0].y);
  double best = kInf, start = 0;
  for (std::size_t i = 1; i < line.size(); ++i) {
    const Xy a = xy(line[i - 1]), b = xy(line[i]);
    const double len = std::hypot(b.x - a.x, b.y - a.y);
    double t = 0;
    const double d = segment_distance(p, a, b, t);
    if (d < best) {
      best = d;
      arc = start + t * len;
    }
    start += len;
  }
  return best;
}

double xy_length(const std::vector<Vec3>& line) {
  double len = 0;
  for (std::size_t i = 1; i < line.size(); ++i) len += std::hypot(line[i].x - line[i - 1].x, line[i].y - line[i - 1].y);
  return len;
}

}  // namespace

std::string_view source_key(TissueSource s) noexcept {
  switch (s) {
    case TissueSource::kBlock: return "block";
    case TissueSource::kPhantom: return "phantom";
    case TissueSource::kFile: return "file";
  }
  return "?";
}

std::string_view surface_key(SurfaceKind s) noexcept {
  switch (s) {
    case SurfaceKind::kSkin: return "skin";
    case SurfaceKind::kBone: return "bone";
  }
  return "?";
}

std::string_view task_key(TaskKind k) noexcept {
  switch (k) {
    case TaskKind::kIncision: return "incision";
    case TaskKind::kDrill: return "drill";
  }
  return "?";
}

std::string_view shape_key(ShapeKind k) noexcept {
  switch (k) {
    case ShapeKind::kLabel: return "label";
    case ShapeKind::kCapsule: return "capsule";
    case ShapeKind::kSphere: return "sphere";
  }
  return "?";
}

Result<Scenario> parse_scenario(std::string_view text, const std::string& source_name) {
  Sink sink{source_name, {}};
  std::optional<Scenario> sc;
  if (const auto root = config::parse_toml(text, sink)) sc = parse_root(*root, sink, source_name);
  if (!sink.errors.empty()) {
    config::sort_errors(sink.errors);
    return Error{ErrorCode::kInvalid, config::format_errors(sink.errors)};
  }
  return std::move(*sc);
}

Result<std::string> read_scenario_text(const std::string& path) {
  auto text = config::read_text_file(path, kMaxFileBytes, "a scenario");
  if (!text.ok()) return Error{text.error().code, path + ": " + text.error().message};
  return text;
}

Result<Scenario> load_scenario(const std::string& path) {
  auto text = read_scenario_text(path);
  if (!text.ok()) return text.error();
  return parse_scenario(text.value(), path);
}

const ScoreBand* find_band(const Score& score, std::string_view metric) noexcept {
  for (const ScoreBand& b : score.bands) {
    if (b.metric == metric) return &b;
  }
  return nullptr;
}

double xy_distance_to_polyline(Vec3 p, const std::vector<Vec3>& line) {
  double arc = 0;
  return polyline_distance(xy(p), line, arc);
}

IncisionProgress incision_progress(const IncisionTask& task, const std::vector<std::vector<Vec3>>& cuts) {
  IncisionProgress out;
  const double tol = task.tolerance;
  const double task_len = xy_length(task.line);
  double cut_len = 0;
  for (const auto& c : cuts) {
    cut_len += xy_length(c);
    for (const Vec3& p : c) out.max_deviation = std::max(out.max_deviation, xy_distance_to_polyline(p, task.line));
  }
  if (task.line.empty() || !(cut_len > 0) || !std::isfinite(cut_len)) return out;

  // Each cut segment in pieces of at most h: a piece whose midpoint is within tolerance covers the
  // stretch of the task line its ends project onto; the others count as outside.
  constexpr double kMaxPieces = 1 << 16;
  const double h = std::max(tol > 0 ? tol / 4 : cut_len, cut_len / kMaxPieces);
  std::vector<std::pair<double, double>> spans;
  double outside_len = 0;
  for (const auto& c : cuts) {
    for (std::size_t i = 1; i < c.size(); ++i) {
      const Xy a = xy(c[i - 1]), b = xy(c[i]);
      const double len = std::hypot(b.x - a.x, b.y - a.y);
      if (!(len > 0)) continue;
      const auto n = static_cast<std::size_t>(std::max(1.0, std::ceil(len / h)));
      for (std::size_t k = 0; k < n; ++k) {
        const double t0 = static_cast<double>(k) / static_cast<double>(n);
        const double t1 = static_cast<double>(k + 1) / static_cast<double>(n);
        const Xy p0{a.x + t0 * (b.x - a.x), a.y + t0 * (b.y - a.y)};
        const Xy p1{a.x + t1 * (b.x - a.x), a.y + t1 * (b.y - a.y)};
        const Xy mid{0.5 * (p0.x + p1.x), 0.5 * (p0.y + p1.y)};
        double s_mid = 0, s0 = 0, s1 = 0;
        if (polyline_distance(mid, task.line, s_mid) > tol) {
          outside_len += len / static_cast<double>(n);
          continue;
        }
        (void)polyline_distance(p0, task.line, s0);
        (void)polyline_distance(p1, task.line, s1);
        // Near a sharp corner of the task line the closest point can jump: then only the
        // midpoint's place counts.
        if (std::abs(s1 - s0) > 2 * len / static_cast<double>(n) + 1e-12) s0 = s1 = s_mid;
        spans.emplace_back(std::min(s0, s1), std::max(s0, s1));
      }
    }
  }
  out.outside = std::clamp(outside_len / cut_len, 0.0, 1.0);
  if (!(task_len > 0)) {
    out.covered = spans.empty() ? 0.0 : 1.0;
    return out;
  }
  std::sort(spans.begin(), spans.end());
  double covered = 0, lo = 0, hi = -1;
  for (const auto& [s0, s1] : spans) {
    if (s0 > hi) {
      if (hi > lo) covered += hi - lo;
      lo = s0;
      hi = s1;
    } else {
      hi = std::max(hi, s1);
    }
  }
  if (hi > lo) covered += hi - lo;
  out.covered = std::clamp(covered / task_len, 0.0, 1.0);
  return out;
}

bool touches(const Structure& s, Vec3 centre, double radius) {
  switch (s.kind) {
    case ShapeKind::kLabel: return false;
    case ShapeKind::kSphere: return norm(centre - s.a) <= s.radius + radius;
    case ShapeKind::kCapsule: {
      const Vec3 ab = s.b - s.a;
      const double len2 = dot(ab, ab);
      const double t = len2 > 0 ? std::clamp(dot(centre - s.a, ab) / len2, 0.0, 1.0) : 0.0;
      return norm(centre - (s.a + t * ab)) <= s.radius + radius;
    }
  }
  return false;
}

}  // namespace lancet::scenario
