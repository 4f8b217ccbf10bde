#include "server/jobs/job_tracker.h"

#include <algorithm>
#include <limits>

#include "absl/strings/str_cat.h"
#include "core/io/durable_file.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

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
    case JobPhase::kRegistering: return "registering";
    case JobPhase::kPosing: return "posing";
    case JobPhase::kBaking: return "baking";
  }
  return "unknown";
}

nlohmann::json JobToJson(const JobStatus& j) {
  return {{"job_id", j.job_id},
          {"scan_id", j.scan_id},
          {"scan_name", j.scan_name},
          {"phase", JobPhaseName(j.phase)},
          {"time_step", j.time_step},
          {"iteration", j.iteration},
          {"total_iterations", j.total_iterations},
          {"elapsed_seconds", j.elapsed_seconds},
          {"loss", j.loss},
          {"psnr", j.psnr},
          {"version", j.version},
          {"error", j.error},
          {"created_unix_ms", j.created_unix_ms},
          {"finished_unix_ms", j.finished_unix_ms},
          {"metrics", j.metrics}};
}

namespace {

bool JobFromJson(const nlohmann::json& o, JobStatus* j) {
  const std::string phase = o.at("phase");
  bool found = false;
  for (JobPhase p : {JobPhase::kDone, JobPhase::kFailed, JobPhase::kCancelled}) {
    if (phase == JobPhaseName(p)) {
      j->phase = p;
      found = true;
    }
  }
  if (!found) return false;
  j->job_id = o.at("job_id");
  j->scan_id = o.at("scan_id");
  j->scan_name = o.at("scan_name");
  j->time_step = o.at("time_step");
  j->iteration = o.at("iteration");
  j->total_iterations = o.at("total_iterations");
  j->elapsed_seconds = o.at("elapsed_seconds");
  j->loss = o.at("loss");
  j->psnr = o.at("psnr");
  j->version = o.at("version");
  j->error = o.at("error");
  j->created_unix_ms = o.at("created_unix_ms");
  j->finished_unix_ms = o.at("finished_unix_ms");
  j->metrics = o.at("metrics").get<std::map<std::string, double>>();
  j->revision = 1;
  return true;
}

}  // namespace

void JobTracker::LoadHistory() {
  if (history_path_.empty()) return;
  RemoveAtomicWriteTemps(history_path_);  // Left by a crash during a save.
  absl::StatusOr<std::string> text = ReadFileToString(history_path_, "job history");
  if (!text.ok()) {
    if (!absl::IsNotFound(text.status())) spdlog::warn("job history not read: {}", text.status().ToString());
    return;
  }
  std::lock_guard<std::mutex> lock(mu_);
  try {
    const nlohmann::json doc = nlohmann::json::parse(*text);  // Must outlive the loop.
    for (const nlohmann::json& o : doc.at("jobs")) {
      JobStatus j;
      if (!JobFromJson(o, &j) || jobs_.count(j.job_id)) continue;
      InsertLocked(std::move(j));
    }
  } catch (const std::exception& e) {
    spdlog::warn("job history {} is corrupt and was ignored: {}", history_path_, e.what());
  }
}

void JobTracker::InsertLocked(JobStatus job) {
  order_.push_back(job.job_id);
  jobs_.emplace(job.job_id, std::move(job));
}

void JobTracker::FinishedLocked() {
  // Forget the oldest finished jobs beyond the cap.
  size_t finished = 0;
  for (const std::string& id : order_) finished += IsFinal(jobs_.at(id).phase);
  for (auto it = order_.begin(); finished > kMaxHistory && it != order_.end();) {
    if (IsFinal(jobs_.at(*it).phase)) {
      jobs_.erase(*it);
      it = order_.erase(it);
      --finished;
    } else {
      ++it;
    }
  }
  if (history_path_.empty()) return;
  nlohmann::json arr = nlohmann::json::array();
  for (const std::string& id : order_) {
    const JobStatus& j = jobs_.at(id);
    if (IsFinal(j.phase)) arr.push_back(JobToJson(j));
  }
  const nlohmann::json doc = {{"jobs", std::move(arr)}};
  // error_handler::replace: names are validated, but older stores may hold
  // anything; history must never throw.
  const std::string text = doc.dump(0, ' ', false, nlohmann::json::error_handler_t::replace);
  if (absl::Status s = AtomicWriteFile(history_path_, text); !s.ok()) {
    if (!history_warned_) spdlog::warn("job history not saved: {}", s.ToString());
    history_warned_ = true;
  } else {
    history_warned_ = false;
  }
}

absl::Status JobTracker::Enqueue(JobStatus job, bool force) {
  std::lock_guard<std::mutex> lock(mu_);
  if (shutdown_) return absl::UnavailableError("server is shutting down");
  if (!force && int(queue_.size()) >= max_queue_) {
    return absl::ResourceExhaustedError(
        absl::StrCat("update queue is full (", max_queue_, " scans wait for training); retry later"));
  }
  if (auto it = jobs_.find(job.job_id); it != jobs_.end()) {
    if (!force || !IsFinal(it->second.phase)) {
      return absl::AlreadyExistsError(absl::StrCat("job ", job.job_id, " exists"));
    }
    jobs_.erase(it);
    order_.erase(std::find(order_.begin(), order_.end(), job.job_id));
  }
  job.phase = JobPhase::kQueued;
  job.revision = 1;
  queue_.push_back(job.job_id);
  InsertLocked(std::move(job));
  cv_.notify_all();
  return absl::OkStatus();
}

void JobTracker::AddFinished(JobStatus job) {
  std::lock_guard<std::mutex> lock(mu_);
  if (auto it = jobs_.find(job.job_id); it != jobs_.end()) {
    jobs_.erase(it);
    order_.erase(std::find(order_.begin(), order_.end(), job.job_id));
  }
  if (job.finished_unix_ms == 0) job.finished_unix_ms = NowUnixMs();
  job.revision = 1;
  // Keep creation order: a record restored at start-up may be older than
  // jobs already known.
  auto pos = std::find_if(order_.begin(), order_.end(),
                          [&](const std::string& id) { return jobs_.at(id).created_unix_ms > job.created_unix_ms; });
  order_.insert(pos, job.job_id);
  jobs_.emplace(job.job_id, std::move(job));
  FinishedLocked();
  cv_.notify_all();
}

std::optional<std::string> JobTracker::WaitNext() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [&] { return shutdown_ || !queue_.empty(); });
  if (shutdown_) return std::nullopt;
  running_ = queue_.front();
  queue_.pop_front();
  return running_;
}

bool JobTracker::WaitQueued() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [&] { return shutdown_ || !queue_.empty(); });
  return !shutdown_;
}

std::optional<std::string> JobTracker::TryNext() {
  std::lock_guard<std::mutex> lock(mu_);
  if (shutdown_ || queue_.empty()) return std::nullopt;
  running_ = queue_.front();
  queue_.pop_front();
  return running_;
}

void JobTracker::Requeue(const std::string& id, const std::string& note) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end() || IsFinal(it->second.phase)) return;
  it->second.phase = JobPhase::kQueued;
  it->second.error = note;
  it->second.iteration = 0;
  ++it->second.revision;
  if (running_ == id) running_.clear();
  if (std::find(queue_.begin(), queue_.end(), id) == queue_.end()) queue_.push_front(id);
  cv_.notify_all();
}

void JobTracker::Update(const std::string& id, const std::function<void(JobStatus*)>& mutate) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(id);
  if (it == jobs_.end()) return;
  const bool was_final = IsFinal(it->second.phase);
  mutate(&it->second);
  ++it->second.revision;
  if (IsFinal(it->second.phase)) {
    if (it->second.finished_unix_ms == 0) it->second.finished_unix_ms = NowUnixMs();
    if (running_ == id) running_.clear();
    // Resolved while queued (by another replica's publish, say): not run.
    queue_.erase(std::remove(queue_.begin(), queue_.end(), id), queue_.end());
    if (!was_final) FinishedLocked();
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
  size_t total = 0;
  return List(0, std::numeric_limits<size_t>::max(), &total);
}

std::vector<JobStatus> JobTracker::List(size_t offset, size_t limit, size_t* total) const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<JobStatus> out;
  *total = order_.size();
  for (size_t i = offset; i < order_.size() && out.size() < limit; ++i) out.push_back(jobs_.at(order_[i]));
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
    FinishedLocked();
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
