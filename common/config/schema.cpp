#include "config/schema.hpp"

#include <algorithm>
#include <array>
#include <utility>

namespace lancet::config {

void Sink::add(const toml::source_region& at, std::string field, std::string expected, std::string found,
               std::string message) {
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

std::optional<toml::table> parse_toml(std::string_view text, Sink& sink) {
  try {
    return toml::parse(text, std::string_view(sink.file));
  } catch (const toml::parse_error& e) {
    sink.add(e.source(), "", "valid TOML", "a syntax error", "TOML syntax error: " + std::string(e.description()));
  }
  return std::nullopt;
}

std::string describe(const toml::node& n, bool hex) {
  switch (n.type()) {
    case toml::node_type::string: return "string " + quote(n.as_string()->get());
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

std::string Range::text() const {
  const bool has_lo = std::isfinite(lo), has_hi = std::isfinite(hi);
  if (has_lo && has_hi) return "a number in " + std::string(lo_open ? "(" : "[") + num(lo) + ", " + num(hi) + (hi_open ? ")" : "]");
  if (has_lo) return std::string("a number ") + (lo_open ? "> " : ">= ") + num(lo);
  if (has_hi) return std::string("a number ") + (hi_open ? "< " : "<= ") + num(hi);
  return "a finite number";
}

namespace {

std::string one_of_text(std::span<const std::int64_t> allowed) {
  std::string expected = "one of ";
  for (std::size_t i = 0; i < allowed.size(); ++i) expected += (i ? ", " : "") + num(allowed[i]);
  return expected;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Node-level reads

std::optional<std::int64_t> read_integer(Sink& s, const toml::node& n, const std::string& field, std::int64_t lo,
                                         std::int64_t hi, bool hex) {
  const auto* v = n.as_integer();
  if (v == nullptr || v->get() < lo || v->get() > hi) {
    s.add(n.source(), field, int_range_text(lo, hi, hex), describe(n, hex));
    return std::nullopt;
  }
  return v->get();
}

std::optional<std::int64_t> read_integer_in(Sink& s, const toml::node& n, const std::string& field,
                                            std::span<const std::int64_t> allowed) {
  const auto* v = n.as_integer();
  if (v == nullptr || std::find(allowed.begin(), allowed.end(), v->get()) == allowed.end()) {
    s.add(n.source(), field, one_of_text(allowed), describe(n));
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

std::optional<Vec3> read_vec3(Sink& s, const toml::node& n, const std::string& field, double scale) {
  const auto* a = n.as_array();
  if (a == nullptr || a->size() != 3) {
    s.add(n.source(), field, "an array of 3 numbers [x, y, z]", describe(n));
    return std::nullopt;
  }
  std::array<double, 3> v{};
  bool ok = true;
  for (std::size_t i = 0; i < 3; ++i) {
    const auto x = read_number(s, *a->get(i), indexed(field, i), kAny);
    if (x) v[i] = *x * scale;
    ok = ok && x.has_value();
  }
  if (!ok) return std::nullopt;
  return Vec3{v[0], v[1], v[2]};
}

std::string choice_message(const toml::node& n, const std::string& expected, std::span<const std::string_view> names) {
  std::string message = "expected " + expected + ", found " + describe(n);
  if (const auto* v = n.as_string()) {
    const std::string_view best = nearest(v->get(), names);
    if (!best.empty()) message += " (did you mean " + quote(best) + "?)";
  }
  return message;
}

// ---------------------------------------------------------------------------------------------
// Section

Section::Section(Sink& sink, const toml::table& table, std::string path)
    : sink_(sink), table_(table), path_(std::move(path)) {}

std::string Section::field(std::string_view key) const {
  return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
}

const toml::source_region& Section::where(std::string_view key) const {
  const toml::node* n = table_.get(key);
  return n != nullptr ? n->source() : table_.source();
}

const toml::node* Section::get(std::string_view key) {
  if (std::find(known_.begin(), known_.end(), key) == known_.end()) known_.emplace_back(key);
  return table_.get(key);
}

void Section::skip(std::initializer_list<std::string_view> keys) {
  for (const auto k : keys) (void)get(k);
}

void Section::forbid(std::string_view key, const std::string& only_for) {
  if (const toml::node* n = get(key)) {
    sink_.add(n->source(), field(key), "no " + std::string(key) + " (it is only for " + only_for + ")", describe(*n));
  }
}

void Section::missing(std::string_view key, const std::string& expected) {
  sink_.add(where(), field(key), expected, "nothing", "required key is missing; expected " + expected);
}

std::optional<std::int64_t> Section::integer(std::string_view key, Need need, std::int64_t lo, std::int64_t hi, bool hex) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (need == kReq) missing(key, int_range_text(lo, hi, hex));
    return std::nullopt;
  }
  return read_integer(sink_, *n, field(key), lo, hi, hex);
}

std::optional<std::int64_t> Section::integer_in(std::string_view key, Need need, std::span<const std::int64_t> allowed) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (need == kReq) missing(key, one_of_text(allowed));
    return std::nullopt;
  }
  return read_integer_in(sink_, *n, field(key), allowed);
}

std::optional<double> Section::number(std::string_view key, Need need, Range range) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (need == kReq) missing(key, range.text());
    return std::nullopt;
  }
  return read_number(sink_, *n, field(key), range);
}

std::optional<std::string> Section::text(std::string_view key, Need need, std::size_t max_len) {
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

std::optional<bool> Section::boolean(std::string_view key, Need need) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (need == kReq) missing(key, "true or false");
    return std::nullopt;
  }
  if (const auto* v = n->as_boolean()) return v->get();
  sink_.add(n->source(), field(key), "true or false", describe(*n));
  return std::nullopt;
}

std::optional<Vec3> Section::vec3(std::string_view key, Need need, double scale) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (need == kReq) missing(key, "an array of 3 numbers [x, y, z]");
    return std::nullopt;
  }
  return read_vec3(sink_, *n, field(key), scale);
}

const toml::table* Section::table(std::string_view key, Need need) {
  const toml::node* n = get(key);
  const std::string expected = "a table [" + field(key) + "]";
  if (n == nullptr) {
    if (need == kReq) missing(key, expected);
    return nullptr;
  }
  if (const auto* t = n->as_table()) return t;
  sink_.add(n->source(), field(key), expected, describe(*n));
  return nullptr;
}

const toml::array* Section::array(std::string_view key, Need need, const std::string& expected) {
  return array(key, need, 0, std::numeric_limits<std::size_t>::max(), expected);
}

const toml::array* Section::array(std::string_view key, Need need, std::size_t min, std::size_t max,
                                  const std::string& expected) {
  const toml::node* n = get(key);
  if (n == nullptr) {
    if (need == kReq) missing(key, expected);
    return nullptr;
  }
  const auto* a = n->as_array();
  if (a == nullptr || a->size() < min || a->size() > max) {
    sink_.add(n->source(), field(key), expected, describe(*n));
    return nullptr;
  }
  return a;
}

std::optional<std::vector<const toml::table*>> Section::tables(std::string_view key, Need need, std::size_t min,
                                                               std::size_t max) {
  const std::string expected = "an array of " + std::to_string(min) + ".." + std::to_string(max) + " tables [[" +
                               field(key) + "]]";
  const toml::array* a = array(key, need, min, max, expected);
  if (a == nullptr) return std::nullopt;
  std::vector<const toml::table*> out;
  for (std::size_t i = 0; i < a->size(); ++i) {
    const toml::node& e = *a->get(i);
    const auto* t = e.as_table();
    if (t == nullptr) sink_.add(e.source(), indexed(field(key), i), "a table", describe(e));
    out.push_back(t);
  }
  return out;
}

void Section::finish() {
  for (auto&& [k, v] : table_) {
    const std::string_view key = k.str();
    if (std::find(known_.begin(), known_.end(), key) != known_.end()) continue;
    std::string list;
    for (const auto& kn : known_) list += (list.empty() ? "" : ", ") + kn;
    const std::string_view best = nearest(key, known_);
    std::string message = "unknown key " + quote(key);
    if (!best.empty()) message += " (did you mean " + quote(best) + "?)";
    message += list.empty() ? "; this table takes no keys" : "; known keys here: " + list;
    sink_.add(k.source(), field(key), list.empty() ? "no keys" : "one of: " + list, "unknown key " + quote(key),
              message);
  }
}

}  // namespace lancet::config
