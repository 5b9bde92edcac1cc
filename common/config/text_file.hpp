#pragma once
// Reading a config file whole, with a size limit (a config is a few kB: a huge file is a wrong
// path, not a config). Configure time only.

#include <cstddef>
#include <string>
#include <string_view>

#include "lancet/shared_model/result.hpp"

namespace lancet::config {

/// The file's bytes. Errors (the message is the reason alone; callers put the path in front):
/// kNotFound "cannot open: ..." when it does not exist, kSystem "cannot open: ..." or "cannot
/// read: ..." for other failures, kInvalid "file is larger than N MiB; not <what>" past
/// max_bytes (`what`: e.g. "an arm config").
[[nodiscard]] Result<std::string> read_text_file(const std::string& path, std::size_t max_bytes, std::string_view what);

}  // namespace lancet::config
