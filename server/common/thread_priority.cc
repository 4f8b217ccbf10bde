#include "server/common/thread_priority.h"

#include <cerrno>
#include <cstring>

#if defined(__linux__)
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

#include "absl/strings/str_cat.h"

namespace clnerf {

absl::Status SetCurrentThreadNice(int nice) {
  if (nice < 0 || nice > 19) return absl::InvalidArgumentError(absl::StrCat("nice must be in [0, 19], got ", nice));
#if defined(__linux__)
  const id_t tid = id_t(syscall(SYS_gettid));
  if (setpriority(PRIO_PROCESS, tid, nice) != 0) {
    return absl::PermissionDeniedError(absl::StrCat("setpriority(", nice, "): ", std::strerror(errno)));
  }
  return absl::OkStatus();
#else
  return absl::UnimplementedError("per-thread nice is Linux-only");
#endif
}

int CurrentThreadNice() {
#if defined(__linux__)
  errno = 0;
  return getpriority(PRIO_PROCESS, id_t(syscall(SYS_gettid)));
#else
  return 0;
#endif
}

}  // namespace clnerf
