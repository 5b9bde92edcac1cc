// Replays fuzz corpora through a fuzz target without libFuzzer, so every compiler (GCC included)
// runs every checked-in input under ctest: main() calls LLVMFuzzerTestOneInput once per file.
//   <target>_replay CORPUS_DIR_OR_FILE...
// Each input's name is printed before it runs, so a crash (which ends the process with its signal:
// ctest reports the test failed) names its input; an input running longer than kSecondsPerInput
// (or LANCET_FUZZ_REPLAY_SECONDS) is ended by SIGALRM the same way. Exit status: 0 every input returned, 1 no inputs (an empty or
// mistyped corpus proves nothing), 2 bad arguments or a missing corpus.

#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <system_error>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

constexpr unsigned kSecondsPerInput = 20;  // libFuzzer's runs use -timeout=5; sanitizer builds are slower

// kSecondsPerInput, or LANCET_FUZZ_REPLAY_SECONDS when set (the driver's own test uses 1).
unsigned seconds_per_input() {
  const char* s = std::getenv("LANCET_FUZZ_REPLAY_SECONDS");
  const long v = s != nullptr ? std::strtol(s, nullptr, 10) : 0;
  return v > 0 && v < 3600 ? static_cast<unsigned>(v) : kSecondsPerInput;
}

std::vector<std::uint8_t> read_file(const std::filesystem::path& p, bool& ok) {
  std::ifstream in(p, std::ios::binary);
  ok = static_cast<bool>(in);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR_OR_FILE...\n", argv[0]);
    return 2;
  }
  std::vector<fs::path> inputs;
  for (int i = 1; i < argc; ++i) {
    const fs::path p(argv[i]);
    std::error_code ec;
    if (fs::is_directory(p, ec)) {
      std::vector<fs::path> files;
      for (const auto& e : fs::directory_iterator(p, ec)) {
        if (e.is_regular_file()) files.push_back(e.path());
      }
      std::sort(files.begin(), files.end());
      inputs.insert(inputs.end(), files.begin(), files.end());
    } else if (fs::is_regular_file(p, ec)) {
      inputs.push_back(p);
    } else {
      std::fprintf(stderr, "replay: %s: not found (expected a corpus folder or an input file)\n", argv[i]);
      return 2;
    }
  }
  if (inputs.empty()) {
    std::fprintf(stderr, "replay: no inputs in the corpus: an empty corpus proves nothing\n");
    return 1;
  }
  const unsigned limit = seconds_per_input();
  for (const fs::path& p : inputs) {
    bool ok = false;
    const std::vector<std::uint8_t> data = read_file(p, ok);
    if (!ok) {
      std::fprintf(stderr, "replay: %s: cannot read\n", p.c_str());
      return 2;
    }
    std::fprintf(stderr, "replay: %s (%zu bytes)\n", p.c_str(), data.size());
    std::fflush(stderr);
    ::alarm(limit);  // the default action of SIGALRM ends the process: a hang fails too
    (void)LLVMFuzzerTestOneInput(data.data(), data.size());
    ::alarm(0);
  }
  std::fprintf(stderr, "replay: %zu inputs, every one returned\n", inputs.size());
  return 0;
}
