#pragma once
// The schema reader of Lancet's TOML files (arm configs, calibration files, training scenarios).
//
// A Sink collects every error (file, line, column, dotted field path, expected vs found); a
// Section reads one TOML table against its schema through typed getters (integers and numbers
// with ranges, strings, booleans, named choices, [x, y, z] vectors, sub-tables, arrays),
// remembers which keys the schema asked for, and finish() reports the rest as unknown keys, with
// the nearest known key for a typo. A getter that finds a problem records it and returns nullopt
// (or nullptr), so a loader carries on and one run reports everything.
//
// Configure time only: everything here allocates. toml++ is part of this interface (the loaders
// read nodes of their own shape through it); loaders' public headers include config/error.hpp
// instead, which is free of it.

// toml++ 3.3 checks two parser preconditions with assert(), and malformed input can break them
// ("[" followed by a newline, "[[ # x", "a = [}]"): builds without NDEBUG would abort instead of
// throwing parse_error (upstream: marzer/tomlplusplus PR #301). With the check off the parser
// reports those inputs as ordinary syntax errors, as release builds do (the fuzz targets in
// tests/fuzz cover it). Matters in header-only mode; the packaged shared library is built without
// these asserts.
#ifndef TOML_ASSERT
#define TOML_ASSERT(expr) static_cast<void>(0)
#endif
#include <toml++/toml.h>

#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "config/describe.hpp"
#include "config/error.hpp"
#include "lancet/shared_model/geometry.hpp"

namespace lancet::config {

// ---------------------------------------------------------------------------------------------
// Errors

/// Collects the errors of one file.
struct Sink {
  std::string file;                 ///< names the file in every error
  std::vector<ConfigError> errors;  ///< in the order found (sort_errors orders them by place)

  /// Records an error at `at` (line and column 1 when toml++ has no place). The message is
  /// "expected <expected>, found <found>" unless `message` says otherwise.
  void add(const toml::source_region& at, std::string field, std::string expected, std::string found,
           std::string message = {});
};

/// Parses `text` as TOML. A syntax error is recorded in `sink` (no field; "TOML syntax error:
/// <what toml++ says>") and gives nullopt.
[[nodiscard]] std::optional<toml::table> parse_toml(std::string_view text, Sink& sink);

/// How a node reads in a message: `string "x"`, `integer 3` (hex: `integer 0x0003`), `float 2.5`,
/// `boolean true`, `array of 2`, `table`, `date`, `time`, `date-time`.
[[nodiscard]] std::string describe(const toml::node& n, bool hex = false);

// ---------------------------------------------------------------------------------------------
// Value rules

enum class Need { kRequired, kOptional };
inline constexpr Need kReq = Need::kRequired;
inline constexpr Need kOpt = Need::kOptional;

/// Allowed interval of a number as the file writes it (always finite).
struct Range {
  double lo = -std::numeric_limits<double>::infinity(), hi = std::numeric_limits<double>::infinity();
  bool lo_open = false, hi_open = false;
  [[nodiscard]] bool contains(double v) const {
    return std::isfinite(v) && (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
  }
  /// "a number in [lo, hi)", "a number > lo", ..., "a finite number".
  [[nodiscard]] std::string text() const;
};
inline constexpr Range kAny{};
inline constexpr Range kPositive{0, std::numeric_limits<double>::infinity(), true, false};
/// (0, hi].
constexpr Range positive_up_to(double hi) { return Range{0, hi, true, false}; }

/// One name a choice accepts and the value it stands for.
template <class E>
struct Choice {
  std::string_view name;
  E value;
};

/// `one of "a", "b", "c"`.
template <class E>
std::string choices_text(std::initializer_list<Choice<E>> options) {
  std::string s = "one of ";
  bool first = true;
  for (const auto& o : options) {
    if (!first) s += ", ";
    s += quote(o.name);
    first = false;
  }
  return s;
}

// Node-level reads, for values that are not directly under a key (array elements, values whose
// type decides how they read): record an error and return nullopt when the node does not fit.

/// An integer in lo..hi (hex: bounds and value shown as 0x%04X).
std::optional<std::int64_t> read_integer(Sink& s, const toml::node& n, const std::string& field, std::int64_t lo,
                                         std::int64_t hi, bool hex = false);
/// An integer that is one of `allowed`.
std::optional<std::int64_t> read_integer_in(Sink& s, const toml::node& n, const std::string& field,
                                            std::span<const std::int64_t> allowed);
/// An integer or a float, within `range`.
std::optional<double> read_number(Sink& s, const toml::node& n, const std::string& field, Range range);
/// An array of exactly three finite numbers, each multiplied by `scale` (file units into SI).
std::optional<Vec3> read_vec3(Sink& s, const toml::node& n, const std::string& field, double scale);

/// The message of a string that names none of the choices: with "did you mean" for a near miss.
std::string choice_message(const toml::node& n, const std::string& expected, std::span<const std::string_view> names);

/// A string naming one of `options`; a near miss gets a "did you mean".
template <class E>
std::optional<E> read_choice(Sink& s, const toml::node& n, const std::string& field,
                             std::initializer_list<Choice<E>> options) {
  std::vector<std::string_view> names;
  if (const auto* v = n.as_string()) {
    for (const auto& o : options) {
      if (o.name == v->get()) return o.value;
      names.push_back(o.name);
    }
  }
  const std::string expected = choices_text(options);
  s.add(n.source(), field, expected, describe(n), choice_message(n, expected, names));
  return std::nullopt;
}

// ---------------------------------------------------------------------------------------------
// Section: one TOML table read against the schema

/// One table of a file. `path` is its dotted field path ("" for the root): keys are reported as
/// path.key. A required key that is absent is reported at the table ("required key is missing;
/// expected ..."); an optional one gives nullopt silently. Call finish() once every key of the
/// schema has been asked for.
class Section {
 public:
  Section(Sink& sink, const toml::table& table, std::string path);
  Section(const Section&) = delete;
  Section& operator=(const Section&) = delete;

  /// path.key (or key at the root).
  [[nodiscard]] std::string field(std::string_view key) const;
  /// Where the table is.
  [[nodiscard]] const toml::source_region& where() const { return table_.source(); }
  /// Where a key's value is, or the table when the key is absent.
  [[nodiscard]] const toml::source_region& where(std::string_view key) const;
  [[nodiscard]] bool has(std::string_view key) const { return table_.get(key) != nullptr; }
  Sink& sink() { return sink_; }

  /// The key's node (nullptr when absent); marks the key as part of the schema here.
  const toml::node* get(std::string_view key);
  /// Marks keys as belonging here without reading them (a section whose variant is unknown).
  void skip(std::initializer_list<std::string_view> keys);
  /// A key that must not appear in this variant of the section (`only_for`: where it belongs).
  void forbid(std::string_view key, const std::string& only_for);
  /// Reports a required key as missing.
  void missing(std::string_view key, const std::string& expected);

  std::optional<std::int64_t> integer(std::string_view key, Need need, std::int64_t lo, std::int64_t hi, bool hex = false);
  std::optional<std::int64_t> integer_in(std::string_view key, Need need, std::span<const std::int64_t> allowed);
  std::optional<double> number(std::string_view key, Need need, Range range);
  /// A non-empty string of at most max_len bytes.
  std::optional<std::string> text(std::string_view key, Need need, std::size_t max_len = 256);
  std::optional<bool> boolean(std::string_view key, Need need);
  /// An array of exactly three numbers, each multiplied by `scale` (file units into SI).
  std::optional<Vec3> vec3(std::string_view key, Need need, double scale);

  template <class E>
  std::optional<E> choice(std::string_view key, Need need, std::initializer_list<Choice<E>> options) {
    const toml::node* n = get(key);
    if (n == nullptr) {
      if (need == kReq) missing(key, choices_text(options));
      return std::nullopt;
    }
    return read_choice(sink_, *n, field(key), options);
  }

  /// A sub-table (`[path.key]` or an inline table).
  const toml::table* table(std::string_view key, Need need);
  /// An array of any size; `expected` describes it in errors.
  const toml::array* array(std::string_view key, Need need, const std::string& expected);
  /// An array of min..max elements.
  const toml::array* array(std::string_view key, Need need, std::size_t min, std::size_t max, const std::string& expected);
  /// An array of tables ([[key]] or key = [{...}]) with min..max entries. Elements that are not
  /// tables are reported and come back as nullptr, so indices still match the file.
  std::optional<std::vector<const toml::table*>> tables(std::string_view key, Need need, std::size_t min, std::size_t max);

  /// Reports every key of the table the schema did not ask for.
  void finish();

 private:
  Sink& sink_;
  const toml::table& table_;
  std::string path_;
  std::vector<std::string> known_;
};

/// The values one key takes across the entries of a list (the names of [[joints]], the bits of
/// [[buttons]]): a value an earlier entry has is reported at this entry's key, once per earlier
/// entry, as "expected a <what> not used by <list>[k]".
template <class T>
class UniqueValues {
 public:
  /// `list`: the list's field path ("joints"); `what`: the value's name in messages ("name").
  UniqueValues(std::string list, std::string what) : list_(std::move(list)), what_(std::move(what)) {}

  /// Checks the value of `key` in entry `index` of the list (read through `s`) and remembers it.
  void check(Section& s, std::string_view key, const T& value, std::size_t index) {
    for (const auto& [other, k] : seen_) {
      if (other == value) {
        s.sink().add(s.where(key), s.field(key), "a " + what_ + " not used by " + indexed(list_, k), describe(*s.get(key)));
      }
    }
    seen_.emplace_back(value, index);
  }

 private:
  std::string list_, what_;
  std::vector<std::pair<T, std::size_t>> seen_;
};

}  // namespace lancet::config
