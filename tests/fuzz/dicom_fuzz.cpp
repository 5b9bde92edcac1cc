// libFuzzer target for the DICOM loader: each input is one file. First scan_dicom on the bytes in
// memory (it must stay inside them, and what it calls an image must have its pixel data inside),
// then the whole loader, scan and GDCM together, on a folder holding the input as its only file.
// GDCM asserts (SIGABRT) on some malformed files; the scan exists to keep every such file away from
// it, so an abort here is a file the scan let through: a crash the fuzzer reports. The input's
// series and geometry checks run too (a slice that parses must give a consistent Volume).

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <span>
#include <string>
#include <system_error>

#include "volume/dicom.hpp"
#include "volume/dicom_scan.hpp"

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "dicom_fuzz: %s\n", what);
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lancet::volume;
  const DicomScan s = scan_dicom(std::span<const std::uint8_t>(data, size));
  if (s.status == DicomScanStatus::kImage) {
    if (s.pixel_offset > size || s.pixel_length > size - s.pixel_offset) fail("the scan put the pixel data outside the file");
    if (!s.encapsulated && s.pixel_length < s.frame_bytes()) fail("the scan accepted pixel data shorter than the image");
  } else if (s.problem.empty()) {
    fail("the scan refused a file without saying why");
  }

  // One folder per fuzzing process, so parallel jobs (-jobs=N) do not share it.
  static const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("lancet_dicom_fuzz_" + std::to_string(::getpid()));
  static const bool made = [] {
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    return !ec;
  }();
  // Removed when the process exits normally (libFuzzer's -max_total_time, the replay's end).
  static const struct Cleanup {
    ~Cleanup() {
      std::error_code ec;
      std::filesystem::remove_all(dir, ec);
    }
  } cleanup;
  if (!made) fail("cannot make the temporary folder");
  {
    std::ofstream out(dir / "slice.dcm", std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  auto r = load_dicom_series(dir.string());
  if (r.ok()) {
    const Volume& v = r.value();
    if (v.data.size() != v.voxel_count() || !(v.spacing.x > 0 && v.spacing.y > 0 && v.spacing.z > 0)) {
      fail("the loader returned an inconsistent Volume");
    }
    if (s.status != DicomScanStatus::kImage) fail("the loader read a file the scan refused");
  } else if (r.error().message.empty()) {
    fail("the loader returned an error without a message");
  }
  return 0;
}
