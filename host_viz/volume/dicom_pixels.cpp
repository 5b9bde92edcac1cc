#include "volume/dicom_pixels.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace lancet::volume {
namespace {

Error invalid(std::string message) { return Error{ErrorCode::kInvalid, std::move(message)}; }

std::uint32_t le32(std::span<const std::uint8_t> b, std::size_t at) {
  return static_cast<std::uint32_t>(b[at]) | static_cast<std::uint32_t>(b[at + 1]) << 8 | static_cast<std::uint32_t>(b[at + 2]) << 16 |
         static_cast<std::uint32_t>(b[at + 3]) << 24;
}

// PackBits: a header byte n; 0..127: n + 1 literal bytes follow; 129..255: the next byte repeats
// 257 - n times; 128: no operation. Decodes into out (exactly out.size() bytes) from seg.
bool unpack(std::span<const std::uint8_t> seg, std::span<std::uint8_t> out, std::size_t& produced) {
  std::size_t i = 0;
  produced = 0;
  while (produced < out.size() && i < seg.size()) {
    const std::uint8_t n = seg[i++];
    if (n < 128) {
      const std::size_t count = std::size_t{n} + 1;
      if (i + count > seg.size() || produced + count > out.size()) return false;
      std::memcpy(out.data() + produced, seg.data() + i, count);
      i += count;
      produced += count;
    } else if (n > 128) {
      const std::size_t count = 257 - std::size_t{n};
      if (i >= seg.size() || produced + count > out.size()) return false;
      std::memset(out.data() + produced, seg[i++], count);
      produced += count;
    }
  }
  return produced == out.size();
}

bool write_all(int fd, const char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

}  // namespace

Result<std::vector<std::uint8_t>> decode_rle_frame(std::span<const std::uint8_t> fragment, int rows, int columns, int bytes_per_sample) {
  if (rows <= 0 || columns <= 0 || (bytes_per_sample != 1 && bytes_per_sample != 2)) {
    return invalid("RLE: expected a positive image size and 1 or 2 bytes per sample");
  }
  if (fragment.size() < 64) {
    return invalid("RLE header: expected 64 bytes, found a fragment of " + std::to_string(fragment.size()));
  }
  const std::uint32_t segments = le32(fragment, 0);
  if (segments != static_cast<std::uint32_t>(bytes_per_sample)) {
    return invalid("RLE header: expected " + std::to_string(bytes_per_sample) + " segment(s) (BitsAllocated / 8 x SamplesPerPixel 1), found " +
                   std::to_string(segments));
  }
  const auto plane = static_cast<std::size_t>(rows) * static_cast<std::size_t>(columns);
  std::vector<std::uint8_t> planes(plane * static_cast<std::size_t>(bytes_per_sample));
  for (std::uint32_t s = 0; s < segments; ++s) {
    const std::uint32_t start = le32(fragment, 4 + 4 * s);
    const std::uint32_t end = s + 1 < segments ? le32(fragment, 8 + 4 * s) : static_cast<std::uint32_t>(fragment.size());
    if (start < 64 || start > end || end > fragment.size()) {
      return invalid("RLE header: segment " + std::to_string(s + 1) + " offset: expected 64.." + std::to_string(fragment.size()) +
                     " and ascending, found " + std::to_string(start) + " to " + std::to_string(end));
    }
    std::size_t produced = 0;
    if (!unpack(fragment.subspan(start, end - start), std::span(planes).subspan(s * plane, plane), produced)) {
      return invalid("RLE segment " + std::to_string(s + 1) + ": expected " + std::to_string(plane) + " bytes (Rows x Columns), decoded " +
                     std::to_string(produced) + " before a run ran past the segment or the image");
    }
  }
  // Segment 1 holds the most significant bytes: interleave into little-endian samples.
  if (bytes_per_sample == 1) return planes;
  std::vector<std::uint8_t> out(plane * 2);
  for (std::size_t i = 0; i < plane; ++i) {
    out[2 * i] = planes[plane + i];
    out[2 * i + 1] = planes[i];
  }
  return out;
}

Result<std::vector<char>> run_isolated(const std::function<bool(std::span<char> out)>& decode, std::size_t bytes,
                                       std::chrono::milliseconds limit) {
  std::vector<char> out(bytes);  // allocated here, before the fork; the child writes its copy
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) return Error{ErrorCode::kSystem, std::string("pipe: ") + std::strerror(errno)};
  const pid_t pid = ::fork();
  if (pid < 0) {
    ::close(fds[0]);
    ::close(fds[1]);
    return Error{ErrorCode::kSystem, std::string("fork: ") + std::strerror(errno)};
  }
  if (pid == 0) {
    ::close(fds[0]);
    // Codecs print their complaints (libjpeg: "Invalid JPEG file structure"); the library prints
    // nothing, so the child's stderr goes nowhere. The parent reports the failure.
    const int null = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
    if (null >= 0) ::dup2(null, 2);
    const char ok = decode(std::span<char>(out)) ? 1 : 0;
    const bool sent = write_all(fds[1], &ok, 1) && (ok == 0 || write_all(fds[1], out.data(), out.size()));
    ::_exit(sent ? 0 : 3);  // no atexit handlers, no flushing of the parent's buffers
  }
  ::close(fds[1]);
  const auto deadline = std::chrono::steady_clock::now() + limit;
  char ok = 0;
  std::size_t got = 0;
  const std::size_t want = 1 + bytes;
  bool timed_out = false, closed = false;
  while (got < want) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now()).count();
    if (left <= 0) {
      timed_out = true;
      break;
    }
    pollfd p{fds[0], POLLIN, 0};
    const int r = ::poll(&p, 1, static_cast<int>(std::min<long long>(left, 1000)));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) continue;
    char* dst = got == 0 ? &ok : out.data() + (got - 1);
    const std::size_t room = got == 0 ? 1 : want - got;
    const ssize_t n = ::read(fds[0], dst, room);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      closed = true;
      break;
    }
    got += static_cast<std::size_t>(n);
    if (got == 1 && ok == 0) break;  // the decoder said no
  }
  ::close(fds[0]);
  if (timed_out) ::kill(pid, SIGKILL);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (timed_out) {
    return invalid("the decoder ran past " + std::to_string(limit.count()) + " ms and was stopped");
  }
  if (WIFSIGNALED(status)) {
    return invalid("the decoder crashed (signal " + std::to_string(WTERMSIG(status)) + ", " + ::strsignal(WTERMSIG(status)) +
                   "): the compressed data is corrupt");
  }
  if (got >= 1 && ok == 0) return invalid("the decoder could not decode the compressed data");
  if (closed || got < want || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    return invalid("the decoder stopped after " + std::to_string(got == 0 ? 0 : got - 1) + " of " + std::to_string(bytes) +
                   " bytes (exit status " + std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) + ")");
  }
  return out;
}

}  // namespace lancet::volume
