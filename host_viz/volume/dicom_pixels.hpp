#pragma once
// Compressed DICOM pixel data, decoded so that no file can take the program down. The DICOM fuzzer
// (tests/fuzz/dicom_fuzz.cpp) found GDCM's RLE decoder reading out of bounds (SIGSEGV) after a
// one-bit change of a valid file's RLE header; its JPEG, JPEG-LS and JPEG 2000 decoders run
// third-party code on the file's bytes too.
//   - RLE (PS3.5 Annex G) is simple enough to decode here, every length checked: decode_rle_frame.
//   - The other codecs run in a child process (run_isolated): a crash there ends the child, and
//     the caller gets an error naming the signal.
// Allocating; load time only, never the real-time path.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "lancet/shared_model/result.hpp"

namespace lancet::volume {

/// Decodes one RLE-compressed frame (one fragment) of rows × columns greyscale samples of
/// bytes_per_sample (1 or 2) bytes, into little-endian native bytes (rows · columns ·
/// bytes_per_sample). The RLE header must name exactly bytes_per_sample segments (the most
/// significant byte first) with offsets inside the fragment; each segment must decode (PackBits) to
/// rows · columns bytes. Errors name the header field or segment with expected vs found.
[[nodiscard]] Result<std::vector<std::uint8_t>> decode_rle_frame(std::span<const std::uint8_t> fragment, int rows, int columns,
                                                                 int bytes_per_sample);

/// Runs decode(out) in a forked child process that writes `bytes` bytes back through a pipe. decode
/// returns false when it cannot decode. A child that crashes, exits early or runs past `limit` (then
/// it is killed) is an error naming what happened; nothing it does can end the calling process.
/// Only for work that is not worth a thread-safe design: the child of a multi-threaded process
/// should allocate little (a deadlocked child is caught by the time limit).
[[nodiscard]] Result<std::vector<char>> run_isolated(const std::function<bool(std::span<char> out)>& decode, std::size_t bytes,
                                                     std::chrono::milliseconds limit);

}  // namespace lancet::volume
