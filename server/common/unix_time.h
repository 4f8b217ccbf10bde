// NowUnixMs: wall-clock time in milliseconds since the Unix epoch, as the
// store's records (jobs, versions) and the API carry it. Thread-safe.
#ifndef CLNERF_SERVER_COMMON_UNIX_TIME_H_
#define CLNERF_SERVER_COMMON_UNIX_TIME_H_

#include <chrono>
#include <cstdint>

namespace clnerf {

inline int64_t NowUnixMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace clnerf

#endif  // CLNERF_SERVER_COMMON_UNIX_TIME_H_
