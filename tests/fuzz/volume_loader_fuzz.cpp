// libFuzzer target for a volume file loader, built once per format (CMakeLists.txt here):
// LANCET_FUZZ_NRRD selects the NRRD loader, otherwise the MetaImage one. Each input is written to
// a temporary file and loaded. The loader must return a Volume whose data matches its dims, or an
// error; ASan and libFuzzer catch crashes, leaks, hangs (-timeout) and huge allocations
// (-rss_limit_mb, -malloc_limit_mb).

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#if defined(LANCET_FUZZ_NRRD)
#include "volume/nrrd.hpp"
namespace {
constexpr const char* kFormat = "nrrd";
auto load(const std::string& path) { return lancet::volume::load_nrrd(path); }
}  // namespace
#else
#include "volume/metaimage.hpp"
namespace {
constexpr const char* kFormat = "mha";
auto load(const std::string& path) { return lancet::volume::load_metaimage(path); }
}  // namespace
#endif

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // One file per fuzzing process, so parallel jobs (-jobs=N) do not overwrite each other's input.
  static const std::string path =
      (std::filesystem::temp_directory_path() /
       ("lancet_" + std::string(kFormat) + "_fuzz_" + std::to_string(::getpid()) + "." + kFormat))
          .string();
  // Removed when the process exits normally (libFuzzer's -max_total_time, the replay's end).
  static const struct Cleanup {
    ~Cleanup() { std::remove(path.c_str()); }
  } cleanup;
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  auto result = load(path);
  if (result.ok()) {
    const lancet::volume::Volume& v = result.value();
    if (v.data.size() != v.voxel_count() || !(v.spacing.x > 0 && v.spacing.y > 0 && v.spacing.z > 0)) {
      std::fprintf(stderr, "the %s loader returned an inconsistent Volume\n", kFormat);
      std::abort();
    }
  } else if (result.error().message.empty()) {
    std::fprintf(stderr, "the %s loader returned an error without a message\n", kFormat);
    std::abort();
  }
  return 0;
}
