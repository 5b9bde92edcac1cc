#include "rt_setup.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <cerrno>
#include <cstring>

namespace lancet::rt {

RtSetupReport apply_rt_setup(const RtSetupOptions& o) {
  RtSetupReport r;
  if (!o.enable) {
    r.degraded.push_back("real-time setup skipped (--no-rt): timing is best effort");
    return r;
  }
  if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    r.memory_locked = true;
  } else {
    r.degraded.push_back(std::string("mlockall refused (") + std::strerror(errno) +
                         "): page faults may stall the loop; run as root or raise RLIMIT_MEMLOCK (ulimit -l unlimited)");
  }
  if (o.priority < 1 || o.priority > 98) {
    r.degraded.push_back("SCHED_FIFO priority " + std::to_string(o.priority) + " is out of range 1..98: not applied");
    return r;
  }
  sched_param sp{};
  sp.sched_priority = o.priority;
  const int err = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
  if (err == 0) {
    r.fifo = true;
  } else {
    r.degraded.push_back(std::string("SCHED_FIFO priority ") + std::to_string(o.priority) + " refused (" +
                         std::strerror(err) + "): the loop runs SCHED_OTHER; run as root or grant CAP_SYS_NICE");
  }
  return r;
}

}  // namespace lancet::rt
