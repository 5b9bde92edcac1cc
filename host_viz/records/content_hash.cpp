// SHA-256 through OpenSSL's EVP interface (records/content_hash.hpp).

#include "records/content_hash.hpp"

#include <openssl/evp.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

namespace lancet::records {
namespace {

struct DigestFree {
  void operator()(EVP_MD_CTX* c) const noexcept { EVP_MD_CTX_free(c); }
};
struct FileClose {
  void operator()(std::FILE* f) const noexcept { std::fclose(f); }
};

std::string hex(const unsigned char* bytes, unsigned n) {
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string s(2 * std::size_t{n}, '0');
  for (unsigned i = 0; i < n; ++i) {
    s[2 * i] = kDigits[bytes[i] >> 4];
    s[2 * i + 1] = kDigits[bytes[i] & 15];
  }
  return s;
}

// Feeds `next` chunks into a SHA-256 until it returns 0 bytes; returns the hex digest, or "" when
// OpenSSL fails.
template <class Next>
std::string digest(Next next) {
  const std::unique_ptr<EVP_MD_CTX, DigestFree> ctx(EVP_MD_CTX_new());
  if (!ctx || EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) != 1) return {};
  std::vector<char> buf(1 << 16);
  for (std::size_t n = 0; (n = next(buf)) > 0;) {
    if (EVP_DigestUpdate(ctx.get(), buf.data(), n) != 1) return {};
  }
  unsigned char out[EVP_MAX_MD_SIZE];
  unsigned len = 0;
  if (EVP_DigestFinal_ex(ctx.get(), out, &len) != 1) return {};
  return hex(out, len);
}

}  // namespace

std::string sha256_hex(std::string_view text) {
  return digest([&text](std::vector<char>& buf) {
    const std::size_t n = std::min(buf.size(), text.size());
    std::memcpy(buf.data(), text.data(), n);
    text.remove_prefix(n);
    return n;
  });
}

Result<std::string> sha256_file(const std::string& path) {
  const std::unique_ptr<std::FILE, FileClose> f(std::fopen(path.c_str(), "rb"));
  if (!f) return Error{errno == ENOENT ? ErrorCode::kNotFound : ErrorCode::kSystem, path + ": cannot open: " + std::strerror(errno)};
  bool read_error = false;
  std::string h = digest([&](std::vector<char>& buf) {
    const std::size_t n = std::fread(buf.data(), 1, buf.size(), f.get());
    read_error = read_error || std::ferror(f.get()) != 0;
    return n;
  });
  if (read_error) return Error{ErrorCode::kSystem, path + ": cannot read"};
  if (h.empty()) return Error{ErrorCode::kSystem, path + ": SHA-256 failed (OpenSSL)"};
  return h;
}

}  // namespace lancet::records
