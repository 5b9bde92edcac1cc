// host-check: the arm's bus. From the arm config to the device in sysfs (the CAN interface, the
// USB device, the NIC that routes to the Modbus TCP drive box, the USB serial adapter), up the
// device tree to the controller that raises the interrupts, then each IRQ's CPU affinity and its
// thread's priority (PREEMPT_RT runs interrupt handlers as irq/N-name threads).

#include <arpa/inet.h>
#include <netdb.h>

#include <cstdlib>
#include <map>
#include <sstream>

#include "rt/rt_setup.hpp"
#include "tools/host_check_detail.hpp"

namespace lancet::tools::host_check {

namespace {

// Where the bus's device sits in sysfs: its folder (resolved, below /sys/devices) or why not.
struct BusDevice {
  std::string what;       ///< "CAN interface can0", "USB device 1209:0001", ...
  std::string sys_path;   ///< "" when not found or virtual
  std::string why_none;   ///< when sys_path is empty: what was found instead
  bool absent = false;    ///< not on this host at all (warn), rather than without an IRQ (skip)
  std::string how_to_find;  ///< by hand, when the IRQ cannot be told
  std::string fix_absent;   ///< what to do when it is absent
};

BusDevice net_device(const HostFs& fs, const std::string& iface, const std::string& what, std::string fix_absent) {
  BusDevice d{what + " " + iface, "", "", false, "grep " + iface + " /proc/interrupts, or ethtool -i " + iface + " for its bus address",
              std::move(fix_absent)};
  if (!fs.exists("/sys/class/net/" + iface)) {
    d.absent = true;
    d.why_none = iface + " does not exist (ip link lists the interfaces)";
  } else if (!fs.exists("/sys/class/net/" + iface + "/device")) {
    d.why_none = iface + " is virtual (no device, no IRQ)";
  } else {
    d.sys_path = fs.resolve("/sys/class/net/" + iface + "/device");
  }
  return d;
}

BusDevice usb_device(const HostFs& fs, std::uint16_t vid, std::uint16_t pid) {
  char id[16];
  std::snprintf(id, sizeof id, "%04x:%04x", vid, pid);
  BusDevice d{std::string("USB device ") + id, "", "", false,
              "lsusb -t shows its bus; its host controller's IRQ is the xhci_hcd line in /proc/interrupts",
              std::string("plug the arm in (lsusb lists ") + id + " when it is there), then run host-check again"};
  for (const auto& name : fs.list("/sys/bus/usb/devices")) {
    const std::string dir = "/sys/bus/usb/devices/" + name;
    const auto v = fs.line(dir + "/idVendor"), p = fs.line(dir + "/idProduct");
    if (v && p && std::strtoul(v->c_str(), nullptr, 16) == vid && std::strtoul(p->c_str(), nullptr, 16) == pid) {
      d.sys_path = fs.resolve(dir);
      return d;
    }
  }
  d.absent = true;
  d.why_none = std::string("not plugged in (no ") + id + " in /sys/bus/usb/devices)";
  return d;
}

// The interface of the IPv4 route to `addr` (network byte order) in /proc/net/route: the longest
// matching prefix.
std::string route_interface(const HostFs& fs, std::uint32_t addr) {
  std::istringstream in(fs.text("/proc/net/route").value_or(""));
  std::string line, best;
  std::getline(in, line);  // the header
  int best_bits = -1;
  while (std::getline(in, line)) {
    std::istringstream f(line);
    std::string iface, dest, gw, flags, refcnt, use, metric, mask;
    if (!(f >> iface >> dest >> gw >> flags >> refcnt >> use >> metric >> mask)) continue;
    // The file prints the addresses as the host-order hex of the network-order word.
    const auto d = static_cast<std::uint32_t>(std::strtoul(dest.c_str(), nullptr, 16));
    const auto m = static_cast<std::uint32_t>(std::strtoul(mask.c_str(), nullptr, 16));
    const int bits = __builtin_popcount(m);
    if ((std::strtoul(flags.c_str(), nullptr, 16) & 1u) != 0 && (addr & m) == d && bits > best_bits) {
      best = iface;
      best_bits = bits;
    }
  }
  return best;
}

BusDevice modbus_tcp_device(const HostFs& fs, const std::string& host) {
  in_addr a{};
  if (inet_pton(AF_INET, host.c_str(), &a) != 1) {
    addrinfo hints{};
    hints.ai_family = AF_INET;
    addrinfo* res = nullptr;
    if (getaddrinfo(host.c_str(), nullptr, &hints, &res) == 0 && res != nullptr) {
      a = reinterpret_cast<sockaddr_in*>(res->ai_addr)->sin_addr;
      freeaddrinfo(res);
    } else {
      return {"Modbus TCP host " + host, "", "cannot resolve " + host, true, "", "give [bus.modbus] host as an address the host can reach"};
    }
  }
  if ((ntohl(a.s_addr) >> 24) == 127) return {"Modbus TCP host " + host, "", host + " is on loopback (no NIC, no IRQ)", false, "", ""};
  const std::string iface = route_interface(fs, a.s_addr);
  if (iface.empty()) {
    return {"Modbus TCP host " + host, "", "no route to " + host + " in /proc/net/route", true, "",
            "bring up the NIC to the drive box (ip addr, ip route get " + host + ")"};
  }
  BusDevice d = net_device(fs, iface, "NIC", "bring up " + iface + " (ip link set " + iface + " up)");
  d.what = "Modbus TCP host " + host + " through NIC " + iface;
  return d;
}

BusDevice serial_device(const HostFs& fs, const std::string& dev) {
  const std::string tty = dev.substr(dev.rfind('/') + 1);
  BusDevice d{"serial port " + dev, "", "", false, "udevadm info -q path -n " + dev + " shows its controller; find it in /proc/interrupts",
              "plug in the serial adapter (ls /dev/ttyUSB* /dev/ttyACM*) or fix [bus.modbus] device"};
  if (!fs.exists("/sys/class/tty/" + tty + "/device")) {
    d.absent = true;
    d.why_none = dev + " not found (no /sys/class/tty/" + tty + "/device)";
  } else {
    d.sys_path = fs.resolve("/sys/class/tty/" + tty + "/device");
  }
  return d;
}

BusDevice find_device(const HostFs& fs, const ArmBus& bus) {
  switch (bus.kind) {
    case ArmBus::Kind::kCan:
      return net_device(fs, bus.can_interface, "CAN interface",
                        "connect the CAN adapter and bring it up: ip link set " + bus.can_interface + " up type can bitrate " +
                            std::to_string(bus.can_bitrate));
    case ArmBus::Kind::kUsb: return usb_device(fs, bus.vid, bus.pid);
    case ArmBus::Kind::kModbusTcp: return modbus_tcp_device(fs, bus.host);
    case ArmBus::Kind::kModbusRtu: return serial_device(fs, bus.serial_device);
    case ArmBus::Kind::kSim: break;
  }
  return {"simulated arm", "", "no bus", false, "", ""};
}

// The IRQs of the device or, going up the device tree, of the first controller that has any: its
// MSI vectors (msi_irqs/) or its line (irq).
std::vector<int> device_irqs(const HostFs& fs, std::string path, std::string& owner) {
  while (path.size() > std::string("/sys/devices").size() && path.rfind("/sys/devices/", 0) == 0) {
    std::vector<int> irqs;
    for (const auto& n : fs.list(path + "/msi_irqs")) irqs.push_back(std::atoi(n.c_str()));
    const int line = std::atoi(fs.line(path + "/irq").value_or("0").c_str());
    if (irqs.empty() && line > 0) irqs.push_back(line);
    if (!irqs.empty()) {
      owner = path;
      return irqs;
    }
    path.resize(path.rfind('/'));
  }
  return {};
}

// IRQ number → the handler names /proc/interrupts gives it (its last column).
std::map<int, std::string> irq_names(const HostFs& fs) {
  std::map<int, std::string> names;
  std::istringstream in(fs.text("/proc/interrupts").value_or(""));
  std::string line;
  while (std::getline(in, line)) {
    char* end = nullptr;
    const long irq = std::strtol(line.c_str(), &end, 10);
    if (end == line.c_str() || *end != ':') continue;
    const auto last = line.find_last_of(" \t");
    names[static_cast<int>(irq)] = line.substr(last == std::string::npos ? 0 : last + 1);
  }
  return names;
}

std::string irq_list(const std::vector<int>& irqs, const std::map<int, std::string>& names) {
  std::string s;
  for (int i : irqs) {
    const auto n = names.find(i);
    s += (s.empty() ? "" : ", ") + std::to_string(i) + (n != names.end() ? " (" + n->second + ")" : "");
  }
  return s;
}

CheckResult check_affinity(const HostFs& fs, const std::vector<int>& irqs, int cpu) {
  std::string off, on;
  for (int i : irqs) {
    const std::string cpus = fs.line("/proc/irq/" + std::to_string(i) + "/smp_affinity_list").value_or("unknown");
    const auto list = rt::parse_cpu_list(cpus);
    std::string& into = list.size() == 1 && list[0] == cpu ? on : off;
    into += (into.empty() ? "IRQ " : ", IRQ ") + std::to_string(i) + " on CPU " + cpus;
  }
  if (off.empty()) return {CheckStatus::kPass, "bus_irq_affinity", on + ": the servo's CPU takes its bus's interrupts", ""};
  std::string fix;
  for (int i : irqs) fix += (fix.empty() ? "" : "; ") + ("echo " + std::to_string(cpu) + " > /proc/irq/" + std::to_string(i) + "/smp_affinity_list");
  return {CheckStatus::kWarn, "bus_irq_affinity", off + ": a busy CPU delays the bus's replies", fix + " (with irqbalance off)"};
}

// policy and rt_priority of a process (fields 41 and 40 of /proc/<pid>/stat, after the comm).
bool sched_of(const HostFs& fs, int pid, int& policy, int& rt_priority) {
  const std::string stat = fs.line("/proc/" + std::to_string(pid) + "/stat").value_or("");
  const auto close = stat.rfind(')');
  if (close == std::string::npos) return false;
  std::istringstream f(stat.substr(close + 2));
  std::vector<std::string> fields{"pid", "comm"};
  for (std::string v; f >> v;) fields.push_back(v);
  if (fields.size() < 41) return false;
  rt_priority = std::atoi(fields[39].c_str());
  policy = std::atoi(fields[40].c_str());
  return true;
}

CheckResult check_threads(const HostFs& fs, const std::vector<int>& irqs, int priority) {
  const auto procs = processes(fs);
  const int want = std::min(priority + 5, 99);
  std::string good, bad, fix;
  for (int i : irqs) {
    const std::string prefix = "irq/" + std::to_string(i) + "-";
    int pid = 0, policy = 0, prio = 0;
    for (const Process& p : procs) {
      if (p.comm.rfind(prefix, 0) == 0 && sched_of(fs, p.pid, policy, prio)) pid = p.pid;
    }
    const bool realtime = policy == 1 || policy == 2;  // SCHED_FIFO or SCHED_RR
    std::string& into = pid > 0 && realtime && prio > priority ? good : bad;
    into += (into.empty() ? "" : ", ") + std::string("IRQ ") + std::to_string(i) +
            (pid == 0 ? ": no irq thread (hard interrupt context)"
                      : " thread " + std::to_string(pid) + (policy == 1 ? " FIFO " : policy == 2 ? " RR " : " policy " + std::to_string(policy) + " priority ") +
                            std::to_string(prio));
    if (pid > 0 && &into == &bad) fix += (fix.empty() ? "" : "; ") + ("chrt -f -p " + std::to_string(want) + " " + std::to_string(pid));
  }
  if (bad.empty()) return {CheckStatus::kPass, "bus_irq_thread", good + ": above the servo's " + std::to_string(priority), ""};
  if (fix.empty()) fix = "boot the PREEMPT_RT kernel (its interrupts run as threads with a priority)";
  return {CheckStatus::kWarn, "bus_irq_thread", bad + ": the servo (FIFO " + std::to_string(priority) + ") waits on it", fix};
}

}  // namespace

std::vector<CheckResult> check_bus(const HostFs& fs, const ArmBus& bus, int cpu, int priority) {
  const BusDevice d = find_device(fs, bus);
  const std::string arm = "arm '" + bus.arm + "': ";
  if (d.sys_path.empty()) {
    const std::string why = arm + d.what + ": " + d.why_none;
    if (d.absent) return {{CheckStatus::kWarn, "bus_device", why, d.fix_absent}};
    return {{CheckStatus::kSkip, "bus_device", why, ""}};
  }
  std::string owner;
  const std::vector<int> irqs = device_irqs(fs, d.sys_path, owner);
  if (irqs.empty()) {
    return {{CheckStatus::kWarn, "bus_device", arm + d.what + " at " + d.sys_path + ": its IRQ is unknown", d.how_to_find}};
  }
  std::vector<CheckResult> out;
  out.push_back({CheckStatus::kPass, "bus_device", arm + d.what + ": IRQ " + irq_list(irqs, irq_names(fs)) + " of " + owner, ""});
  out.push_back(check_affinity(fs, irqs, cpu));
  out.push_back(check_threads(fs, irqs, priority));
  return out;
}

}  // namespace lancet::tools::host_check
