// JobTracker: the update jobs the server knows about, a bounded FIFO queue of
// the ones waiting for the single update worker, and change notification for
// watchers.
//
// Every change to a job bumps its `revision` and wakes waiters, so WatchJob
// can stream each state exactly once without polling. Jobs live in memory;
// after a restart the server re-creates queued jobs from the durable scans.
//
// Thread-safety: all methods are thread-safe (one mutex, one condition
// variable). Waits end on a change, a deadline, or Shutdown().
#ifndef CLNERF_SERVER_JOB_TRACKER_H_
#define CLNERF_SERVER_JOB_TRACKER_H_

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace clnerf {

enum class JobPhase { kQueued, kPreparingReplay, kTraining, kValidating, kPublishing, kDone, kFailed, kCancelled };
const char* JobPhaseName(JobPhase p);
inline bool IsFinal(JobPhase p) { return p == JobPhase::kDone || p == JobPhase::kFailed || p == JobPhase::kCancelled; }

struct JobStatus {
  std::string job_id, scan_id, scan_name;
  JobPhase phase = JobPhase::kQueued;
  int time_step = 0;  // Predicted while queued, actual once training.
  int iteration = 0, total_iterations = 0;
  double elapsed_seconds = 0, eta_seconds = 0;
  float loss = 0, psnr = 0;
  int64_t version = 0;
  std::string error;
  int64_t created_unix_ms = 0, finished_unix_ms = 0;
  std::map<std::string, double> metrics;
  uint64_t revision = 0;
  bool cancel_requested = false;
};

class JobTracker {
 public:
  explicit JobTracker(int max_queue) : max_queue_(max_queue) {}

  // Adds a queued job. RESOURCE_EXHAUSTED if `max_queue` jobs wait already
  // (`force` skips the limit: used when re-queuing after a restart).
  absl::Status Enqueue(JobStatus job, bool force = false);
  // Blocks until a job is queued (returns its id) or Shutdown() (nullopt).
  std::optional<std::string> WaitNext();
  // Applies `mutate` to the job and notifies watchers.
  void Update(const std::string& id, const std::function<void(JobStatus*)>& mutate);
  absl::StatusOr<JobStatus> Get(const std::string& id) const;
  std::vector<JobStatus> List() const;  // In creation order.
  // Waits until the job's revision exceeds `after_revision`, the deadline
  // passes, or shutdown; returns the current state. NOT_FOUND if unknown.
  absl::StatusOr<JobStatus> WaitForChange(const std::string& id, uint64_t after_revision,
                                          std::chrono::steady_clock::time_point deadline) const;
  // Queued job: removed from the queue and marked cancelled (returns true).
  // Running job: cancel_requested is set (returns false); the worker stops it.
  // FAILED_PRECONDITION for a finished job, NOT_FOUND for an unknown one.
  absl::StatusOr<bool> Cancel(const std::string& id);
  int queued() const;
  int running_or_queued() const;  // Jobs ahead of a new upload.
  std::string running() const;    // Id of the running job or "".
  void Shutdown();

 private:
  const int max_queue_;
  mutable std::mutex mu_;
  mutable std::condition_variable cv_;
  bool shutdown_ = false;
  std::map<std::string, JobStatus> jobs_;
  std::vector<std::string> order_;
  std::deque<std::string> queue_;
  std::string running_;
};

int64_t NowUnixMs();

}  // namespace clnerf

#endif  // CLNERF_SERVER_JOB_TRACKER_H_
