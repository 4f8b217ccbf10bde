// SecondsSince: the seconds elapsed since a steady-clock time point, the
// one way the engine and the service time their phases (update reports,
// metrics, logs).
//
// Thread-safety: a pure function of the clock.
#ifndef CLNERF_CORE_DATA_STOPWATCH_H_
#define CLNERF_CORE_DATA_STOPWATCH_H_

#include <chrono>

namespace clnerf {

inline double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace clnerf

#endif  // CLNERF_CORE_DATA_STOPWATCH_H_
