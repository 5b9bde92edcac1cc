#pragma once
// SampleTrace: lancet-viz's --trace, every ToolSample received written as one CSV line (time in s,
// stage, events, tool and proxy positions in mm, force in N, the patch version the tick used, the hand: right or left).

#include <cstdio>
#include <memory>
#include <span>
#include <string>

#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/result.hpp"

namespace lancet::viz {

class SampleTrace {
 public:
  /// Creates the file and writes the CSV header; the error names the path and the system's reason.
  [[nodiscard]] static Result<std::unique_ptr<SampleTrace>> create(const std::string& path);
  /// One line a sample, in order.
  void write(std::span<const ToolSample> samples);

 private:
  explicit SampleTrace(std::FILE* f) : file_(f, &std::fclose) {}
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file_;
};

}  // namespace lancet::viz
