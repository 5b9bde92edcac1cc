// main() of the GoogleTest executables that emulate USB devices under umockdev: re-executes the
// test under umockdev-wrapper when umockdev's preload library is not loaded yet (usb_testbed.hpp),
// then runs the tests. Listed among such a test's SOURCES; it takes the place of gtest_main.

#include <gtest/gtest.h>

#include "usb_testbed.hpp"

int main(int argc, char** argv) {
  lancet::test::reexec_under_umockdev_if_needed(argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
