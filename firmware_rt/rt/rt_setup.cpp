#include "rt/rt_setup.hpp"

#include <alloca.h>
#include <fcntl.h>
#include <malloc.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace lancet::rt {
namespace {

std::string read_first_line(const char* path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  return line;
}

std::string errno_text(int err) { return std::strerror(err); }

// Touches `bytes` of stack below the caller so the pages exist before the loop runs.
[[gnu::noinline]] void prefault_stack(std::size_t bytes) {
  constexpr std::size_t kChunk = 4096;
  for (std::size_t done = 0; done < bytes; done += kChunk) {
    volatile unsigned char* p = static_cast<volatile unsigned char*>(alloca(kChunk));
    p[0] = 0;
  }
}

struct ThreadStart {
  std::function<void()> body;
  std::size_t prefault;
};

extern "C" void* rt_thread_entry(void* arg) {
  std::unique_ptr<ThreadStart> start(static_cast<ThreadStart*>(arg));
  prefault_stack(start->prefault);
  start->body();
  return nullptr;
}

}  // namespace

bool current_thread_is_fifo() {
  int policy = 0;
  sched_param sp{};
  return pthread_getschedparam(pthread_self(), &policy, &sp) == 0 && policy == SCHED_FIFO;
}

bool kernel_is_preempt_rt(const std::string& sys_kernel_realtime, const std::string& uname_version) {
  return sys_kernel_realtime == "1" || uname_version.find("PREEMPT_RT") != std::string::npos ||
         uname_version.find("PREEMPT RT") != std::string::npos;
}

bool kernel_is_preempt_rt() {
  utsname u{};
  return kernel_is_preempt_rt(read_first_line("/sys/kernel/realtime"), uname(&u) == 0 ? u.version : "");
}

int default_rt_cpu() { return static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN)) - 1; }

bool allowed_cpus_without(int cpu, cpu_set_t& set) {
  if (cpu < 0 || cpu >= CPU_SETSIZE) return false;
  CPU_ZERO(&set);
  if (pthread_getaffinity_np(pthread_self(), sizeof set, &set) != 0 || !CPU_ISSET(cpu, &set) || CPU_COUNT(&set) < 2) return false;
  CPU_CLR(cpu, &set);
  return true;
}

bool keep_off_cpu(int cpu) {
  cpu_set_t set;
  return allowed_cpus_without(cpu, set) && pthread_setaffinity_np(pthread_self(), sizeof set, &set) == 0;
}

std::vector<int> parse_cpu_list(const std::string& list) {
  std::vector<int> cpus;
  std::stringstream ss(list);
  std::string part;
  while (std::getline(ss, part, ',')) {
    if (part.empty()) continue;
    const auto dash = part.find('-');
    char* end = nullptr;
    const long a = std::strtol(part.c_str(), &end, 10);
    if (end == part.c_str() || a < 0) return {};
    long b = a;
    if (dash != std::string::npos) {
      const char* s = part.c_str() + dash + 1;
      b = std::strtol(s, &end, 10);
      if (end == s || b < a) return {};
    } else if (*end != '\0' && *end != '\n') {
      return {};
    }
    for (long c = a; c <= b; ++c) cpus.push_back(static_cast<int>(c));
  }
  return cpus;
}

RtEnvironment::RtEnvironment(const RtSetupOptions& o, RtSetupReport& r) {
  utsname u{};
  if (uname(&u) == 0) r.kernel = std::string(u.release) + " " + u.version;
  r.preempt_rt = kernel_is_preempt_rt();
  r.isolated_cpus = read_first_line("/sys/devices/system/cpu/isolated");
  if (o.cpu >= 0) {
    const auto iso = parse_cpu_list(r.isolated_cpus);
    r.cpu_isolated = std::find(iso.begin(), iso.end(), o.cpu) != iso.end();
  }
  if (!o.enable) {
    r.degraded.push_back("real-time setup skipped (--no-rt): timing is best effort");
    return;
  }
  if (r.preempt_rt) {
    r.applied.push_back("kernel is PREEMPT_RT");
  } else {
    r.degraded.push_back("kernel is not PREEMPT_RT (" + r.kernel +
                         "): latency bounds cannot be guaranteed; use a PREEMPT_RT kernel on the target");
  }
  if (o.cpu >= 0 && !r.cpu_isolated) {
    r.degraded.push_back("CPU " + std::to_string(o.cpu) + " is not isolated (isolated: '" + r.isolated_cpus +
                         "'): other tasks may run there; boot with isolcpus=" + std::to_string(o.cpu) +
                         " nohz_full=" + std::to_string(o.cpu) + " rcu_nocbs=" + std::to_string(o.cpu));
  } else if (o.cpu >= 0) {
    r.applied.push_back("CPU " + std::to_string(o.cpu) + " is isolated");
  }
  if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    r.memory_locked = true;
    r.applied.push_back("memory locked (mlockall current and future)");
  } else {
    const int err = errno;
    rlimit rl{};
    getrlimit(RLIMIT_MEMLOCK, &rl);
    r.degraded.push_back("mlockall refused (" + errno_text(err) + ", RLIMIT_MEMLOCK " +
                         (rl.rlim_cur == RLIM_INFINITY ? std::string("unlimited") : std::to_string(rl.rlim_cur) + " bytes") +
                         "): page faults may stall the loop; run as root or set 'ulimit -l unlimited'");
  }
  // Keep freed memory: no trimming back to the kernel and no mmap'd chunks that come and go.
  if (mallopt(M_TRIM_THRESHOLD, -1) == 1 && mallopt(M_MMAP_MAX, 0) == 1) {
    r.malloc_tuned = true;
    r.applied.push_back("malloc trimming and mmap allocation off");
  } else {
    r.degraded.push_back("mallopt refused: freed memory may be returned to the kernel and fault back in");
  }
  if (o.hold_dma_latency) {
    dma_fd_ = ::open("/dev/cpu_dma_latency", O_WRONLY | O_CLOEXEC);
    const std::int32_t zero = 0;
    if (dma_fd_ >= 0 && ::write(dma_fd_, &zero, sizeof zero) == static_cast<ssize_t>(sizeof zero)) {
      r.dma_latency_held = true;
      r.applied.push_back("/dev/cpu_dma_latency held at 0 us (no deep C-states)");
    } else {
      const int err = errno;
      if (dma_fd_ >= 0) ::close(dma_fd_);
      dma_fd_ = -1;
      r.degraded.push_back("cannot hold /dev/cpu_dma_latency at 0 (" + errno_text(err) +
                           "): deep C-states may add wake-up latency; run as root");
    }
  }
}

RtEnvironment::~RtEnvironment() {
  if (dma_fd_ >= 0) ::close(dma_fd_);  // closing restores the default latency
}

RtThread::RtThread(RtThread&& o) noexcept : thread_(o.thread_), started_(std::exchange(o.started_, false)) {}
RtThread& RtThread::operator=(RtThread&& o) noexcept {
  if (this != &o) {
    join();
    thread_ = o.thread_;
    started_ = std::exchange(o.started_, false);
  }
  return *this;
}
RtThread::~RtThread() { join(); }
void RtThread::join() {
  if (started_) pthread_join(thread_, nullptr);
  started_ = false;
}

RtThread start_rt_thread(const RtSetupOptions& o, RtSetupReport& r, std::function<void()> body) {
  RtThread t;
  bool want_fifo = o.enable;
  bool want_cpu = o.enable && o.cpu >= 0;
  if (o.enable && (o.priority < 1 || o.priority > 98)) {
    r.degraded.push_back("SCHED_FIFO priority " + std::to_string(o.priority) + " is outside 1..98: not applied");
    want_fifo = false;
  }
  if (want_cpu && o.cpu >= CPU_SETSIZE) {
    r.degraded.push_back("CPU " + std::to_string(o.cpu) + " does not exist: no affinity");
    want_cpu = false;
  }
  // Try with everything, then drop what the kernel refuses, one step at a time.
  for (int attempt = 0; attempt < 3; ++attempt) {
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    if (want_fifo) {
      pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
      pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
      sched_param sp{};
      sp.sched_priority = o.priority;
      pthread_attr_setschedparam(&attr, &sp);
    } else {
      // Never inherit a real-time policy by accident: an unprivileged fallback runs SCHED_OTHER.
      pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
      pthread_attr_setschedpolicy(&attr, SCHED_OTHER);
      sched_param sp{};
      pthread_attr_setschedparam(&attr, &sp);
    }
    if (want_cpu) {
      cpu_set_t set;
      CPU_ZERO(&set);
      CPU_SET(o.cpu, &set);
      pthread_attr_setaffinity_np(&attr, sizeof set, &set);
    }
    auto* start = new ThreadStart{body, o.stack_prefault};
    const int err = pthread_create(&t.thread_, &attr, rt_thread_entry, start);
    pthread_attr_destroy(&attr);
    if (err == 0) {
      t.started_ = true;
      r.fifo = want_fifo;
      r.affinity = want_cpu;
      if (want_fifo) r.applied.push_back("SCHED_FIFO priority " + std::to_string(o.priority));
      if (want_cpu) r.applied.push_back("pinned to CPU " + std::to_string(o.cpu));
      r.applied.push_back(std::to_string(o.stack_prefault / 1024) + " KiB of stack prefaulted");
      return t;
    }
    delete start;
    if (err == EPERM && want_fifo) {
      r.degraded.push_back("SCHED_FIFO priority " + std::to_string(o.priority) +
                           " refused (" + errno_text(err) + "): the loop runs SCHED_OTHER; run as root or grant CAP_SYS_NICE "
                           "(or an rtprio limit in /etc/security/limits.conf)");
      want_fifo = false;
    } else if (err == EINVAL && want_cpu) {
      r.degraded.push_back("CPU " + std::to_string(o.cpu) + " refused (" + errno_text(err) +
                           "): not in this process's allowed CPUs; no affinity");
      want_cpu = false;
    } else {
      throw std::runtime_error("cannot start the real-time thread: " + errno_text(err));
    }
  }
  throw std::runtime_error("cannot start the real-time thread");
}

}  // namespace lancet::rt
