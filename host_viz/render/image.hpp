#pragma once
// RGBA8 images read back from the GPU, written as PNG, and a blankness measure for tests.

#include <cstdint>
#include <string>
#include <vector>

namespace lancet::render {

struct Image {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgba;  ///< width*height*4, top row first
};

/// Writes img as PNG; returns false (errno set by the writer) on failure.
bool write_png(const std::string& path, const Image& img);
/// Reads a PNG as RGBA (top row first); an empty image (width 0) when it cannot.
Image read_png(const std::string& path);

/// Variance of the luminance over all pixels (0 for a uniform image), in (8-bit units)².
double luminance_variance(const Image& img);

}  // namespace lancet::render
