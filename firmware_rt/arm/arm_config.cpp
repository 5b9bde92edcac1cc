// The arm config loader. Everything that touches toml++ lives in this file (the library is heavy
// to compile). Structure: a Sink collects errors; a Section reads one TOML table, remembers which
// keys the schema asked for and reports the rest as unknown; one parse_* function per schema
// section fills the plain ArmConfig; cross-section checks (joint counts, the bus against the
// backend, buttons against the bus's button word) come last. Every check records an error and
// carries on, so one run reports everything.

#include "arm/arm_config.hpp"

// toml++ 3.3 checks two parser preconditions with assert(), and malformed input can break them
// ("[" followed by a newline, "[[ # x", "a = [}]"): builds without NDEBUG would abort instead of
// throwing parse_error (upstream: marzer/tomlplusplus PR #301). With the check off the parser
// reports those inputs as ordinary syntax errors, as release builds do (the fuzz test covers it,
// and 200k mutated files ran clean under ASan/UBSan). Matters in header-only mode; the packaged
// shared library is built without these asserts.
#ifndef TOML_ASSERT
#define TOML_ASSERT(expr) static_cast<void>(0)
#endif
#include <toml++/toml.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <numbers>
#include <span>
#include <utility>

namespace lancet::arm {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kMm = 1e-3;
constexpr double kDeg = std::numbers::pi / 180.0;
constexpr std::size_t kMaxFileBytes = 4u << 20;  // a config is a few kB; refuse anything absurd

// ---------------------------------------------------------------------------------------------
// Describing values in messages

std::string quoted(std::string_view s) {
  std::string out = "\"";
  std::size_t shown = 0;
  for (const char ch : s) {
    if (++shown > 48) {
      out += "...";
      break;
    }
    const auto c = static_cast<unsigned char>(ch);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += ch;
    } else if (c < 0x20 || c >= 0x7f) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", static_cast<unsigned>(c));
      out += buf;
    } else {
      out += ch;
    }
  }
  return out + "\"";
}

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

std::string num(std::int64_t v, bool hex = false) {
  char buf[48];
  if (hex && v >= 0) {
    std::snprintf(buf, sizeof buf, "0x%04llX", static_cast<unsigned long long>(v));
  } else {
    std::snprintf(buf, sizeof buf, "%lld", static_cast<long long>(v));
  }
  return buf;
}

std::string describe(const toml::node& n, bool hex = false) {
  switch (n.type()) {
    case toml::node_type::string: return "string " + quoted(n.as_string()->get());
    case toml::node_type::integer: return "integer " + num(n.as_integer()->get(), hex);
    case toml::node_type::floating_point: return "float " + num(n.as_floating_point()->get());
    case toml::node_type::boolean: return n.as_boolean()->get() ? "boolean true" : "boolean false";
    case toml::node_type::array: return "array of " + std::to_string(n.as_array()->size());
    case toml::node_type::table: return "table";
    case toml::node_type::date: return "date";
    case toml::node_type::time: return "time";
    case toml::node_type::date_time: return "date-time";
    case toml::node_type::none: break;
  }
  return "nothing";
}

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0u : 1u)});
      diag = up;
    }
  }
  return row[b.size()];
}

// ---------------------------------------------------------------------------------------------
// Errors

struct Sink {
  std::string file;
  std::vector<ConfigError> errors;

  void add(const toml::source_region& at, std::string field, std::string expected, std::string found,
           std::string message = {}) {
    ConfigError e;
    e.file = file;
    e.line = at.begin.line > 0 ? static_cast<int>(at.begin.line) : 1;
    e.column = at.begin.column > 0 ? static_cast<int>(at.begin.column) : 1;
    e.field = std::move(field);
    if (message.empty()) message = "expected " + expected + ", found " + found;
    e.expected = std::move(expected);
    e.found = std::move(found);
    e.message = std::move(message);
    errors.push_back(std::move(e));
  }
};

enum class Need { kRequired, kOptional };
constexpr Need kReq = Need::kRequired;
constexpr Need kOpt = Need::kOptional;

/// Allowed interval of a number as the file writes it.
struct Range {
  double lo = -kInf, hi = kInf;
  bool lo_open = false, hi_open = false;
  [[nodiscard]] bool contains(double v) const {
    return std::isfinite(v) && (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
  [[nodiscard]] std::string text() const {
    const bool has_lo = std::isfinite(lo), has_hi = std::isfinite(hi);
    if (has_lo && has_hi) return "a number in " + std::string(lo_open ? "(" : "[") + num(lo) + ", " + num(hi) + (hi_open ? ")" : "]");
    if (has_lo) return std::string("a number ") + (lo_open ? "> " : ">= ") + num(lo);
    if (has_hi) return std::string("a number ") + (hi_open ? "< " : "<= ") + num(hi);
    return "a finite number";
  }
};
constexpr Range kAny{};
constexpr Range kPositive{0, kInf, true, false};
constexpr Range below(double hi_inclusive) { return Range{0, hi_inclusive, true, false}; }

template <class E>
struct Choice {
  std::string_view name;
  E value;
};

template <class E>
std::string choices_text(std::initializer_list<Choice<E>> options) {
  std::string s = "one of ";
  bool first = true;
  for (const auto& o : options) {
    if (!first) s += ", ";
    s += quoted(o.name);
    first = false;
  }
  return s;
}

std::string int_range_text(std::int64_t lo, std::int64_t hi, bool hex) {
  if (lo == hi) return "the integer " + num(lo, hex);
  return "an integer in " + num(lo, hex) + ".." + num(hi, hex);
}

// Node-level checks: record an error and return nullopt when the node does not fit.

std::optional<std::int64_t> read_integer(Sink& s, const toml::node& n, const std::string& field, std::int64_t lo,
                                         std::int64_t hi, bool hex = false) {
  const auto* v = n.as_integer();
  if (v == nullptr) {
    s.add(n.source(), field, int_range_text(lo, hi, hex), describe(n, hex));
    return std::nullopt;
  }
  if (v->get() < lo || v->get() > hi) {
    s.add(n.source(), field, int_range_text(lo, hi, hex), describe(n, hex));
    return std::nullopt;
  }
  return v->get();
}

std::optional<std::int64_t> read_integer_in(Sink& s, const toml::node& n, const std::string& field,
                                            std::span<const std::int64_t> allowed) {
  std::string expected = "one of ";
  for (std::size_t i = 0; i < allowed.size(); ++i) expected += (i ? ", " : "") + num(allowed[i]);
  const auto* v = n.as_integer();
  if (v == nullptr || std::find(allowed.begin(), allowed.end(), v->get()) == allowed.end()) {
    s.add(n.source(), field, expected, describe(n));
    return std::nullopt;
  }
  return v->get();
}

std::optional<double> read_number(Sink& s, const toml::node& n, const std::string& field, Range range) {
  double v = 0;
  if (const auto* i = n.as_integer()) {
    v = static_cast<double>(i->get());
  } else if (const auto* f = n.as_floating_point()) {
    v = f->get();
  } else {
    s.add(n.source(), field, range.text(), describe(n));
    return std::nullopt;
  }
  if (!range.contains(v)) {
    s.add(n.source(), field, range.text(), describe(n));
    return std::nullopt;
  }
  return v;
}

// ---------------------------------------------------------------------------------------------
// Section: one TOML table read against the schema

class Section {
 public:
  Section(Sink& sink, const toml::table& table, std::string path) : sink_(sink), table_(table), path_(std::move(path)) {}
  Section(const Section&) = delete;
  Section& operator=(const Section&) = delete;

  [[nodiscard]] std::string field(std::string_view key) const {
    return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
  }
  [[nodiscard]] const toml::source_region& where() const { return table_.source(); }
  /// Where a key's value is, or the table when the key is absent.
  [[nodiscard]] const toml::source_region& where(std::string_view key) const {
    const toml::node* n = table_.get(key);
    return n != nullptr ? n->source() : table_.source();
  }
  [[nodiscard]] bool has(std::string_view key) const { return table_.get(key) != nullptr; }
  Sink& sink() { return sink_; }

  /// The key's node (nullptr when absent); marks the key as part of the schema here.
  const toml::node* get(std::string_view key) {
    if (std::find(known_.begin(), known_.end(), key) == known_.end()) known_.emplace_back(key);
    return table_.get(key);
  }
  /// Marks keys as belonging here without reading them (a section whose variant is unknown).
  void skip(std::initializer_list<std::string_view> keys) {
    for (const auto k : keys) (void)get(k);
  }
  /// A key that must not appear in this variant of the section.
  void forbid(std::string_view key, const std::string& only_for) {
    if (const toml::node* n = get(key)) {
      sink_.add(n->source(), field(key), "no " + std::string(key) + " (it is only for " + only_for + ")",
                describe(*n));
    }
  }
  void missing(std::string_view key, const std::string& expected) {
    sink_.add(where(), field(key), expected, "nothing",
              "required key is missing; expected " + expected);
  }

  std::optional<std::int64_t> integer(std::string_view key, Need need, std::int64_t lo, std::int64_t hi,
                                      bool hex = false) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, int_range_text(lo, hi, hex));
      return std::nullopt;
    }
    return read_integer(sink_, *n, field(key), lo, hi, hex);
  }

  std::optional<std::int64_t> integer_in(std::string_view key, Need need, std::span<const std::int64_t> allowed) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) {
        std::string expected = "one of ";
        for (std::size_t i = 0; i < allowed.size(); ++i) expected += (i ? ", " : "") + num(allowed[i]);
        missing(key, expected);
      }
      return std::nullopt;
    }
    return read_integer_in(sink_, *n, field(key), allowed);
  }

  std::optional<double> number(std::string_view key, Need need, Range range) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, range.text());
      return std::nullopt;
    }
    return read_number(sink_, *n, field(key), range);
  }

  std::optional<std::string> text(std::string_view key, Need need, std::size_t max_len = 256) {
    const toml::node* n = get(key);
    const std::string expected = "a non-empty string of at most " + std::to_string(max_len) + " characters";
    if (n == nullptr) {
      if (need == kReq) missing(key, expected);
      return std::nullopt;
    }
    const auto* v = n->as_string();
    if (v == nullptr || v->get().empty() || v->get().size() > max_len) {
      sink_.add(n->source(), field(key), expected, describe(*n));
      return std::nullopt;
    }
    return v->get();
  }

  template <class E>
  std::optional<E> choice(std::string_view key, Need need, std::initializer_list<Choice<E>> options) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, choices_text(options));
      return std::nullopt;
    }
    if (const auto* v = n->as_string()) {
      for (const auto& o : options) {
        if (o.name == v->get()) return o.value;
      }
    }
    sink_.add(n->source(), field(key), choices_text(options), describe(*n));
    return std::nullopt;
  }

  std::optional<bool> boolean(std::string_view key, Need need) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, "true or false");
      return std::nullopt;
    }
    if (const auto* v = n->as_boolean()) return v->get();
    sink_.add(n->source(), field(key), "true or false", describe(*n));
    return std::nullopt;
  }

  /// An array of exactly three numbers, scaled into SI.
  std::optional<Vec3> vec3(std::string_view key, Need need, double scale) {
    const toml::node* n = get(key);
    const std::string expected = "an array of 3 numbers [x, y, z]";
    if (n == nullptr) {
      if (need == kReq) missing(key, expected);
      return std::nullopt;
    }
    const auto* a = n->as_array();
    if (a == nullptr || a->size() != 3) {
      sink_.add(n->source(), field(key), expected, describe(*n));
      return std::nullopt;
    }
    std::array<double, 3> v{};
    bool ok = true;
    for (std::size_t i = 0; i < 3; ++i) {
      const auto x = read_number(sink_, *a->get(i), field(key) + "[" + std::to_string(i) + "]", kAny);
      if (x) v[i] = *x * scale;
      ok = ok && x.has_value();
    }
    if (!ok) return std::nullopt;
    return Vec3{v[0], v[1], v[2]};
  }

  const toml::table* table(std::string_view key, Need need) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, "a table [" + field(key) + "]");
      return nullptr;
    }
    if (const auto* t = n->as_table()) return t;
    sink_.add(n->source(), field(key), "a table", describe(*n));
    return nullptr;
  }

  const toml::array* array(std::string_view key, Need need, const std::string& expected) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, expected);
      return nullptr;
    }
    if (const auto* a = n->as_array()) return a;
    sink_.add(n->source(), field(key), expected, describe(*n));
    return nullptr;
  }

  /// An array of tables ([[key]] or key = [{...}]) with min..max entries. Elements that are not
  /// tables are reported and come back as nullptr, so indices still match the file.
  std::optional<std::vector<const toml::table*>> tables(std::string_view key, Need need, std::size_t min,
                                                        std::size_t max) {
    const std::string expected = "an array of " + std::to_string(min) + ".." + std::to_string(max) + " tables [[" +
                                 field(key) + "]]";
    const toml::array* a = array(key, need, expected);
    if (a == nullptr) return std::nullopt;
    if (a->size() < min || a->size() > max) {
      sink_.add(a->source(), field(key), expected, describe(*a));
      return std::nullopt;
    }
    std::vector<const toml::table*> out;
    for (std::size_t i = 0; i < a->size(); ++i) {
      const toml::node& e = *a->get(i);
      const auto* t = e.as_table();
      if (t == nullptr) sink_.add(e.source(), field(key) + "[" + std::to_string(i) + "]", "a table", describe(e));
      out.push_back(t);
    }
    return out;
  }

  /// Reports every key of the table the schema did not ask for.
  void finish() {
    for (auto&& [k, v] : table_) {
      const std::string_view key = k.str();
      if (std::find(known_.begin(), known_.end(), key) != known_.end()) continue;
      std::string list;
      std::string_view best;
      std::size_t best_d = 3;
      for (const auto& kn : known_) {
        list += (list.empty() ? "" : ", ") + kn;
        const std::size_t d = edit_distance(key, kn);
        if (d < best_d && d < std::max<std::size_t>(kn.size() / 2, 1)) {
          best_d = d;
          best = kn;
        }
      }
      std::string message = "unknown key " + quoted(key);
      if (!best.empty()) message += " (did you mean " + quoted(best) + "?)";
      message += list.empty() ? "; this table takes no keys" : "; known keys here: " + list;
      sink_.add(k.source(), field(key), list.empty() ? "no keys" : "one of: " + list, "unknown key " + quoted(key),
                message);
    }
  }

 private:
  Sink& sink_;
  const toml::table& table_;
  std::string path_;
  std::vector<std::string> known_;
};

std::string indexed(const std::string& path, std::size_t i) { return path + "[" + std::to_string(i) + "]"; }

// A byte / register extent for overlap checks.
struct Extent {
  std::string field;
  std::int64_t begin = 0, end = 0;  // [begin, end)
  toml::source_region where;
};

// Reports each extent that overlaps an earlier one (in file order) of the same space.
void check_overlaps(Sink& s, std::vector<Extent> extents, const std::string& unit) {
  std::stable_sort(extents.begin(), extents.end(), [](const Extent& a, const Extent& b) {
    return std::pair(a.where.begin.line, a.where.begin.column) < std::pair(b.where.begin.line, b.where.begin.column);
  });
  for (std::size_t i = 0; i < extents.size(); ++i) {
    for (std::size_t j = 0; j < i; ++j) {
      const Extent& a = extents[j];
      const Extent& b = extents[i];
      if (b.begin < a.end && a.begin < b.end) {
        s.add(b.where, b.field,
              unit + " not used by " + a.field + " (" + num(a.begin) + ".." + num(a.end - 1) + ")",
              unit + " " + num(b.begin) + ".." + num(b.end - 1));
        break;
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Sections

struct Context {
  std::optional<int> n;                     // joints of the kinematic model, when it is known
  std::vector<JointType> types;             // per joint, when the model is known
  std::optional<Backend> backend;
  std::string backend_name;
};

std::string_view backend_key(Backend b) {
  switch (b) {
    case Backend::kSim: return "sim";
    case Backend::kUsb: return "usb";
    case Backend::kModbus: return "modbus";
    case Backend::kCanopen: return "canopen";
  }
  return "sim";
}

void parse_kinematics(Section& k, KinematicsConfig& out, Context& ctx) {
  const auto model = k.choice<KinematicModel>("model", kReq, {{"phantom", KinematicModel::kPhantom}, {"dh", KinematicModel::kDh}});
  if (auto v = k.vec3("base_offset_mm", kOpt, kMm)) out.base_offset = *v;
  if (!model) {
    k.skip({"l1_mm", "l2_mm", "links", "tool_offset_mm"});
    return;
  }
  out.model = *model;
  if (*model == KinematicModel::kPhantom) {
    const auto l1 = k.number("l1_mm", kReq, below(10'000));
    const auto l2 = k.number("l2_mm", kReq, below(10'000));
    k.forbid("links", "model = \"dh\"");
    k.forbid("tool_offset_mm", "model = \"dh\"");
    out.l1 = l1.value_or(0) * kMm;
    out.l2 = l2.value_or(0) * kMm;
    ctx.n = 3;
    ctx.types.assign(3, JointType::kRevolute);
    return;
  }
  k.forbid("l1_mm", "model = \"phantom\"");
  k.forbid("l2_mm", "model = \"phantom\"");
  if (auto v = k.vec3("tool_offset_mm", kOpt, kMm)) out.tool_offset = *v;
  const auto links = k.tables("links", kReq, 1, kMaxJoints);
  if (!links) return;
  bool all_typed = true;
  for (std::size_t i = 0; i < links->size(); ++i) {
    DhLink l;
    if ((*links)[i] == nullptr) {
      all_typed = false;
      out.links.push_back(l);
      continue;
    }
    Section s(k.sink(), *(*links)[i], indexed(k.field("links"), i));
    const auto type = s.choice<JointType>("type", kOpt, {{"revolute", JointType::kRevolute}, {"prismatic", JointType::kPrismatic}});
    if (s.has("type") && !type) all_typed = false;
    l.type = type.value_or(JointType::kRevolute);
    l.a = s.number("a_mm", kReq, kAny).value_or(0) * kMm;
    l.alpha = s.number("alpha_deg", kReq, Range{-360, 360}).value_or(0) * kDeg;
    l.d = s.number("d_mm", kReq, kAny).value_or(0) * kMm;
    l.theta_offset = s.number("theta_offset_deg", kReq, Range{-360, 360}).value_or(0) * kDeg;
    s.finish();
    out.links.push_back(l);
  }
  ctx.n = static_cast<int>(links->size());
  if (all_typed) {
    for (const auto& l : out.links) ctx.types.push_back(l.type);
  }
}

void parse_joints(Section& top, std::vector<JointConfig>& out, const Context& ctx) {
  const auto joints = top.tables("joints", kReq, 1, kMaxJoints);
  if (!joints) return;
  if (ctx.n && static_cast<std::size_t>(*ctx.n) != joints->size()) {
    top.sink().add(top.where("joints"), "joints",
                   std::to_string(*ctx.n) + " [[joints]] entries (one per joint of the kinematic model)",
                   std::to_string(joints->size()));
  }
  std::vector<std::pair<std::string, std::size_t>> names;
  for (std::size_t i = 0; i < joints->size(); ++i) {
    JointConfig j;
    const toml::table* t = (*joints)[i];
    if (t == nullptr) {
      out.push_back(j);
      continue;
    }
    const bool known_type = i < ctx.types.size();
    j.type = known_type ? ctx.types[i] : JointType::kRevolute;
    Section s(top.sink(), *t, indexed("joints", i));
    if (auto v = s.text("name", kReq, 64)) {
      j.name = *v;
      for (const auto& [other, k] : names) {
        if (other == *v) {
          s.sink().add(s.where("name"), s.field("name"), "a name not used by joints[" + std::to_string(k) + "]",
                       describe(*t->get("name")));
        }
      }
      names.emplace_back(*v, i);
    }
    j.counts_per_rev = s.integer("counts_per_rev", kReq, 1, std::int64_t{1} << 40).value_or(1);
    j.gear_ratio = s.number("gear_ratio", kReq, below(1e6)).value_or(1);
    const std::int64_t dirs[] = {-1, 1};
    j.direction = static_cast<int>(s.integer_in("direction", kReq, dirs).value_or(1));
    if (!known_type) {
      // The model is broken: accept either unit family without judging it.
      s.skip({"offset_deg", "min_deg", "max_deg", "offset_mm", "min_mm", "max_mm", "lead_mm", "max_speed_deg_s",
              "max_speed_mm_s"});
    } else {
      const bool revolute = j.type == JointType::kRevolute;
      const char* unit = revolute ? "deg" : "mm";
      const double scale = revolute ? kDeg : kMm;
      const std::string o = std::string("offset_") + unit, lo = std::string("min_") + unit, hi = std::string("max_") + unit;
      const std::string why = revolute ? "prismatic joints; this joint is revolute in the kinematic model"
                                       : "revolute joints; this joint is prismatic in the kinematic model";
      static constexpr std::array<const char*, 5> kPrismaticOnly{"offset_mm", "min_mm", "max_mm", "lead_mm", "max_speed_mm_s"};
      static constexpr std::array<const char*, 4> kRevoluteOnly{"offset_deg", "min_deg", "max_deg", "max_speed_deg_s"};
      if (revolute) {
        for (const char* key : kPrismaticOnly) s.forbid(key, why);
      } else {
        for (const char* key : kRevoluteOnly) s.forbid(key, why);
      }
      j.offset = s.number(o, kOpt, kAny).value_or(0) * scale;
      const auto mn = s.number(lo, kReq, kAny);
      const auto mx = s.number(hi, kReq, kAny);
      if (mn && mx && !(*mn < *mx)) {
        s.sink().add(s.where(hi), s.field(hi), "a number > " + lo + " (" + num(*mn) + ")", describe(*t->get(hi)));
      }
      j.min = mn.value_or(0) * scale;
      j.max = mx.value_or(0) * scale;
      if (!revolute) j.lead = s.number("lead_mm", kReq, kPositive).value_or(0) * kMm;
      // Encoder plausibility: a reading that moved faster than this since the last one is a glitch.
      const std::string vmax = std::string("max_speed_") + unit + "_s";
      j.max_speed = s.number(vmax, kOpt, kPositive).value_or(revolute ? JointConfig::kDefaultMaxSpeedDegS
                                                                       : JointConfig::kDefaultMaxSpeedMmS) *
                    scale;
    }
    s.finish();
    out.push_back(j);
  }
}

void parse_actuators(Section& top, std::vector<ActuatorConfig>& out, const Context& ctx) {
  const auto acts = top.tables("actuators", kReq, 1, kMaxJoints);
  if (!acts) return;
  if (ctx.n && static_cast<std::size_t>(*ctx.n) != acts->size()) {
    top.sink().add(top.where("actuators"), "actuators",
                   std::to_string(*ctx.n) + " [[actuators]] entries (one per joint of the kinematic model)",
                   std::to_string(acts->size()));
  }
  for (std::size_t i = 0; i < acts->size(); ++i) {
    ActuatorConfig a;
    const toml::table* t = (*acts)[i];
    if (t == nullptr) {
      out.push_back(a);
      continue;
    }
    Section s(top.sink(), *t, indexed("actuators", i));
    a.name = s.text("name", kOpt, 64).value_or("");
    a.torque_constant = s.number("torque_constant_nm_per_a", kReq, below(100)).value_or(0);
    const auto peak = s.number("peak_current_a", kReq, below(1000));
    const auto cont = s.number("continuous_current_a", kReq, below(1000));
    if (peak && cont && *peak < *cont) {
      s.sink().add(s.where("peak_current_a"), s.field("peak_current_a"),
                   "a number >= continuous_current_a (" + num(*cont) + ")", describe(*t->get("peak_current_a")));
    }
    a.peak_current = peak.value_or(0);
    a.continuous_current = cont.value_or(0);
    s.finish();
    out.push_back(a);
  }
}

void parse_safety(Section& top, SafetyConfig& out, const Context& ctx) {
  const toml::table* t = top.table("safety", kReq);
  if (t == nullptr) return;
  Section s(top.sink(), *t, "safety");
  out.max_force = s.number("max_force_n", kReq, below(1000)).value_or(0);
  const std::string tq_expected = ctx.n ? "an array of " + std::to_string(*ctx.n) + " numbers > 0 (one per joint)"
                                        : "an array of numbers > 0 (one per joint)";
  if (const toml::array* a = s.array("max_joint_torque_nm", kReq, tq_expected)) {
    if (ctx.n && a->size() != static_cast<std::size_t>(*ctx.n)) {
      s.sink().add(a->source(), s.field("max_joint_torque_nm"), tq_expected, describe(*a));
    }
    for (std::size_t i = 0; i < a->size(); ++i) {
      out.max_joint_torque.push_back(
          read_number(s.sink(), *a->get(i), indexed(s.field("max_joint_torque_nm"), i), below(10'000)).value_or(0));
    }
  }
  out.max_slew = s.number("max_slew_n_per_s", kReq, Range{0, 1e9}).value_or(0);
  const auto wmin = s.vec3("workspace_min_mm", kReq, kMm);
  const auto wmax = s.vec3("workspace_max_mm", kReq, kMm);
  if (wmin && wmax) {
    const std::array<double, 3> lo{wmin->x, wmin->y, wmin->z}, hi{wmax->x, wmax->y, wmax->z};
    const toml::array* amax = t->get("workspace_max_mm")->as_array();
    for (std::size_t i = 0; i < 3; ++i) {
      if (!(lo[i] < hi[i])) {
        s.sink().add(amax->get(i)->source(), indexed(s.field("workspace_max_mm"), i),
                     "a number > workspace_min_mm[" + std::to_string(i) + "] (" + num(lo[i] / kMm) + ")",
                     describe(*amax->get(i)));
      }
    }
  }
  out.workspace_min = wmin.value_or(Vec3{});
  out.workspace_max = wmax.value_or(Vec3{});
  out.watchdog_period = s.number("watchdog_period_ms", kReq, below(10'000)).value_or(0) * 1e-3;
  s.finish();
}

// --- bus sections ------------------------------------------------------------------------------

SimBusConfig parse_sim(Section& s) {
  SimBusConfig c;
  c.stylus_mass = s.number("stylus_mass_kg", kOpt, below(100)).value_or(c.stylus_mass);
  c.hand_stiffness = s.number("hand_stiffness_n_per_m", kOpt, Range{0, 1e6}).value_or(c.hand_stiffness);
  c.hand_damping = s.number("hand_damping_ns_per_m", kOpt, Range{0, 1e5}).value_or(c.hand_damping);
  c.encoder_noise_counts = s.integer("encoder_noise_counts", kOpt, 0, 1'000'000).value_or(0);
  s.finish();
  return c;
}

// --- USB report fields and Modbus register entries (shared layout keys) ----------------------

const std::initializer_list<Choice<FieldType>> kUsbNumberTypes = {
    {"u8", FieldType::kU8},   {"i8", FieldType::kI8},   {"u16", FieldType::kU16}, {"i16", FieldType::kI16},
    {"u32", FieldType::kU32}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kUsbSetpointTypes = {
    {"i8", FieldType::kI8}, {"i16", FieldType::kI16}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kUsbWordTypes = {{"u8", FieldType::kU8}, {"u16", FieldType::kU16}, {"u32", FieldType::kU32}};
const std::initializer_list<Choice<FieldType>> kRegNumberTypes = {
    {"u16", FieldType::kU16}, {"i16", FieldType::kI16}, {"u32", FieldType::kU32}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kRegSetpointTypes = {{"i16", FieldType::kI16}, {"i32", FieldType::kI32}, {"f32", FieldType::kF32}};
const std::initializer_list<Choice<FieldType>> kRegWordTypes = {{"u16", FieldType::kU16}, {"u32", FieldType::kU32}};
const std::initializer_list<Choice<ByteOrder>> kByteOrders = {{"little", ByteOrder::kLittle}, {"big", ByteOrder::kBig}};
const std::initializer_list<Choice<bool>> kWordOrders = {{"high_first", true}, {"low_first", false}};

/// What else a field takes besides its place and type.
enum class Extra : std::uint8_t {
  kNone,        // a raw word (buttons, heartbeat)
  kScale,       // a quantity: scale and bias
  kBits,        // the status word: bits = { ready, fault, enabled, estop, comm_lost }
  kEnable,      // on and off values
  kFaultReset,  // the value that resets a fault
};

struct FieldSpec {
  std::string_view key;
  bool required;
  bool per_joint;
  bool written;  // Modbus: must be a holding register
  Extra extra;
  std::initializer_list<Choice<FieldType>> types;
};

/// A key this schema had before and what took its place: reported at the key, with the way to
/// write it now (the key counts as known, so it is not also reported as unknown).
void replaced_key(Section& s, std::string_view key, const std::string& now) {
  if (const toml::node* n = s.get(key)) {
    s.sink().add(n->source(), s.field(key), now, describe(*n), "\"" + std::string(key) + "\" was replaced: " + now);
  }
}

/// The largest raw word of an unsigned field type.
std::int64_t word_max(FieldType t) {
  return t == FieldType::kU8 ? 0xFF : t == FieldType::kU16 ? 0xFFFF : std::int64_t{0xFFFF'FFFF};
}

/// The old `control` entry (bit 0 enable, bit 1 fault reset) became `enable` and `fault_reset`:
/// the error writes them out with the old entry's place (`where` is "table = ..., address = N" or
/// "offset = N").
void replaced_control(Section& r, bool modbus) {
  const toml::node* n = r.has("control") ? r.get("control") : nullptr;
  if (n == nullptr) return;
  std::string place = modbus ? "table = \"holding\", address = N" : "offset = N";
  std::string type = modbus ? "u16" : "u8";
  if (const auto* t = n->as_table()) {
    const char* key = modbus ? "address" : "offset";
    if (const auto v = t->get(key) ? t->get(key)->value<std::int64_t>() : std::nullopt)
      place = modbus ? "table = \"holding\", address = " + num(*v) : "offset = " + num(*v);
    if (const auto v = t->get("type") ? t->get("type")->value<std::string>() : std::nullopt) type = *v;
  }
  const std::string head = "{ " + place + ", type = \"" + type + "\", ";
  replaced_key(r, "control", "enable = " + head + "on = 1, off = 0 } and fault_reset = " + head + "value = 2 } (the old control bits 0 and 1)");
}

/// `lsb_ma = X` (mA per count) became `scale = X / 1000` (A per count): the error says the number.
void replaced_lsb_ma(Section& f) {
  const toml::node* n = f.has("lsb_ma") ? f.get("lsb_ma") : nullptr;
  if (n == nullptr) return;
  std::string now = "scale = A per count (lsb_ma = 1.0 is scale = 0.001)";
  if (const auto v = n->value<double>(); v && std::isfinite(*v)) now = "scale = " + num(*v * 1e-3) + " (A per count; lsb_ma was mA per count)";
  replaced_key(f, "lsb_ma", now);
}

/// scale (> 0) and bias (finite) of a quantity field: physical = scale · raw + bias.
void parse_scale(Section& f, double& scale, double& bias) {
  scale = f.number("scale", kOpt, kPositive).value_or(1);
  bias = f.number("bias", kOpt, kAny).value_or(0);
}

/// `bits = { name = BIT, name = { bit = BIT, active_low = true }, … }` of a status word `width` bits wide.
StatusBits parse_status_bits(Section& f, int width) {
  StatusBits out;
  if (!f.has("bits")) {
    f.missing("bits", "bits = { ... }: which bits of the word mean what (ready, fault, enabled, estop, comm_lost; "
                      "e.g. bits = { fault = 0, enabled = 1 }, the fixed meaning before this key)");
    (void)f.get("bits");
    return out;
  }
  const toml::table* t = f.table("bits", kReq);
  if (t == nullptr) return out;
  Section bs(f.sink(), *t, f.field("bits"));
  const std::pair<std::string_view, StatusBit StatusBits::*> names[] = {
      {"ready", &StatusBits::ready}, {"fault", &StatusBits::fault}, {"enabled", &StatusBits::enabled},
      {"estop", &StatusBits::estop}, {"comm_lost", &StatusBits::comm_lost}};
  const std::string expected = "a bit number 0.." + std::to_string(width - 1) + ", or { bit = N, active_low = true }";
  struct Named {
    std::string_view name;
    int bit;
    toml::source_region where;
  };
  std::vector<Named> used;
  for (const auto& [name, member] : names) {
    const toml::node* n = bs.get(name);
    if (n == nullptr) continue;
    StatusBit b;
    if (n->is_integer()) {
      if (auto v = read_integer(f.sink(), *n, bs.field(name), 0, width - 1)) b.bit = static_cast<int>(*v);
    } else if (const auto* bt = n->as_table()) {
      Section e(f.sink(), *bt, bs.field(name));
      if (auto v = e.integer("bit", kReq, 0, width - 1)) b.bit = static_cast<int>(*v);
      b.active_low = e.boolean("active_low", kOpt).value_or(false);
      e.finish();
    } else {
      f.sink().add(n->source(), bs.field(name), expected, describe(*n));
    }
    if (!b.mapped()) continue;
    used.push_back({name, b.bit, n->source()});
    out.*member = b;
  }
  // Two names on one bit: reported at the later one in the file.
  std::stable_sort(used.begin(), used.end(), [](const Named& a, const Named& b) {
    return std::pair(a.where.begin.line, a.where.begin.column) < std::pair(b.where.begin.line, b.where.begin.column);
  });
  for (std::size_t i = 0; i < used.size(); ++i) {
    for (std::size_t k = 0; k < i; ++k) {
      if (used[k].bit == used[i].bit) {
        f.sink().add(used[i].where, bs.field(used[i].name), "a bit not used by " + bs.field(used[k].name), "bit " + std::to_string(used[i].bit));
        break;
      }
    }
  }
  bs.finish();
  return out;
}

/// An enable / fault-reset word: an integer that fits the field's unsigned type.
std::optional<std::uint32_t> word_value(Section& f, std::string_view key, std::optional<FieldType> type) {
  const std::int64_t hi = type ? word_max(*type) : std::int64_t{0xFFFF'FFFF};
  const auto v = f.integer(key, kReq, 0, hi, true);
  return v ? std::optional<std::uint32_t>(static_cast<std::uint32_t>(*v)) : std::nullopt;
}

/// The keys of one field that say what its value means, by spec: scale and bias, status bits,
/// enable on / off, the fault-reset value. `width` is the field's width in bits, when known.
struct FieldMeaning {
  double scale = 1, bias = 0;
  StatusBits bits;
  std::uint32_t on = 1, off = 0, value = 0;
};

FieldMeaning parse_meaning(Section& f, const FieldSpec& spec, std::optional<FieldType> type) {
  FieldMeaning m;
  switch (spec.extra) {
    case Extra::kNone: break;
    case Extra::kScale: parse_scale(f, m.scale, m.bias); break;
    case Extra::kBits: m.bits = parse_status_bits(f, type ? 8 * field_size(*type) : 32); break;
    case Extra::kEnable: {
      const auto on = word_value(f, "on", type);
      const auto off = word_value(f, "off", type);
      if (on && off && *on == *off)
        f.sink().add(f.where("off"), f.field("off"), "a value other than on (" + num(std::int64_t{*on}, true) + ")", "the same value");
      m.on = on.value_or(1);
      m.off = off.value_or(0);
      break;
    }
    case Extra::kFaultReset: m.value = word_value(f, "value", type).value_or(0); break;
  }
  return m;
}

// --- [bus.usb] ---------------------------------------------------------------------------------

struct UsbField {
  ReportField field;
  FieldMeaning meaning;
  std::vector<Extent> extents;
};

// One report (in or out) of the USB section: size, optional report ID, its fields; a fault reset
// at exactly the enable's bytes (fields[reset_at], fields[enable_at]) shares them on purpose.
void parse_usb_report(Section& usb, std::string_view key, std::span<const FieldSpec> specs, ByteOrder default_order,
                      std::uint32_t& size, std::optional<std::uint8_t>& report_id, std::span<std::optional<UsbField>> fields,
                      const Context& ctx, std::optional<std::size_t> enable_at = {}, std::optional<std::size_t> reset_at = {}) {
  const toml::table* t = usb.table(key, kReq);
  if (t == nullptr) return;
  Section r(usb.sink(), *t, usb.field(key));
  const auto sz = r.integer("size", kReq, 1, 1024);
  size = static_cast<std::uint32_t>(sz.value_or(0));
  if (auto id = r.integer("report_id", kOpt, 1, 255)) report_id = static_cast<std::uint8_t>(*id);
  const int count = ctx.n.value_or(1);
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const FieldSpec& spec = specs[i];
    const toml::table* ft = r.table(spec.key, spec.required ? kReq : kOpt);
    if (ft == nullptr) continue;
    Section f(usb.sink(), *ft, r.field(spec.key));
    UsbField uf;
    const auto off = f.integer("offset", kReq, 0, 1023);
    const auto type = f.choice<FieldType>("type", kReq, spec.types);
    uf.field.byte_order = f.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(default_order);
    uf.meaning = parse_meaning(f, spec, type);
    if (spec.extra == Extra::kScale) {
      uf.field.scale = uf.meaning.scale;
      uf.field.bias = uf.meaning.bias;
      replaced_lsb_ma(f);
    }
    f.finish();
    if (!off || !type) continue;
    uf.field.offset = static_cast<std::uint32_t>(*off);
    uf.field.type = *type;
    const std::int64_t bytes = field_size(*type) * (spec.per_joint ? count : 1);
    if (sz && *off + bytes > *sz) {
      usb.sink().add(f.where("offset"), f.field("offset"),
                     "a field that fits in size = " + num(*sz) + " bytes (" + std::string(spec.key) + " takes " +
                         num(bytes) + " bytes" + (spec.per_joint ? ", one value per joint" : "") + ")",
                     "bytes " + num(*off) + ".." + num(*off + bytes - 1));
    }
    uf.extents.push_back({f.field("offset"), *off, *off + bytes, f.where("offset")});
    fields[i] = std::move(uf);
  }
  if (key == "out_report") {
    replaced_control(r, false);
    if (!r.has("current_command") && !r.has("torque_command")) {
      r.missing("current_command", "current_command = { offset, type, scale } (A per count) or torque_command = { ... } "
                                   "(N·m per count), one value per joint");
    } else if (r.has("current_command") && r.has("torque_command")) {
      usb.sink().add(r.where("torque_command"), r.field("torque_command"), "only one of current_command and torque_command", "both");
    }
  }
  r.finish();
  std::vector<Extent> extents;
  if (report_id) extents.push_back({r.field("report_id"), 0, 1, r.where("report_id")});
  const bool shared = enable_at && reset_at && fields[*enable_at] && fields[*reset_at] &&
                      fields[*enable_at]->field.offset == fields[*reset_at]->field.offset &&
                      fields[*enable_at]->field.type == fields[*reset_at]->field.type;
  for (std::size_t i = 0; i < fields.size(); ++i) {
    if (!fields[i] || (shared && i == *reset_at)) continue;
    extents.insert(extents.end(), fields[i]->extents.begin(), fields[i]->extents.end());
  }
  check_overlaps(usb.sink(), std::move(extents), "bytes");
}

/// `drive_watchdog_ms` of a bus section: required to make sense only with a heartbeat; 0 is off;
/// otherwise at least 10 ms and four times the bus's own timeout (a few late replies never trip it).
double parse_drive_watchdog(Section& s, bool has_heartbeat, const std::string& heartbeat_field, double timeout_s) {
  const auto ms = s.integer("drive_watchdog_ms", kOpt, 0, 65'535);
  if (!has_heartbeat) {
    if (ms && *ms > 0)
      s.sink().add(s.where("drive_watchdog_ms"), s.field("drive_watchdog_ms"), "a " + heartbeat_field + " for the drive to watch",
                   "no heartbeat in the map", "drive_watchdog_ms needs " + heartbeat_field + " (the value the drive watches)");
    return 0;
  }
  const std::int64_t v = ms.value_or(100);
  const double floor_ms = std::max(10.0, 4.0 * timeout_s * 1e3);
  if (ms && v > 0 && static_cast<double>(v) < floor_ms) {
    s.sink().add(s.where("drive_watchdog_ms"), s.field("drive_watchdog_ms"),
                 "0 (off) or at least " + num(static_cast<std::int64_t>(std::ceil(floor_ms))) +
                     " ms (10 ms and 4 bus timeouts: a few late replies must not trip the drive)",
                 "integer " + num(v));
  }
  return static_cast<double>(v) * 1e-3;
}

UsbBusConfig parse_usb(Section& s, const Context& ctx, std::optional<int>& button_bits) {
  UsbBusConfig c;
  c.vid = static_cast<std::uint16_t>(s.integer("vid", kReq, 0, 0xFFFF, true).value_or(0));
  c.pid = static_cast<std::uint16_t>(s.integer("pid", kReq, 0, 0xFFFF, true).value_or(0));
  c.interface_number = static_cast<int>(s.integer("interface", kReq, 0, 255).value_or(0));
  c.endpoint_in = static_cast<std::uint8_t>(s.integer("endpoint_in", kReq, 0x81, 0x8F, true).value_or(0x81));
  c.endpoint_out = static_cast<std::uint8_t>(s.integer("endpoint_out", kReq, 0x01, 0x0F, true).value_or(0x01));
  c.byte_order = s.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(ByteOrder::kLittle);
  c.timeout = s.number("timeout_ms", kOpt, below(1000)).value_or(2) * 1e-3;

  const FieldSpec in_specs[] = {
      {"encoder_counts", true, true, false, Extra::kScale, kUsbNumberTypes},
      {"buttons", false, false, false, Extra::kNone, kUsbWordTypes},
      {"status", false, false, false, Extra::kBits, kUsbWordTypes},
  };
  std::array<std::optional<UsbField>, 3> in{};
  parse_usb_report(s, "in_report", in_specs, c.byte_order, c.in_size, c.in_report_id, in, ctx);
  if (in[0]) c.encoder_counts = in[0]->field;
  if (in[1]) c.buttons = in[1]->field;
  if (in[2]) {
    c.status = in[2]->field;
    c.status_bits = in[2]->meaning.bits;
  }
  if (c.buttons) button_bits = 8 * field_size(c.buttons->type);
  const toml::node* in_node = s.has("in_report") ? s.get("in_report") : nullptr;
  if (!c.buttons && in_node != nullptr && in_node->is_table() && in_node->as_table()->contains("buttons"))
    button_bits = 32;  // a broken entry: its own error says what is wrong, the buttons need not

  const FieldSpec out_specs[] = {
      {"current_command", false, true, false, Extra::kScale, kUsbSetpointTypes},
      {"torque_command", false, true, false, Extra::kScale, kUsbSetpointTypes},
      {"enable", false, false, false, Extra::kEnable, kUsbWordTypes},
      {"fault_reset", false, false, false, Extra::kFaultReset, kUsbWordTypes},
      {"heartbeat", false, false, false, Extra::kNone, kUsbWordTypes},
  };
  std::array<std::optional<UsbField>, 5> out{};
  parse_usb_report(s, "out_report", out_specs, c.byte_order, c.out_size, c.out_report_id, out, ctx, 2, 3);
  if (out[0]) c.setpoint = out[0]->field;
  if (out[1]) {
    c.setpoint = out[1]->field;
    c.setpoint_kind = SetpointKind::kTorque;
  }
  if (out[2]) {
    c.enable = out[2]->field;
    c.enable_on = out[2]->meaning.on;
    c.enable_off = out[2]->meaning.off;
  }
  if (out[3]) {
    c.fault_reset = out[3]->field;
    c.fault_reset_value = out[3]->meaning.value;
  }
  if (out[4]) c.heartbeat = out[4]->field;
  c.drive_watchdog = parse_drive_watchdog(s, c.heartbeat.has_value(), "bus.usb.out_report.heartbeat", c.timeout);
  s.finish();
  return c;
}

// --- [bus.modbus] ------------------------------------------------------------------------------

struct ModbusEntry {
  RegisterField field;
  FieldMeaning meaning;
  std::vector<Extent> extents;
};

/// Where an entry's values are: `address = N` (values back to back from N) or, per joint,
/// `address = [a0, a1, …]` (one address per joint, in any order, not overlapping).
std::vector<std::uint16_t> parse_addresses(Section& f, const FieldSpec& spec, int count, std::optional<FieldType> type,
                                           std::vector<Extent>& extents) {
  std::vector<std::uint16_t> out;
  const std::int64_t w = type ? field_size(*type) / 2 : 1;
  const std::string expected = spec.per_joint ? "an address 0..65535, or an array of " + std::to_string(count) +
                                                    " addresses (one per joint)"
                                              : "an address 0..65535";
  const toml::node* n = f.get("address");
  if (n == nullptr) {
    f.missing("address", expected);
    return out;
  }
  const std::string key(spec.key);
  if (const auto* a = n->as_array(); a != nullptr && spec.per_joint) {
    if (a->size() != static_cast<std::size_t>(count)) {
      f.sink().add(a->source(), f.field("address"), expected, describe(*a));
      return {};
    }
    bool ok = true;
    for (std::size_t j = 0; j < a->size(); ++j) {
      const std::string fj = indexed(f.field("address"), j);
      const auto v = read_integer(f.sink(), *a->get(j), fj, 0, 65535);
      if (!v) {
        ok = false;
        continue;
      }
      if (*v + w > 65536) {
        f.sink().add(a->get(j)->source(), fj, "registers within 0..65535 (one value takes " + num(w) + ")",
                     "registers " + num(*v) + ".." + num(*v + w - 1));
        ok = false;
        continue;
      }
      out.push_back(static_cast<std::uint16_t>(*v));
      extents.push_back({fj, *v, *v + w, a->get(j)->source()});
    }
    if (!ok) out.clear();
    return out;
  }
  const auto v = read_integer(f.sink(), *n, f.field("address"), 0, 65535);
  if (!v) return out;
  const int values = spec.per_joint ? count : 1;
  const std::int64_t regs = w * values;
  if (*v + regs > 65536) {
    f.sink().add(n->source(), f.field("address"), "registers within 0..65535 (" + key + " takes " + num(regs) + ")",
                 "registers " + num(*v) + ".." + num(*v + regs - 1));
    return out;
  }
  for (int j = 0; j < values; ++j) out.push_back(static_cast<std::uint16_t>(*v + j * w));
  extents.push_back({f.field("address"), *v, *v + regs, n->source()});
  return out;
}

ModbusBusConfig parse_modbus(Section& s, const Context& ctx, std::optional<int>& button_bits) {
  ModbusBusConfig c;
  const auto transport =
      s.choice<ModbusTransport>("transport", kReq, {{"tcp", ModbusTransport::kTcp}, {"rtu", ModbusTransport::kRtu}});
  if (transport) c.transport = *transport;
  if (!transport) {
    s.skip({"host", "port", "device", "baud", "parity", "data_bits", "stop_bits"});
  } else if (*transport == ModbusTransport::kTcp) {
    c.host = s.text("host", kReq, 253).value_or("");
    c.port = static_cast<int>(s.integer("port", kOpt, 1, 65535).value_or(502));
    for (const char* k : {"device", "baud", "parity", "data_bits", "stop_bits"}) s.forbid(k, "transport = \"rtu\"");
  } else {
    c.device = s.text("device", kReq, 255).value_or("");
    c.baud = static_cast<int>(s.integer("baud", kReq, 300, 4'000'000).value_or(115200));
    c.parity = s.choice<Parity>("parity", kReq, {{"none", Parity::kNone}, {"even", Parity::kEven}, {"odd", Parity::kOdd}})
                   .value_or(Parity::kNone);
    const std::int64_t data_bits[] = {7, 8};
    const std::int64_t stop_bits[] = {1, 2};
    c.data_bits = static_cast<int>(s.integer_in("data_bits", kOpt, data_bits).value_or(8));
    c.stop_bits = static_cast<int>(s.integer_in("stop_bits", kOpt, stop_bits).value_or(1));
    for (const char* k : {"host", "port"}) s.forbid(k, "transport = \"tcp\"");
  }
  c.unit_id = static_cast<int>(s.integer("unit_id", kReq, 1, 247).value_or(1));
  c.response_timeout = s.number("response_timeout_ms", kOpt, below(10'000)).value_or(5) * 1e-3;

  bool has_heartbeat = false;
  const toml::table* rt = s.table("registers", kReq);
  if (rt != nullptr) {
    Section r(s.sink(), *rt, s.field("registers"));
    const bool hwf = r.choice<bool>("word_order", kOpt, kWordOrders).value_or(true);
    const ByteOrder bo = r.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(ByteOrder::kBig);
    const FieldSpec specs[] = {
        {"encoder_counts", true, true, false, Extra::kScale, kRegNumberTypes},
        {"current_command", false, true, true, Extra::kScale, kRegSetpointTypes},
        {"torque_command", false, true, true, Extra::kScale, kRegSetpointTypes},
        {"status", false, false, false, Extra::kBits, kRegWordTypes},
        {"buttons", false, false, false, Extra::kNone, kRegWordTypes},
        {"enable", false, false, true, Extra::kEnable, kRegWordTypes},
        {"fault_reset", false, false, true, Extra::kFaultReset, kRegWordTypes},
        {"heartbeat", false, false, true, Extra::kNone, kRegWordTypes},
        {"watchdog_timeout", false, false, true, Extra::kScale, kRegWordTypes},
    };
    enum : std::size_t { kEncoders, kCurrent, kTorque, kStatus, kButtons, kEnable, kFaultReset, kHeartbeat, kWatchdogTimeout };
    std::array<std::optional<ModbusEntry>, std::size(specs)> fields{};
    std::array<RegisterTable, std::size(specs)> tables{};
    const int count = ctx.n.value_or(1);
    for (std::size_t i = 0; i < std::size(specs); ++i) {
      const FieldSpec& spec = specs[i];
      const toml::table* ft = r.table(spec.key, spec.required ? kReq : kOpt);
      if (ft == nullptr) continue;
      Section f(s.sink(), *ft, r.field(spec.key));
      ModbusEntry e;
      const auto table = spec.written
                             ? f.choice<RegisterTable>("table", kReq, {{"holding", RegisterTable::kHolding}})
                             : f.choice<RegisterTable>("table", kReq, {{"input", RegisterTable::kInput}, {"holding", RegisterTable::kHolding}});
      const auto type = f.choice<FieldType>("type", kReq, spec.types);
      e.field.address = parse_addresses(f, spec, count, type, e.extents);
      e.field.high_word_first = f.choice<bool>("word_order", kOpt, kWordOrders).value_or(hwf);
      e.field.byte_order = f.choice<ByteOrder>("byte_order", kOpt, kByteOrders).value_or(bo);
      e.meaning = parse_meaning(f, spec, type);
      e.field.scale = e.meaning.scale;
      e.field.bias = e.meaning.bias;
      if (spec.extra == Extra::kScale) {
        replaced_lsb_ma(f);
        replaced_key(f, "offset", "bias (physical = scale * raw + bias; the register is `address`)");
      }
      f.finish();
      if (!table || !type || e.field.address.empty()) continue;
      e.field.table = *table;
      e.field.type = *type;
      tables[i] = *table;
      fields[i] = std::move(e);
    }
    replaced_control(r, true);
    if (!r.has("current_command") && !r.has("torque_command")) {
      r.missing("current_command", "current_command = { table = \"holding\", address, type, scale } (A per count) or "
                                   "torque_command = { ... } (N·m per count), one value per joint");
    } else if (r.has("current_command") && r.has("torque_command")) {
      s.sink().add(r.where("torque_command"), r.field("torque_command"), "only one of current_command and torque_command", "both");
    }
    r.finish();
    // Overlaps per table; a fault reset written to the enable register itself is meant.
    const auto& en = fields[kEnable];
    const auto& fr = fields[kFaultReset];
    const bool shared = en && fr && en->field.table == fr->field.table && en->field.address == fr->field.address &&
                        en->field.type == fr->field.type;
    std::vector<Extent> input, holding;
    for (std::size_t i = 0; i < fields.size(); ++i) {
      if (!fields[i] || (shared && i == kFaultReset)) continue;
      auto& dst = tables[i] == RegisterTable::kInput ? input : holding;
      dst.insert(dst.end(), fields[i]->extents.begin(), fields[i]->extents.end());
    }
    check_overlaps(s.sink(), std::move(input), "input registers");
    check_overlaps(s.sink(), std::move(holding), "holding registers");

    ModbusRegisterMap& m = c.registers;
    if (fields[kEncoders]) m.encoder_counts = fields[kEncoders]->field;
    if (fields[kCurrent]) m.setpoint = fields[kCurrent]->field;
    if (fields[kTorque]) {
      m.setpoint = fields[kTorque]->field;
      m.setpoint_kind = SetpointKind::kTorque;
    }
    if (fields[kStatus]) {
      m.status = fields[kStatus]->field;
      m.status_bits = fields[kStatus]->meaning.bits;
    }
    if (fields[kButtons]) {
      m.buttons = fields[kButtons]->field;
      button_bits = 8 * field_size(m.buttons->type);
    } else if (rt->contains("buttons")) {
      button_bits = 32;  // a broken entry: its own error says what is wrong, the buttons need not
    }
    if (en) {
      m.enable = en->field;
      m.enable_on = en->meaning.on;
      m.enable_off = en->meaning.off;
    }
    if (fr) {
      m.fault_reset = fr->field;
      m.fault_reset_value = fr->meaning.value;
    }
    if (fields[kHeartbeat]) m.heartbeat = fields[kHeartbeat]->field;
    if (fields[kWatchdogTimeout]) m.watchdog_timeout = fields[kWatchdogTimeout]->field;
    has_heartbeat = rt->contains("heartbeat");
  }
  c.drive_watchdog = parse_drive_watchdog(s, has_heartbeat, "bus.modbus.registers.heartbeat", c.response_timeout);
  s.finish();
  return c;
}

struct PdoParse {
  std::vector<PdoConfig> pdos;
  // every object mapped at subindex 0, with its width
  struct Mapped {
    std::uint16_t index;
    std::uint8_t bits;
  };
  std::vector<Mapped> mapped;
  bool complete = true;  // false when some entry could not be read (skip the "is it mapped" checks)
};

PdoParse parse_pdos(Section& s, std::string_view key, std::string_view label) {
  PdoParse out;
  const auto pdos = s.tables(key, kReq, 1, 4);
  if (!pdos) {
    out.complete = false;
    return out;
  }
  std::vector<std::pair<std::int64_t, std::size_t>> numbers;
  for (std::size_t i = 0; i < pdos->size(); ++i) {
    const toml::table* t = (*pdos)[i];
    if (t == nullptr) {
      out.complete = false;
      continue;
    }
    Section p(s.sink(), *t, indexed(s.field(key), i));
    PdoConfig pc;
    if (auto n = p.integer("number", kReq, 1, 4)) {
      for (const auto& [other, k] : numbers) {
        if (other == *n) {
          p.sink().add(p.where("number"), p.field("number"),
                       "a " + std::string(label) + " number not used by " + indexed(s.field(key), k),
                       describe(*t->get("number")));
        }
      }
      numbers.emplace_back(*n, i);
      pc.number = static_cast<int>(*n);
    } else {
      out.complete = false;
    }
    pc.sync_divider = static_cast<int>(p.integer("sync_divider", kOpt, 1, 240).value_or(1));
    const std::string expected = "an array of 1..8 inline tables { index, subindex, bits }";
    if (const toml::array* entries = p.array("entries", kReq, expected)) {
      if (entries->empty() || entries->size() > 8) {
        p.sink().add(entries->source(), p.field("entries"), expected, describe(*entries));
      }
      int total_bits = 0;
      for (std::size_t e = 0; e < entries->size(); ++e) {
        const toml::node& en = *entries->get(e);
        const std::string ef = indexed(p.field("entries"), e);
        const auto* et = en.as_table();
        if (et == nullptr) {
          p.sink().add(en.source(), ef, "a table { index, subindex, bits }", describe(en));
          out.complete = false;
          continue;
        }
        Section es(s.sink(), *et, ef);
        const auto index = es.integer("index", kReq, 0x1000, 0xFFFF, true);
        const auto sub = es.integer("subindex", kReq, 0, 255);
        const std::int64_t widths[] = {8, 16, 32};
        const auto bits = es.integer_in("bits", kReq, widths);
        es.finish();
        if (!index || !sub || !bits) {
          out.complete = false;
          continue;
        }
        total_bits += static_cast<int>(*bits);
        pc.entries.push_back({static_cast<std::uint16_t>(*index), static_cast<std::uint8_t>(*sub),
                              static_cast<std::uint8_t>(*bits)});
        if (*sub == 0) out.mapped.push_back({static_cast<std::uint16_t>(*index), static_cast<std::uint8_t>(*bits)});
      }
      if (total_bits > 64) {
        p.sink().add(entries->source(), p.field("entries"), "at most 64 bits of mapped objects (one CAN frame)",
                     std::to_string(total_bits) + " bits");
      }
    } else {
      out.complete = false;
    }
    p.finish();
    out.pdos.push_back(std::move(pc));
  }
  return out;
}

CanopenBusConfig parse_canopen(Section& s, const Context& ctx, bool has_buttons, std::optional<int>& button_bits) {
  CanopenBusConfig c;
  c.interface_name = s.text("interface", kReq, 15).value_or("");
  const std::int64_t rates[] = {10'000, 20'000, 50'000, 125'000, 250'000, 500'000, 800'000, 1'000'000};
  c.bitrate = static_cast<int>(s.integer_in("bitrate", kReq, rates).value_or(1'000'000));
  c.mode = s.choice<Cia402Mode>("mode", kOpt, {{"cst", Cia402Mode::kCyclicSyncTorque}, {"tq", Cia402Mode::kProfileTorque}})
               .value_or(Cia402Mode::kCyclicSyncTorque);
  c.sync_period = s.number("sync_period_us", kOpt, Range{100, 100'000}).value_or(1000) * 1e-6;
  c.heartbeat_period = s.number("heartbeat_ms", kOpt, Range{0, 65'535}).value_or(100) * 1e-3;
  // 0x1006 takes whole µs, and cyclic synchronous mode writes the period to 0x60C2 as value · 10^index s
  // with value 1..255: 1000 µs is 1 · 10^-3, 2500 µs is 25 · 10^-4, 333 µs has no exact form.
  if (const toml::node* sp = s.has("sync_period_us") ? s.get("sync_period_us") : nullptr) {
    const double us = c.sync_period * 1e6;
    std::int64_t mantissa = std::llround(us);
    if (std::abs(us - static_cast<double>(mantissa)) > 1e-6) {
      s.sink().add(sp->source(), s.field("sync_period_us"), "a whole number of microseconds (0x1006 is in µs)", describe(*sp));
    } else if (c.mode == Cia402Mode::kCyclicSyncTorque) {
      while (mantissa % 10 == 0 && mantissa > 0) mantissa /= 10;
      if (mantissa > 255) {
        s.sink().add(sp->source(), s.field("sync_period_us"),
                     "a period 0x60C2 (interpolation time) can express exactly: value · 10^index s with value 1..255 "
                     "(e.g. 1000, 2500, 250, 125)", describe(*sp));
      }
    }
  }
  c.master_node_id = static_cast<int>(s.integer("master_node_id", kOpt, 1, 127).value_or(127));
  const std::optional<std::int64_t> watchdog_ms = s.integer("drive_watchdog_ms", kOpt, 0, 65'535);
  c.drive_watchdog = static_cast<double>(watchdog_ms.value_or(100)) * 1e-3;
  if (watchdog_ms && *watchdog_ms > 0) {
    // The master's heartbeat goes out every drive_watchdog_ms / 4, from the servo tick: at least a SYNC period.
    const double floor_ms = std::max(10.0, 4.0 * c.sync_period * 1e3);
    if (static_cast<double>(*watchdog_ms) < floor_ms) {
      s.sink().add(s.where("drive_watchdog_ms"), s.field("drive_watchdog_ms"),
                   "0 (off) or at least " + num(static_cast<std::int64_t>(std::ceil(floor_ms))) +
                       " ms (10 ms and 4 SYNC periods: the master's heartbeat goes out every drive_watchdog_ms / 4)",
                   "integer " + num(*watchdog_ms));
    }
  }

  const std::string ids_expected = ctx.n ? "an array of " + std::to_string(*ctx.n) + " node ids (one per joint)"
                                         : "an array of node ids (one per joint)";
  if (const toml::array* ids = s.array("node_ids", kReq, ids_expected)) {
    if (ctx.n && ids->size() != static_cast<std::size_t>(*ctx.n)) {
      s.sink().add(ids->source(), s.field("node_ids"), ids_expected, describe(*ids));
    }
    for (std::size_t i = 0; i < ids->size(); ++i) {
      const std::string f = indexed(s.field("node_ids"), i);
      const auto id = read_integer(s.sink(), *ids->get(i), f, 1, 127);
      if (!id) continue;
      if (std::find(c.node_ids.begin(), c.node_ids.end(), *id) != c.node_ids.end()) {
        s.sink().add(ids->get(i)->source(), f, "a node id not used by another joint", describe(*ids->get(i)));
      }
      c.node_ids.push_back(static_cast<int>(*id));
    }
  }
  if (std::find(c.node_ids.begin(), c.node_ids.end(), c.master_node_id) != c.node_ids.end()) {
    s.sink().add(s.where("master_node_id"), s.field("master_node_id"), "a node id that no drive uses (the host's own)",
                 "integer " + num(std::int64_t{c.master_node_id}) + (s.has("master_node_id") ? "" : " (the default), one of node_ids"));
  }
  if (auto b = s.integer("buttons_node", kOpt, 1, 127)) {
    c.buttons_node = static_cast<int>(*b);
    if (!c.node_ids.empty() && std::find(c.node_ids.begin(), c.node_ids.end(), *b) == c.node_ids.end()) {
      s.sink().add(s.where("buttons_node"), s.field("buttons_node"), "one of node_ids",
                   "integer " + num(*b));
    }
  }

  if (const toml::table* ot = s.table("objects", kOpt)) {
    Section o(s.sink(), *ot, s.field("objects"));
    auto idx = [&](std::string_view k, std::uint16_t dflt) {
      return static_cast<std::uint16_t>(o.integer(k, kOpt, 0x1000, 0xFFFF, true).value_or(dflt));
    };
    c.objects.controlword = idx("controlword", c.objects.controlword);
    c.objects.statusword = idx("statusword", c.objects.statusword);
    c.objects.position_actual = idx("position_actual", c.objects.position_actual);
    c.objects.target_torque = idx("target_torque", c.objects.target_torque);
    c.objects.digital_inputs = idx("digital_inputs", c.objects.digital_inputs);
    o.finish();
  }

  PdoParse rp = parse_pdos(s, "rpdo", "RPDO");
  PdoParse tp = parse_pdos(s, "tpdo", "TPDO");
  c.rpdos = std::move(rp.pdos);
  c.tpdos = std::move(tp.pdos);

  // The driver needs these objects in PDOs of the right direction and width.
  struct Need402 {
    const char* what;
    std::uint16_t index;
    std::uint8_t bits;
    bool in_tpdo;
    bool needed;
  };
  const Need402 needs[] = {
      {"controlword", c.objects.controlword, 16, false, true},
      {"target_torque", c.objects.target_torque, 16, false, true},
      {"statusword", c.objects.statusword, 16, true, true},
      {"position_actual", c.objects.position_actual, 32, true, true},
      {"digital_inputs", c.objects.digital_inputs, 32, true, has_buttons},
  };
  for (const auto& nd : needs) {
    const PdoParse& p = nd.in_tpdo ? tp : rp;
    if (!nd.needed || !p.complete) continue;
    const std::string key = nd.in_tpdo ? "tpdo" : "rpdo";
    const auto it = std::find_if(p.mapped.begin(), p.mapped.end(), [&](const auto& m) { return m.index == nd.index; });
    const std::string expected = std::string(nd.what) + " (" + num(nd.index, true) + ":00, " +
                                 std::to_string(nd.bits) + " bits) mapped in a " + (nd.in_tpdo ? "TPDO" : "RPDO");
    if (it == p.mapped.end()) {
      s.sink().add(s.where(key), s.field(key), expected, "it in no " + std::string(nd.in_tpdo ? "TPDO" : "RPDO"));
    } else if (it->bits != nd.bits) {
      s.sink().add(s.where(key), s.field(key), expected, "it mapped with " + std::to_string(it->bits) + " bits");
    }
  }
  button_bits = 32;
  s.finish();
  return c;
}

void parse_bus(Section& top, ArmConfig& cfg, const Context& ctx, bool has_buttons, std::optional<int>& button_bits,
               bool& button_source_known) {
  const bool sim = ctx.backend == Backend::kSim;
  const toml::table* bt = top.table("bus", (ctx.backend && !sim) ? kReq : kOpt);
  // The button word is known once the backend's own section has been read (sim needs none).
  button_source_known = sim;
  if (sim) {
    cfg.sim = SimBusConfig{};
    button_bits = 32;
  }
  if (bt == nullptr) return;
  Section bus(top.sink(), *bt, "bus");
  const std::string_view keys[] = {"sim", "usb", "modbus", "canopen"};
  const Backend kinds[] = {Backend::kSim, Backend::kUsb, Backend::kModbus, Backend::kCanopen};
  for (std::size_t i = 0; i < 4; ++i) {
    const std::string_view key = keys[i];
    const bool matches = ctx.backend == kinds[i];
    const toml::node* n = bus.get(key);
    if (n == nullptr) {
      if (matches && !sim) bus.missing(key, "a table [bus." + std::string(key) + "] (backend = \"" + ctx.backend_name + "\")");
      continue;
    }
    if (ctx.backend && !matches) {
      top.sink().add(n->source(), bus.field(key),
                     "only [bus." + std::string(backend_key(*ctx.backend)) + "] (backend = \"" + ctx.backend_name + "\")",
                     "[bus." + std::string(key) + "], the section of backend \"" + std::string(key) + "\"");
      continue;
    }
    const toml::table* t = n->as_table();
    if (t == nullptr) {
      top.sink().add(n->source(), bus.field(key), "a table", describe(*n));
      continue;
    }
    Section s(top.sink(), *t, bus.field(key));
    std::optional<int> bits;
    switch (kinds[i]) {
      case Backend::kSim: cfg.sim = parse_sim(s); bits = 32; break;
      case Backend::kUsb: cfg.usb = parse_usb(s, ctx, bits); break;
      case Backend::kModbus: cfg.modbus = parse_modbus(s, ctx, bits); break;
      case Backend::kCanopen: cfg.canopen = parse_canopen(s, ctx, has_buttons, bits); break;
    }
    if (matches) {
      button_bits = bits;
      button_source_known = true;
    }
  }
  bus.finish();
}

void parse_buttons(Section& top, std::vector<ButtonConfig>& out, const Context& ctx, std::optional<int> button_bits,
                   bool button_source_known) {
  const auto buttons = top.tables("buttons", kOpt, 0, 32);
  if (!buttons || buttons->empty()) return;
  if (button_source_known && !button_bits) {
    std::string source = "a button word in the bus section";
    if (ctx.backend == Backend::kUsb) source = "bus.usb.in_report.buttons";
    if (ctx.backend == Backend::kModbus) source = "bus.modbus.registers.buttons";
    top.sink().add(top.where("buttons"), "buttons", source + " for the buttons to come from", "none");
  }
  const std::int64_t max_bit = button_bits.value_or(32) - 1;
  std::vector<std::pair<std::string, std::size_t>> names;
  std::vector<std::pair<std::int64_t, std::size_t>> bits;
  for (std::size_t i = 0; i < buttons->size(); ++i) {
    const toml::table* t = (*buttons)[i];
    if (t == nullptr) continue;
    Section s(top.sink(), *t, indexed("buttons", i));
    ButtonConfig b;
    if (auto v = s.text("name", kReq, 64)) {
      for (const auto& [other, k] : names) {
        if (other == *v) {
          s.sink().add(s.where("name"), s.field("name"), "a name not used by buttons[" + std::to_string(k) + "]",
                       describe(*t->get("name")));
        }
      }
      names.emplace_back(*v, i);
      b.name = *v;
    }
    if (auto v = s.integer("bit", kReq, 0, max_bit)) {
      for (const auto& [other, k] : bits) {
        if (other == *v) {
          s.sink().add(s.where("bit"), s.field("bit"), "a bit not used by buttons[" + std::to_string(k) + "]",
                       describe(*t->get("bit")));
        }
      }
      bits.emplace_back(*v, i);
      b.bit = static_cast<int>(*v);
    }
    b.action = s.choice<ButtonAction>("action", kOpt,
                                      {{"none", ButtonAction::kNone}, {"clutch", ButtonAction::kClutch},
                                       {"activate", ButtonAction::kActivate}, {"mode", ButtonAction::kMode}})
                   .value_or(ButtonAction::kNone);
    b.active_low = s.boolean("active_low", kOpt).value_or(false);
    s.finish();
    out.push_back(std::move(b));
  }
}

ArmConfig parse_root(const toml::table& root, Sink& sink) {
  ArmConfig cfg;
  cfg.source = sink.file;
  Section top(sink, root, "");
  cfg.schema_version = static_cast<int>(top.integer("schema_version", kReq, 1, 1).value_or(1));
  cfg.name = top.text("name", kReq, 64).value_or("");
  cfg.description = top.text("description", kOpt, 1024).value_or("");
  Context ctx;
  ctx.backend = top.choice<Backend>("backend", kReq,
                                    {{"sim", Backend::kSim}, {"usb", Backend::kUsb}, {"modbus", Backend::kModbus},
                                     {"canopen", Backend::kCanopen}});
  if (ctx.backend) {
    cfg.backend = *ctx.backend;
    ctx.backend_name = std::string(backend_key(*ctx.backend));
  }

  if (const toml::table* kt = top.table("kinematics", kReq)) {
    Section k(sink, *kt, "kinematics");
    parse_kinematics(k, cfg.kinematics, ctx);
    k.finish();
  }
  parse_joints(top, cfg.joints, ctx);
  parse_actuators(top, cfg.actuators, ctx);

  // Without a usable model, size the per-joint bus fields by the joints table.
  Context bus_ctx = ctx;
  if (!bus_ctx.n && !cfg.joints.empty()) bus_ctx.n = static_cast<int>(cfg.joints.size());

  const toml::node* bn = root.get("buttons");
  const bool has_buttons = bn != nullptr && bn->as_array() != nullptr && !bn->as_array()->empty();
  std::optional<int> button_bits;
  bool button_source_known = false;
  parse_bus(top, cfg, bus_ctx, has_buttons, button_bits, button_source_known);
  parse_safety(top, cfg.safety, bus_ctx);
  parse_buttons(top, cfg.buttons, ctx, button_bits, button_source_known);
  top.finish();
  return cfg;
}

struct Parsed {
  ConfigReport report;
  std::optional<ArmConfig> config;
};

Parsed parse_text(std::string_view text, const std::string& source_name) {
  Parsed out;
  out.report.file = source_name;
  Sink sink;
  sink.file = source_name;
  try {
    const toml::table root = toml::parse(text, std::string_view(source_name));
    ArmConfig cfg = parse_root(root, sink);
    if (sink.errors.empty()) out.config = std::move(cfg);
  } catch (const toml::parse_error& e) {
    sink.add(e.source(), "", "valid TOML", "a syntax error", "TOML syntax error: " + std::string(e.description()));
  }
  std::stable_sort(sink.errors.begin(), sink.errors.end(), [](const ConfigError& a, const ConfigError& b) {
    return std::pair(a.line, a.column) < std::pair(b.line, b.column);
  });
  out.report.errors = std::move(sink.errors);
  return out;
}

// Reads a whole file; on failure returns the reason.
std::optional<std::string> read_file(const std::string& path, std::string& text, ErrorCode& code) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) {
    code = errno == ENOENT ? ErrorCode::kNotFound : ErrorCode::kSystem;
    return "cannot open: " + std::string(std::strerror(errno));
  }
  text.clear();
  char buf[65536];
  std::size_t got = 0;
  while ((got = std::fread(buf, 1, sizeof buf, f)) > 0) {
    text.append(buf, got);
    if (text.size() > kMaxFileBytes) {
      std::fclose(f);
      code = ErrorCode::kInvalid;
      return "file is larger than " + std::to_string(kMaxFileBytes >> 20) + " MiB; not an arm config";
    }
  }
  const bool failed = std::ferror(f) != 0;
  const int err = errno;
  std::fclose(f);
  if (failed) {
    code = ErrorCode::kSystem;
    return "cannot read: " + std::string(std::strerror(err));
  }
  return std::nullopt;
}

ConfigReport unreadable(const std::string& path, std::string why) {
  ConfigReport r;
  r.file = path;
  r.readable = false;
  ConfigError e;
  e.file = path;
  e.expected = "a readable file";
  e.found = why;
  e.message = std::move(why);
  r.errors.push_back(std::move(e));
  return r;
}

}  // namespace

int field_size(FieldType t) noexcept {
  switch (t) {
    case FieldType::kU8:
    case FieldType::kI8: return 1;
    case FieldType::kU16:
    case FieldType::kI16: return 2;
    case FieldType::kU32:
    case FieldType::kI32:
    case FieldType::kF32: return 4;
  }
  return 1;
}

ConfigReport validate_arm_config_text(std::string_view text, const std::string& source_name) {
  return parse_text(text, source_name).report;
}

ConfigReport validate_arm_config_file(const std::string& path) {
  std::string text;
  ErrorCode code{};
  if (auto why = read_file(path, text, code)) return unreadable(path, *why);
  return validate_arm_config_text(text, path);
}

Result<ArmConfig> load_arm_config_text(std::string_view text, const std::string& source_name) {
  Parsed p = parse_text(text, source_name);
  if (!p.config) return Error{ErrorCode::kInvalid, format_report(p.report)};
  return std::move(*p.config);
}

Result<ArmConfig> load_arm_config(const std::string& path) {
  std::string text;
  ErrorCode code{};
  if (auto why = read_file(path, text, code)) return Error{code, path + ": " + *why};
  return load_arm_config_text(text, path);
}

std::string format_report(const ConfigReport& report) {
  std::string out;
  for (const ConfigError& e : report.errors) {
    out += e.file;
    if (e.line > 0) out += ":" + std::to_string(e.line) + ":" + std::to_string(e.column);
    out += ": ";
    if (!e.field.empty()) out += e.field + ": ";
    out += e.message;
    out += '\n';
  }
  return out;
}

std::string calibration_path(const std::string& config_path) {
  const std::string ext = ".toml";
  const bool has_ext = config_path.size() >= ext.size() && config_path.compare(config_path.size() - ext.size(), ext.size(), ext) == 0;
  return (has_ext ? config_path.substr(0, config_path.size() - ext.size()) : config_path) + ".calibration.toml";
}

std::string calibration_text(const ArmConfig& config, std::span<const double> offsets, const std::string& note) {
  std::string out = "# Encoder offsets for arm '" + config.name + "' (" + config.source + "), written by lancetctl calibrate.\n";
  out += "# " + note + "\n";
  out += "# Loaded after the config by lancet-rt and lancetctl; delete this file to use the config's offsets.\n";
  out += "arm = " + quoted(config.name) + "\n";
  for (std::size_t j = 0; j < config.joints.size(); ++j) {
    const JointConfig& jc = config.joints[j];
    const double v = j < offsets.size() ? offsets[j] : jc.offset;
    char buf[64];
    if (jc.type == JointType::kRevolute) std::snprintf(buf, sizeof buf, "%.9g", v * 180.0 / std::numbers::pi);
    else std::snprintf(buf, sizeof buf, "%.9g", v * 1e3);
    out += "\n[[joints]]\nname = " + quoted(jc.name) + "\n" + (jc.type == JointType::kRevolute ? "offset_deg = " : "offset_mm = ") + buf + "\n";
  }
  return out;
}

Result<bool> apply_calibration_file(ArmConfig& config, const std::string& path) {
  std::string text;
  ErrorCode code{};
  if (auto why = read_file(path, text, code)) {
    if (code == ErrorCode::kNotFound) return false;
    return Error{code, path + ": " + *why};
  }
  const auto where = [&](const toml::node& n) {
    return path + ":" + std::to_string(n.source().begin.line) + ":" + std::to_string(n.source().begin.column) + ": ";
  };
  toml::table root;
  try {
    root = toml::parse(text, std::string_view(path));
  } catch (const toml::parse_error& e) {
    return Error{ErrorCode::kInvalid, path + ":" + std::to_string(e.source().begin.line) + ":" + std::to_string(e.source().begin.column) +
                                          ": TOML syntax error: " + std::string(e.description())};
  }
  for (const auto& [key, node] : root)
    if (key.str() != "arm" && key.str() != "joints") return Error{ErrorCode::kInvalid, where(node) + std::string(key.str()) + ": unknown key (expected arm, joints)"};
  const auto* arm_name = root.get_as<std::string>("arm");
  if (arm_name == nullptr) return Error{ErrorCode::kInvalid, path + ": arm: missing (the name of the arm this calibration is for)"};
  if (arm_name->get() != config.name)
    return Error{ErrorCode::kInvalid, where(*arm_name) + "arm: this calibration is for '" + arm_name->get() + "', the config is '" + config.name + "'"};
  const auto* joints = root.get_as<toml::array>("joints");
  if (joints == nullptr || !joints->is_array_of_tables() || joints->size() != config.joints.size())
    return Error{ErrorCode::kInvalid, path + ": joints: expected " + std::to_string(config.joints.size()) + " [[joints]] tables, one per joint of the config"};
  std::vector<double> offsets(config.joints.size());
  for (std::size_t j = 0; j < config.joints.size(); ++j) {
    const toml::table& t = *joints->get(j)->as_table();
    const JointConfig& jc = config.joints[j];
    const std::string field = "joints[" + std::to_string(j) + "]";
    const std::string key = jc.type == JointType::kRevolute ? "offset_deg" : "offset_mm";
    for (const auto& [k, n] : t)
      if (k.str() != "name" && k.str() != key) return Error{ErrorCode::kInvalid, where(n) + field + "." + std::string(k.str()) + ": unknown key (expected name, " + key + ")"};
    const auto* name = t.get_as<std::string>("name");
    if (name == nullptr || name->get() != jc.name)
      return Error{ErrorCode::kInvalid, where(t) + field + ".name: expected '" + jc.name + "'" + (name ? ", found '" + name->get() + "'" : std::string(", missing"))};
    const toml::node* v = t.get(key);
    const std::optional<double> num = v != nullptr ? v->value<double>() : std::nullopt;
    if (!num || !std::isfinite(*num)) return Error{ErrorCode::kInvalid, where(t) + field + "." + key + ": expected a finite number"};
    offsets[j] = jc.type == JointType::kRevolute ? *num * std::numbers::pi / 180.0 : *num * 1e-3;
  }
  for (std::size_t j = 0; j < offsets.size(); ++j) config.joints[j].offset = offsets[j];
  return true;
}

double joint_position_from_counts(const JointConfig& j, std::int64_t counts) noexcept {
  const double per_output_rev = static_cast<double>(j.counts_per_rev) * j.gear_ratio;
  const double travel = j.type == JointType::kRevolute ? 2.0 * std::numbers::pi : j.lead;
  return j.direction * travel * static_cast<double>(counts) / per_output_rev + j.offset;
}

double motor_current_for_joint_torque(const JointConfig& j, const ActuatorConfig& a, double tau) noexcept {
  // Output-side torque: tau itself (revolute) or force × lead / 2π (prismatic); the gear divides it.
  const double output = j.type == JointType::kRevolute ? tau : tau * j.lead / (2.0 * std::numbers::pi);
  return j.direction * output / (j.gear_ratio * a.torque_constant);
}

}  // namespace lancet::arm
