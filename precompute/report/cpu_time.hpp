// CPU time of the calling thread and of the whole process, in seconds: what budgets and benchmarks
// count, so that other jobs on the machine's cores do not count against the code measured.
#pragma once

#include <time.h>

namespace clothdb {

inline double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// All threads: a threaded run's CPU time measures the work, its wall time also the neighbours.
inline double process_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

}  // namespace clothdb
