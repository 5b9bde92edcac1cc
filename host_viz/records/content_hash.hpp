#pragma once
// SHA-256 (OpenSSL's libcrypto) of a recording file or of a text: the content hash that keys an
// attempt (the same recording imported twice is the same attempt, wherever the file lies) and
// the scenario hash (which version of a scenario an attempt was scored against).

#include <string>
#include <string_view>

#include "lancet/shared_model/result.hpp"

namespace lancet::records {

/// The SHA-256 of `text` as 64 lowercase hex digits.
[[nodiscard]] std::string sha256_hex(std::string_view text);
/// The SHA-256 of the file's bytes as 64 lowercase hex digits; an error names the file.
[[nodiscard]] Result<std::string> sha256_file(const std::string& path);

}  // namespace lancet::records
