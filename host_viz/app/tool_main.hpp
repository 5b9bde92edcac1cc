#pragma once
// The last guard of a command-line tool's main (lancet-report, lancet-volume, lancet-records):
// the tools return errors as values; anything else that escapes (memory, a library's exception)
// ends with a message through the tool's `fail` (which prints it and returns exit status 2), never
// an abort.

#include <exception>
#include <new>
#include <string>

namespace lancet::app {

/// run(): the tool's status; fail(message): prints it and returns the tool's error status.
template <class Run, class Fail>
int guarded_main(Run run, Fail fail) {
  try {
    return run();
  } catch (const std::bad_alloc&) {
    return fail("out of memory");
  } catch (const std::exception& e) {
    return fail(std::string("unexpected error: ") + e.what());
  }
}

}  // namespace lancet::app
