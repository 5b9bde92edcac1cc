// libFuzzer target for the MetaImage loader: each input is written to a temporary .mha file and
// loaded. The loader must return a Volume whose data matches its dims, or an error; ASan and
// libFuzzer catch crashes, leaks, hangs (-timeout) and huge allocations (-rss_limit_mb,
// -malloc_limit_mb). See CMakeLists.txt here for how to build and run it.

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "volume/metaimage.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // One file per fuzzing process, so parallel jobs (-jobs=N) do not overwrite each other's input.
  static const std::string path =
      (std::filesystem::temp_directory_path() / ("lancet_metaimage_fuzz_" + std::to_string(::getpid()) + ".mha")).string();
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  auto result = lancet::volume::load_metaimage(path);
  if (result.ok()) {
    const lancet::volume::Volume& v = result.value();
    if (v.data.size() != v.voxel_count() || !(v.spacing.x > 0 && v.spacing.y > 0 && v.spacing.z > 0)) {
      std::fprintf(stderr, "load_metaimage returned an inconsistent Volume\n");
      std::abort();
    }
  } else if (result.error().message.empty()) {
    std::fprintf(stderr, "load_metaimage returned an error without a message\n");
    std::abort();
  }
  return 0;
}
