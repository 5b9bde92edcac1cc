#include "volume/detail/header_fields.hpp"

#include <zlib.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

namespace lancet::volume::detail {

const HeaderField* HeaderFields::find(std::initializer_list<std::string_view> names) const {
  for (std::string_view n : names) {
    const auto it = fields_.find(lower(n));
    if (it != fields_.end()) return &it->second;
  }
  return nullptr;
}

Error HeaderFields::error(const HeaderField& f, const std::string& expected) const {
  return invalid(path_ + ":" + std::to_string(f.line) + ": " + f.name + ": expected " + expected + ", found " +
                 shown(f.value));
}

Error HeaderFields::missing(std::string_view name, std::string_view example) const {
  return invalid(path_ + ": " + std::string(name) + ": expected a line '" + std::string(example) + "', found none");
}

Result<std::int64_t> HeaderFields::integer(const HeaderField& f, std::int64_t lo, std::int64_t hi) const {
  const auto words = split_words(f.value);
  const std::string expected = "an integer in " + std::to_string(lo) + ".." + std::to_string(hi);
  if (words.size() != 1) return error(f, expected);
  const auto v = parse_int(words[0]);
  if (!v || *v < lo || *v > hi) return error(f, expected);
  return *v;
}

Result<std::vector<double>> HeaderFields::numbers(const HeaderField& f, std::size_t n, bool positive) const {
  const auto words = split_words(f.value);
  const std::string expected = std::to_string(n) + (positive ? " positive finite numbers" : " finite numbers");
  if (words.size() != n) return error(f, expected);
  std::vector<double> out;
  for (std::string_view w : words) {
    const auto v = parse_double(w);
    if (!v || !std::isfinite(*v) || (positive && !(*v > 0))) return error(f, expected);
    out.push_back(*v);
  }
  return out;
}

Result<bool> HeaderFields::boolean(const HeaderField& f) const {
  const std::string v = lower(trim(f.value));
  if (v == "true" || v == "1" || v == "yes") return true;
  if (v == "false" || v == "0" || v == "no") return false;
  return error(f, "True or False");
}

Result<std::array<int, 3>> HeaderFields::sizes(const HeaderField& f, std::uint64_t max_voxels) const {
  const auto words = split_words(f.value);
  const std::string expected = "3 integers in 1.." + std::to_string(std::numeric_limits<int>::max()) +
                               " with a product of at most " + std::to_string(max_voxels);
  if (words.size() != 3) return error(f, expected);
  std::array<int, 3> dims{};
  std::uint64_t count = 1;
  for (std::size_t a = 0; a < 3; ++a) {
    const auto v = parse_int(words[a]);
    if (!v || *v < 1 || *v > std::numeric_limits<int>::max()) return error(f, expected);
    dims[a] = static_cast<int>(*v);
    count *= static_cast<std::uint64_t>(*v);  // three factors below 2^31 cannot overflow 2^64
  }
  if (count > max_voxels) return error(f, expected);
  return dims;
}

double determinant3(const std::array<double, 9>& d) {
  return d[0] * (d[4] * d[8] - d[5] * d[7]) - d[1] * (d[3] * d[8] - d[5] * d[6]) + d[2] * (d[3] * d[7] - d[4] * d[6]);
}

std::string header_dir(const std::string& path) {
  const std::filesystem::path p(path);
  return p.has_parent_path() ? p.parent_path().string() : std::string(".");
}

Result<bool> append_file_bytes(const std::string& path, std::uint64_t offset, std::uint64_t count,
                               std::vector<unsigned char>& out, const Progress& progress, double p0, double p1) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{ErrorCode::kNotFound, path + ": cannot open for reading"};
  in.seekg(static_cast<std::streamoff>(offset));
  if (!in) return invalid(path + ": cannot seek to byte " + std::to_string(offset));
  const std::size_t at = out.size();
  out.resize(at + static_cast<std::size_t>(count));
  const std::uint64_t chunk = std::max<std::uint64_t>(kMinChunk, count / kProgressSteps + 1);
  std::uint64_t done = 0;
  while (done < count) {
    const std::uint64_t n = std::min(chunk, count - done);
    in.read(reinterpret_cast<char*>(out.data() + at + done), static_cast<std::streamsize>(n));
    if (static_cast<std::uint64_t>(in.gcount()) != n) {
      out.resize(at);
      return invalid(path + ": truncated data: expected " + std::to_string(count) + " bytes from byte " +
                     std::to_string(offset) + ", found " + std::to_string(done + static_cast<std::uint64_t>(in.gcount())));
    }
    done += n;
    report(progress, p0 + (p1 - p0) * static_cast<double>(done) / static_cast<double>(count));
  }
  return true;
}

namespace {

// A zlib inflater over an input buffer of any size (zlib counts in 32-bit uInt, so the input is
// handed over in steps).
class Inflater {
 public:
  explicit Inflater(const std::vector<unsigned char>& in) : in_(in) {}
  ~Inflater() {
    if (open_) inflateEnd(&zs_);
  }
  Inflater(const Inflater&) = delete;
  Inflater& operator=(const Inflater&) = delete;

  bool open() { return open_ = inflateInit2(&zs_, 15 + 32) == Z_OK; }  // 15 + 32: zlib or gzip header

  /// Inflates into [out, out + room); returns zlib's code and adds what came out to `produced`.
  int step(unsigned char* out, std::size_t room, std::uint64_t& produced) {
    feed();
    room = std::min(room, kMaxStep);
    zs_.next_out = out;
    zs_.avail_out = static_cast<uInt>(room);
    const int rc = inflate(&zs_, Z_NO_FLUSH);
    produced += room - zs_.avail_out;
    return rc;
  }
  bool input_spent() const { return zs_.avail_in == 0 && pos_ >= in_.size(); }
  std::string message() const { return zs_.msg != nullptr ? zs_.msg : ""; }

 private:
  static constexpr std::size_t kMaxStep = 1u << 30;
  void feed() {
    if (zs_.avail_in != 0 || pos_ >= in_.size()) return;
    const std::size_t n = std::min(kMaxStep, in_.size() - pos_);
    zs_.next_in = const_cast<Bytef*>(in_.data() + pos_);  // zlib's API is not const; it only reads
    zs_.avail_in = static_cast<uInt>(n);
    pos_ += n;
  }
  const std::vector<unsigned char>& in_;
  std::size_t pos_ = 0;
  z_stream zs_{};
  bool open_ = false;
};

}  // namespace

Result<bool> inflate_exact(const std::string& where, const StreamWords& words, const std::vector<unsigned char>& in,
                           std::uint64_t expected, std::vector<unsigned char>& out, const Progress& progress,
                           double p0, double p1) {
  Inflater z(in);
  if (!z.open()) return Error{ErrorCode::kSystem, where + ": zlib inflateInit failed"};
  const std::size_t base = out.size();
  const std::uint64_t report_every = std::max<std::uint64_t>(1, expected / kProgressSteps);
  std::uint64_t produced = 0;
  std::uint64_t reported = 0;
  int rc = Z_OK;
  while (produced < expected) {
    if (base + produced == out.size()) {
      const std::uint64_t grow = std::min<std::uint64_t>(expected - produced, std::max<std::uint64_t>(produced, kMinChunk));
      out.resize(out.size() + static_cast<std::size_t>(grow));
    }
    rc = z.step(out.data() + base + produced, out.size() - base - static_cast<std::size_t>(produced), produced);
    if (rc == Z_STREAM_END) break;
    if (rc == Z_BUF_ERROR && z.input_spent()) break;
    if (rc != Z_OK && rc != Z_BUF_ERROR) break;
    if (produced / report_every > reported) {
      reported = produced / report_every;
      report(progress, p0 + (p1 - p0) * static_cast<double>(produced) / static_cast<double>(expected));
    }
  }
  // A stream that holds more than the image is as wrong as one that holds less.
  bool more = false;
  if (produced == expected && rc != Z_STREAM_END && rc != Z_DATA_ERROR) {
    unsigned char extra = 0;
    std::uint64_t extra_out = 0;
    rc = z.step(&extra, 1, extra_out);
    more = extra_out != 0;
  }
  out.resize(base + static_cast<std::size_t>(produced));
  const std::string msg = z.message();
  const std::string field(words.field), kind(words.kind), made_of(words.expected_is);
  if (rc == Z_DATA_ERROR || rc == Z_NEED_DICT || rc == Z_MEM_ERROR || rc == Z_STREAM_ERROR) {
    return invalid(where + ": " + field + ": corrupt " + kind + " stream after " + std::to_string(produced) + " of " +
                   std::to_string(expected) + " expected bytes" + (msg.empty() ? "" : " (" + msg + ")"));
  }
  if (more) {
    return invalid(where + ": " + field + ": the " + kind + " stream holds more than the expected " +
                   std::to_string(expected) + " bytes (" + made_of + ")");
  }
  if (produced != expected) {
    return invalid(where + ": " + field + ": truncated " + kind + " stream: expected " + std::to_string(expected) +
                   " bytes (" + made_of + "), found " + std::to_string(produced));
  }
  report(progress, p1);
  return true;
}

}  // namespace lancet::volume::detail
