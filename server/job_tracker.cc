#include "server/job_tracker.h"

#include <algorithm>

#include "absl/strings/str_cat.h"

namespace clnerf {

const char* JobPhaseName(JobPhase p) {
  switch (p) {
    case JobPhase::kQueued: return "queued";
    case JobPhase::kPreparingReplay: return "preparing replay";
    case JobPhase::kTraining: return "training";
    case JobPhase::kValidating: return "validating";
    case JobPhase::kPublishing: return "publishing";
    case JobPhase::kDone: return "done";
    case JobPhase::kFailed: return "failed";
    case JobPhase::kCancelled: return "cancelled";
  }
  return "unknown";
}

int64_t NowUnixMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

absl::Status JobTracker::Enqueue(JobStatus job, bool force) {
  std::lock_guard<std::mutex> lock(mu_);
  if (shutdown_) return absl::UnavailableError("server is shutting down");
  if (!force && int(queue_.size()) >= max_queue_) {
    return absl::ResourceExhaustedError(
        absl::StrCat("update queue is full (", max_queue_, " scans wait for training); retry later"));
  }
  if (jobs_.count(job.job_id)) return absl::AlreadyExistsError(absl::StrCat("job ", job.job_id, " exists"));
  job.phase = JobPhase::kQueued;
  job.revision = 1;
  queue_.push_back(job.job_id);
  order_.push_back(job.job_id);
  jobs_.emplace(job.job_id, std::move(job));
  cv_.notify_all();
  return absl::OkStatus();
}

std::optional<std::string> JobTracker::WaitNext() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [&] { return shutdown_ || !queue_.empty(); });
  if (shutdown_) return std::nullopt;
  running_ = queue_.front();
  queue_.pop_front();
  return running_;
}

void JobTracker::Update(const std::string& id, const std::function<void(JobStatus*)>& mutate) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return;
  mutate(&it->second);
  ++it->second.revision;
  if (IsFinal(it->second.phase)) {
    if (it->second.finished_unix_ms == 0) it->second.finished_unix_ms = NowUnixMs();
    if (running_ == id) running_.clear();
  }
  cv_.notify_all();
}

absl::StatusOr<JobStatus> JobTracker::Get(const std::string& id) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return absl::NotFoundError(absl::StrCat("job '", id, "' does not exist"));
  return it->second;
}

std::vector<JobStatus> JobTracker::List() const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<JobStatus> out;
  for (const std::string& id : order_) out.push_back(jobs_.at(id));
  return out;
}

absl::StatusOr<JobStatus> JobTracker::WaitForChange(const std::string& id, uint64_t after_revision,
                                                    std::chrono::steady_clock::time_point deadline) const {
  std::unique_lock<std::mutex> lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return absl::NotFoundError(absl::StrCat("job '", id, "' does not exist"));
  cv_.wait_until(lock, deadline, [&] { return shutdown_ || it->second.revision > after_revision; });
  return it->second;
}

absl::StatusOr<bool> JobTracker::Cancel(const std::string& id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return absl::NotFoundError(absl::StrCat("job '", id, "' does not exist"));
  JobStatus& j = it->second;
  if (IsFinal(j.phase)) {
    return absl::FailedPreconditionError(absl::StrCat("job ", id, " already ended (", JobPhaseName(j.phase), ")"));
  }
  ++j.revision;
  auto q = std::find(queue_.begin(), queue_.end(), id);
  if (q != queue_.end()) {
    queue_.erase(q);
    j.phase = JobPhase::kCancelled;
    j.error = "cancelled before training started";
    j.finished_unix_ms = NowUnixMs();
    cv_.notify_all();
    return true;
  }
  j.cancel_requested = true;
  cv_.notify_all();
  return false;
}

int JobTracker::queued() const {
  std::lock_guard<std::mutex> lock(mu_);
  return int(queue_.size());
}

int JobTracker::running_or_queued() const {
  std::lock_guard<std::mutex> lock(mu_);
  return int(queue_.size()) + (running_.empty() ? 0 : 1);
}

std::string JobTracker::running() const {
  std::lock_guard<std::mutex> lock(mu_);
  return running_;
}

void JobTracker::Shutdown() {
  std::lock_guard<std::mutex> lock(mu_);
  shutdown_ = true;
  cv_.notify_all();
}

}  // namespace clnerf
