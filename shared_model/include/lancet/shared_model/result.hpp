#pragma once
// Result<T>: a value or an Error with a human-readable message. Used for runtime failures at
// load/configure time (files, segments, configs); never thrown on the real-time path.

#include <cassert>
#include <string>
#include <utility>
#include <variant>

namespace lancet {

enum class ErrorCode {
  kNotFound,    ///< the thing (file, segment) does not exist
  kInUse,       ///< owned by a live process
  kMismatch,    ///< exists but is incompatible (layout hash, size, magic)
  kNotReady,    ///< exists but is not initialised yet: try again
  kStale,       ///< left behind by a process that died
  kSystem,      ///< a system call failed
  kInvalid,     ///< bad argument or input
  kUnsupported, ///< the operation does not exist for this object (a backend without it)
};

struct Error {
  ErrorCode code;
  std::string message;  ///< names the object, the field, expected vs found, and what to do
};

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}            // NOLINT: implicit by design
  Result(Error error) : v_(std::move(error)) {}        // NOLINT
  [[nodiscard]] bool ok() const noexcept { return v_.index() == 0; }
  explicit operator bool() const noexcept { return ok(); }
  T& value() & { assert(ok() && "Result::value on an error"); return std::get<0>(v_); }
  T&& value() && { assert(ok() && "Result::value on an error"); return std::get<0>(std::move(v_)); }
  const Error& error() const { assert(!ok() && "Result::error on a value"); return std::get<1>(v_); }

 private:
  std::variant<T, Error> v_;
};

/// Success, or the Error that stopped a step (configure, activate, a file write ...).
template <>
class [[nodiscard]] Result<void> {
 public:
  Result() = default;                                   ///< success
  Result(Error error) : error_(std::move(error)), failed_(true) {}  // NOLINT: implicit by design
  static Result success() { return {}; }
  static Result failure(ErrorCode code, std::string message) { return Error{code, std::move(message)}; }
  [[nodiscard]] bool ok() const noexcept { return !failed_; }
  explicit operator bool() const noexcept { return ok(); }
  const Error& error() const { assert(!ok() && "Result::error on a success"); return error_; }
  Error& error() { assert(!ok() && "Result::error on a success"); return error_; }

 private:
  Error error_{ErrorCode::kInvalid, {}};
  bool failed_ = false;
};

}  // namespace lancet
