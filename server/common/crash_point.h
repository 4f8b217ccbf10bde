// CrashPoint: fault injection for the crash-recovery tests. When the
// environment variable CLNERF_CRASH_AT names the point being passed, the
// process ends at once with status 137, as `kill -9` would leave it: no
// destructors, no flushing, no clean-up. Unset (production), it is one cached
// getenv and a null check.
//
// Points: "publish:version-written", "publish:manifest-written" (publisher.cc),
// "publish:scan-removed" (update_worker.cc).
//
// Thread-safety: safe from any thread.
#ifndef CLNERF_SERVER_CRASH_POINT_H_
#define CLNERF_SERVER_CRASH_POINT_H_

#include <cstdlib>
#include <cstring>

namespace clnerf {

inline void CrashPoint(const char* name) {
  static const char* const at = std::getenv("CLNERF_CRASH_AT");
  if (at != nullptr && std::strcmp(at, name) == 0) std::_Exit(137);
}

}  // namespace clnerf

#endif  // CLNERF_SERVER_CRASH_POINT_H_
