// Thread priority: lowers the scheduling priority (raises the nice value) of
// the calling thread only. Threads it creates afterwards (e.g. the OpenMP
// team of its first parallel region) inherit the value, which is how the
// update worker's training yields the cores to renders: with nice 10 the
// kernel gives a runnable render thread about ten times the CPU share of a
// training thread, and training still gets every cycle renders leave idle.
//
// Linux-specific (per-thread nice); elsewhere it returns UNIMPLEMENTED.
// Thread-safe (it touches only the calling thread).
#ifndef CLNERF_SERVER_THREAD_PRIORITY_H_
#define CLNERF_SERVER_THREAD_PRIORITY_H_

#include "absl/status/status.h"

namespace clnerf {

// Sets the calling thread's nice value to `nice` (0-19). Raising it needs no
// privilege; lowering it below the current value may fail (EACCES), which is
// reported, not fatal.
absl::Status SetCurrentThreadNice(int nice);
// The calling thread's nice value.
int CurrentThreadNice();

}  // namespace clnerf

#endif  // CLNERF_SERVER_THREAD_PRIORITY_H_
