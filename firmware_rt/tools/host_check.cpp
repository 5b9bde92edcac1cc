#include "tools/host_check.hpp"

#include <sys/resource.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "arm/arm_config.hpp"
#include "rt/rt_setup.hpp"
#include "text/text.hpp"
#include "tools/host_check_detail.hpp"

namespace lancet::tools {

namespace fs = std::filesystem;

const char* to_string(CheckStatus s) noexcept {
  switch (s) {
    case CheckStatus::kPass: return "pass";
    case CheckStatus::kWarn: return "warn";
    case CheckStatus::kFail: return "fail";
    case CheckStatus::kSkip: return "skip";
  }
  return "?";
}

int HostCheckReport::count(CheckStatus s) const noexcept {
  return static_cast<int>(std::count_if(checks.begin(), checks.end(), [s](const CheckResult& c) { return c.status == s; }));
}

ProcessLimits ProcessLimits::of_this_process() {
  ProcessLimits l;
  l.euid = ::geteuid();
  const auto limit = [](int resource) {
    rlimit r{};
    if (getrlimit(resource, &r) != 0) return std::uint64_t{0};
    return r.rlim_cur == RLIM_INFINITY ? kUnlimited : static_cast<std::uint64_t>(r.rlim_cur);
  };
  l.memlock = limit(RLIMIT_MEMLOCK);
  l.rtprio = limit(RLIMIT_RTPRIO);
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);) {
    if (line.rfind("CapEff:", 0) == 0) l.cap_effective = std::strtoull(line.c_str() + 7, nullptr, 16);
  }
  return l;
}

namespace host_check {

HostFs::HostFs(std::string root) : root_(std::move(root)) {
  while (!root_.empty() && root_.back() == '/') root_.pop_back();
}

std::string HostFs::path(std::string_view absolute) const { return root_ + std::string(absolute); }

std::optional<std::string> HostFs::line(std::string_view absolute) const {
  std::ifstream in(path(absolute));
  std::string l;
  if (!in || !std::getline(in, l)) return std::nullopt;
  while (!l.empty() && (l.back() == ' ' || l.back() == '\r')) l.pop_back();
  return l;
}

std::optional<std::string> HostFs::text(std::string_view absolute) const {
  std::ifstream in(path(absolute));
  if (!in) return std::nullopt;
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

bool HostFs::exists(std::string_view absolute) const {
  std::error_code ec;
  return fs::exists(path(absolute), ec);
}

std::vector<std::string> HostFs::list(std::string_view absolute) const {
  std::vector<std::string> names;
  std::error_code ec;
  for (fs::directory_iterator it(path(absolute), ec), end; !ec && it != end; it.increment(ec)) {
    names.push_back(it->path().filename().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

std::string HostFs::resolve(std::string_view absolute) const {
  std::error_code ec;
  const std::string real = fs::canonical(path(absolute), ec).string();
  const std::string root = root_.empty() ? "" : fs::canonical(root_, ec).string();
  if (ec || real.compare(0, root.size(), root) != 0) return {};
  return real.substr(root.size());
}

std::vector<Process> processes(const HostFs& fs) {
  std::vector<Process> procs;
  for (const auto& name : fs.list("/proc")) {
    if (name.empty() || !std::all_of(name.begin(), name.end(), [](unsigned char c) { return std::isdigit(c) != 0; })) continue;
    if (auto comm = fs.line("/proc/" + name + "/comm")) procs.push_back({std::atoi(name.c_str()), *comm});
  }
  return procs;
}

std::optional<std::string> boot_param(const std::string& cmdline, std::string_view name) {
  std::istringstream in(cmdline);
  std::optional<std::string> value;
  for (std::string word; in >> word;) {
    if (word == "--") break;
    if (word == name) value = "";
    if (word.size() > name.size() && word.compare(0, name.size(), name) == 0 && word[name.size()] == '=') value = word.substr(name.size() + 1);
  }
  return value;
}

std::vector<int> boot_cpu_list(const std::string& value, const std::vector<int>& online) {
  if (value == "all") return online;
  std::string cpus;
  std::istringstream in(value);
  for (std::string part; std::getline(in, part, ',');) {
    if (!part.empty() && std::isdigit(static_cast<unsigned char>(part[0])) != 0) cpus += (cpus.empty() ? "" : ",") + part;
  }
  return rt::parse_cpu_list(cpus);
}

bool contains(const std::vector<int>& cpus, int cpu) { return std::find(cpus.begin(), cpus.end(), cpu) != cpus.end(); }

CheckResult unknown(std::string name, const std::string& what, std::string fix) {
  return {CheckStatus::kWarn, std::move(name), "unknown (cannot read " + what + ")", std::move(fix)};
}

}  // namespace host_check

HostCheckReport run_host_check(const HostCheckInput& in) {
  using namespace host_check;
  const HostFs fs(in.root);
  HostCheckReport r;
  r.checks.push_back(check_servo_cpu(fs, in.cpu));
  r.checks.push_back(check_preempt_rt(fs, in.uname_version));
  for (const char* p : {"isolcpus", "nohz_full", "rcu_nocbs"}) r.checks.push_back(check_isolation(fs, in.cpu, p));
  r.checks.push_back(check_smt_sibling(fs, in.cpu));
  r.checks.push_back(check_governor(fs, in.cpu));
  r.checks.push_back(check_cstates(fs, in.cpu, in.limits));
  r.checks.push_back(check_rt_throttling(fs));
  r.checks.push_back(check_timer_migration(fs));
  r.checks.push_back(check_thp(fs));
  r.checks.push_back(check_swap(fs));
  r.checks.push_back(check_memlock(in.limits));
  r.checks.push_back(check_rtprio(in.limits, in.priority));
  r.checks.push_back(check_clocksource(fs));
  r.checks.push_back(check_irqbalance(fs, in.cpu));
  if (in.bus) {
    for (auto& c : check_bus(fs, *in.bus, in.cpu, in.priority)) r.checks.push_back(std::move(c));
  } else {
    r.checks.push_back({CheckStatus::kSkip, "bus_device", "the arm's bus is not checked: " + in.no_bus_reason,
                        "give the arm's config: lancetctl host-check --config hw_configs/<arm>.toml"});
  }
  return r;
}

std::string format_host_check_text(const HostCheckReport& r) {
  std::string out;
  for (const CheckResult& c : r.checks) {
    std::string status = to_string(c.status);
    std::transform(status.begin(), status.end(), status.begin(), [](unsigned char ch) { return static_cast<char>(std::toupper(ch)); });
    out += text::format("%-4s  %-20s %s\n", status.c_str(), c.name.c_str(), c.found.c_str());
    if (!c.fix.empty()) out += text::format("      %-20s fix: %s\n", "", c.fix.c_str());
  }
  out += text::format("host-check: %d pass, %d warn, %d fail, %d skip: %s\n", r.count(CheckStatus::kPass), r.count(CheckStatus::kWarn),
                      r.count(CheckStatus::kFail), r.count(CheckStatus::kSkip),
                      r.ok() ? "no check fails" : "NOT ready for 1 kHz work (see the fail lines)");
  return out;
}

std::string format_host_check_json(const HostCheckInput& in, const HostCheckReport& r) {
  std::string j = "{\"root\": " + text::json_string(in.root) + ", \"cpu\": " + std::to_string(in.cpu) +
                  ", \"priority\": " + std::to_string(in.priority) + ", \"checks\": [";
  for (std::size_t i = 0; i < r.checks.size(); ++i) {
    const CheckResult& c = r.checks[i];
    j += std::string(i == 0 ? "\n" : ",\n") + "  {\"status\": " + text::json_string(to_string(c.status)) + ", \"name\": " +
         text::json_string(c.name) + ", \"found\": " + text::json_string(c.found) + ", \"fix\": " + text::json_string(c.fix) + "}";
  }
  j += text::format("\n], \"summary\": {\"pass\": %d, \"warn\": %d, \"fail\": %d, \"skip\": %d, \"ok\": %s}}\n", r.count(CheckStatus::kPass),
                    r.count(CheckStatus::kWarn), r.count(CheckStatus::kFail), r.count(CheckStatus::kSkip), r.ok() ? "true" : "false");
  return j;
}

namespace {

ArmBus bus_of(const arm::ArmConfig& c) {
  ArmBus b;
  b.arm = c.name;
  if (c.usb) {
    b.kind = ArmBus::Kind::kUsb;
    b.vid = c.usb->vid;
    b.pid = c.usb->pid;
  } else if (c.modbus) {
    b.kind = c.modbus->transport == arm::ModbusTransport::kTcp ? ArmBus::Kind::kModbusTcp : ArmBus::Kind::kModbusRtu;
    b.host = c.modbus->host;
    b.serial_device = c.modbus->device;
  } else if (c.falcon) {  // a Novint Falcon is a USB device too (its FTDI chip)
    b.kind = ArmBus::Kind::kUsb;
    b.vid = c.falcon->vid;
    b.pid = c.falcon->pid;
  } else if (c.canopen) {
    b.kind = ArmBus::Kind::kCan;
    b.can_interface = c.canopen->interface_name;
    b.can_bitrate = c.canopen->bitrate;
  }
  return b;
}

}  // namespace

int run_host_check_command(const HostCheckOptions& o, std::FILE* out, std::FILE* err) {
  HostCheckInput in;
  in.root = o.root;
  in.cpu = o.cpu == -2 ? rt::default_rt_cpu() : o.cpu;
  in.priority = o.priority;
  utsname u{};
  if (uname(&u) == 0) in.uname_version = u.version;
  in.limits = ProcessLimits::of_this_process();
  if (!o.config_path.empty()) {
    Result<arm::ArmConfig> c = arm::load_arm_config(o.config_path);
    if (!c.ok()) {
      std::string msg = c.error().message;
      if (!msg.empty() && msg.back() != '\n') msg += '\n';
      std::fprintf(err, "lancetctl host-check: bad --config:\n%s", msg.c_str());
      return 2;
    }
    in.bus = bus_of(c.value());
  }
  const HostCheckReport r = run_host_check(in);
  std::fputs(o.json ? format_host_check_json(in, r).c_str() : format_host_check_text(r).c_str(), out);
  return r.ok() ? 0 : 1;
}

}  // namespace lancet::tools
