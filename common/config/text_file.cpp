#include "config/text_file.hpp"

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace lancet::config {

Result<std::string> read_text_file(const std::string& path, std::size_t max_bytes, std::string_view what) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) {
    const int err = errno;
    return Error{err == ENOENT ? ErrorCode::kNotFound : ErrorCode::kSystem, "cannot open: " + std::string(std::strerror(err))};
  }
  std::string text;
  char buf[65536];
  std::size_t got = 0;
  while ((got = std::fread(buf, 1, sizeof buf, f)) > 0) {
    text.append(buf, got);
    if (text.size() > max_bytes) {
      std::fclose(f);
      return Error{ErrorCode::kInvalid,
                   "file is larger than " + std::to_string(max_bytes >> 20) + " MiB; not " + std::string(what)};
    }
  }
  const bool failed = std::ferror(f) != 0;
  const int err = errno;
  std::fclose(f);
  if (failed) return Error{ErrorCode::kSystem, "cannot read: " + std::string(std::strerror(err))};
  return text;
}

}  // namespace lancet::config
