// Values of records/sql.hpp, read the same way whichever back end returned them.

#include "records/sql.hpp"

#include <cmath>
#include <cstdlib>
#include <limits>

namespace lancet::records::sql {

bool is_null(const Value& v) noexcept { return std::holds_alternative<std::monostate>(v); }

std::int64_t as_int(const Value& v) {
  if (const auto* n = std::get_if<std::int64_t>(&v)) return *n;
  if (const auto* d = std::get_if<double>(&v)) return static_cast<std::int64_t>(*d);
  if (const auto* s = std::get_if<std::string>(&v)) return std::strtoll(s->c_str(), nullptr, 10);
  return 0;
}

double as_double(const Value& v) {
  if (const auto* d = std::get_if<double>(&v)) return *d;
  if (const auto* n = std::get_if<std::int64_t>(&v)) return static_cast<double>(*n);
  if (const auto* s = std::get_if<std::string>(&v)) return std::strtod(s->c_str(), nullptr);
  return std::numeric_limits<double>::quiet_NaN();
}

std::string as_text(const Value& v) {
  if (const auto* s = std::get_if<std::string>(&v)) return *s;
  if (const auto* n = std::get_if<std::int64_t>(&v)) return std::to_string(*n);
  if (const auto* d = std::get_if<double>(&v)) return std::to_string(*d);
  return {};
}

Result<void> Connection::commit() {
  auto r = execute("COMMIT");
  if (!r.ok()) {
    rollback();
    return r.error();
  }
  return {};
}

Value number_or_null(double v) {
  if (!std::isfinite(v)) return std::monostate{};
  return v;
}

}  // namespace lancet::records::sql
