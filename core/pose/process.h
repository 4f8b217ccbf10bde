// RunProcess: runs an external tool (COLMAP, ffmpeg) as a real child
// process, its standard output and error appended to a log file, and waits
// for it, polling `cancel` (the child is killed when it is set). The one
// place core/ starts processes.
// Thread-safety: each call is independent; safe from any thread.
#ifndef CLNERF_CORE_POSE_PROCESS_H_
#define CLNERF_CORE_POSE_PROCESS_H_

#include <atomic>
#include <string>
#include <vector>

#include "absl/status/status.h"

namespace clnerf {

// argv[0] is looked up on PATH. Returns OK on exit status 0; NOT_FOUND when
// the program is not installed; CANCELLED when `cancel` stopped it;
// INTERNAL with the exit status and the log's last lines otherwise.
absl::Status RunProcess(const std::vector<std::string>& argv, const std::string& log_path,
                        const std::atomic<bool>* cancel = nullptr);

// The last `max_lines` lines of a text file ("" when unreadable).
std::string TailOfFile(const std::string& path, int max_lines);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_PROCESS_H_
