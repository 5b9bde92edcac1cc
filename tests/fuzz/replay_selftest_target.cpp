// A fuzz target that fails on purpose, for replay_test.cpp: an input starting with "abort" aborts,
// "segv" dereferences null, "hang" never returns; anything else returns. Linked with
// replay_main.cpp it shows that a replay reports a crashing or hanging input.

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include <unistd.h>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto starts = [&](const char* word) { return size >= std::strlen(word) && std::memcmp(data, word, std::strlen(word)) == 0; };
  if (starts("abort")) std::abort();
  if (starts("segv")) {
    volatile int* volatile p = nullptr;
    *p = 1;
  }
  if (starts("hang")) {
    while (true) ::pause();
  }
  return 0;
}
