#include "app/sample_trace.hpp"

#include <cerrno>
#include <cstring>

namespace lancet::viz {

Result<std::unique_ptr<SampleTrace>> SampleTrace::create(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return Error{ErrorCode::kSystem, "--trace " + path + ": cannot create: " + std::strerror(errno)};
  std::fputs("t_s,stage,events,tool_x_mm,tool_y_mm,tool_z_mm,proxy_x_mm,proxy_y_mm,proxy_z_mm,force_x_n,force_y_n,"
             "force_z_n,patch_version,hand\n",
             f);
  return std::unique_ptr<SampleTrace>(new SampleTrace(f));
}

void SampleTrace::write(std::span<const ToolSample> samples) {
  for (const ToolSample& t : samples) {
    const Vec3 a = t.tool.position * 1e3, b = t.proxy.position * 1e3;
    std::fprintf(file_.get(), "%.6f,%u,%u,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f,%.5f,%.5f,%llu,%s\n", static_cast<double>(t.t_ns) * 1e-9,
                 static_cast<unsigned>(t.stage), static_cast<unsigned>(t.events), a.x, a.y, a.z, b.x, b.y, b.z, t.force.x,
                 t.force.y, t.force.z, static_cast<unsigned long long>(t.patch_version), hand_name(t.hand));
  }
}

}  // namespace lancet::viz
