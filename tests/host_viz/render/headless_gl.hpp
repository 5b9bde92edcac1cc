#pragma once
// The GL tests' fixture: a GL 4.5 context of W × H through EGL surfaceless, with DISPLAY unset so
// that no test can lean on an X server.

#include <gtest/gtest.h>

#include <cstdlib>
#include <memory>

#include "render/window.hpp"

namespace lancet::test {

template <int W, int H>
class HeadlessGl : public ::testing::Test {
 protected:
  void SetUp() override {
    unsetenv("DISPLAY");  // EGL needs none
    auto w = render::Window::create({W, H, false, "test"});
    ASSERT_TRUE(w) << "no headless GL context: " << w.error().message;
    window_ = std::move(w).value();
  }
  std::unique_ptr<render::Window> window_;
};

}  // namespace lancet::test
