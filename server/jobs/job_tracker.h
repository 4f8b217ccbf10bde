// JobTracker: the update jobs the server knows about, a bounded FIFO queue of
// the ones waiting for the single update worker, and change notification for
// watchers.
//
// Every change to a job bumps its `revision` and wakes waiters, so WatchJob
// can stream each state exactly once without polling. Live jobs are in
// memory (after a restart the server re-creates queued jobs from the durable
// scans); finished jobs are also written to a history file (the newest
// kMaxHistory, replaced atomically on every finish) and read back on start,
// so `jobs` still shows what happened before a restart.
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

#include "server/common/unix_time.h"
#include "absl/status/statusor.h"
#include "nlohmann/json_fwd.hpp"

namespace clnerf {

// (The order matches the wire enum's, less one; kPosing then kRegistering
// run before kPreparingReplay, kBaking between kValidating and kPublishing.)
enum class JobPhase {
  kQueued, kPreparingReplay, kTraining, kValidating, kPublishing, kDone, kFailed, kCancelled, kRegistering, kPosing,
  kBaking
};
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

// A job as a JSON object: the job history file's record, which the HTTP API
// also serves (adding the live fields).
nlohmann::json JobToJson(const JobStatus& job);

class JobTracker {
 public:
  static constexpr size_t kMaxHistory = 1000;  // Finished jobs remembered.

  // `history_path` empty = finished jobs are not persisted.
  explicit JobTracker(int max_queue, std::string history_path = "")
      : max_queue_(max_queue), history_path_(std::move(history_path)) {}

  // Reads the history file (a missing file is an empty history; a corrupt
  // one is logged and ignored: history is informational).
  void LoadHistory();

  // Adds a queued job. RESOURCE_EXHAUSTED if `max_queue` jobs wait already
  // (`force` skips the limit: used when re-queuing after a restart, where a
  // finished record with the same id, e.g. "cancelled by shutdown", is
  // replaced).
  absl::Status Enqueue(JobStatus job, bool force = false);
  // Records a job that ended before it was queued (e.g. a parked scan).
  void AddFinished(JobStatus job);
  // Blocks until a job is queued (returns its id) or Shutdown() (nullopt).
  std::optional<std::string> WaitNext();
  // Blocks until a job is queued (true) or Shutdown() (false); pops nothing.
  bool WaitQueued();
  // Pops the next queued job like WaitNext, or nullopt at once if none.
  std::optional<std::string> TryNext();
  // Puts the running job back at the head of the queue (QUEUED): another
  // replica took its place's lease, so it trains it instead (coordinator.h).
  void Requeue(const std::string& id, const std::string& note);
  // Applies `mutate` to the job and notifies watchers.
  void Update(const std::string& id, const std::function<void(JobStatus*)>& mutate);
  absl::StatusOr<JobStatus> Get(const std::string& id) const;
  std::vector<JobStatus> List() const;  // In creation order.
  // Page of List(): `limit` jobs from `offset`; *total = all jobs.
  std::vector<JobStatus> List(size_t offset, size_t limit, size_t* total) const;
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
  void FinishedLocked();  // Trims and persists the history; caller holds mu_.
  void InsertLocked(JobStatus job);

  const int max_queue_;
  const std::string history_path_;
  bool history_warned_ = false;
  mutable std::mutex mu_;
  mutable std::condition_variable cv_;
  bool shutdown_ = false;
  std::map<std::string, JobStatus> jobs_;
  std::vector<std::string> order_;
  std::deque<std::string> queue_;
  std::string running_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_JOB_TRACKER_H_
