#include "server/training_scheduler.h"

#include <algorithm>

namespace clnerf {

void TrainingScheduler::Enqueue(const std::string& place, const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  places_[place].queue.emplace_back(job_id, ++clock_);
  cv_.notify_all();
}

bool TrainingScheduler::Cancel(const std::string& place, const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = places_.find(place);
  if (it == places_.end()) return false;
  auto& q = it->second.queue;
  auto j = std::find_if(q.begin(), q.end(), [&](const auto& e) { return e.first == job_id; });
  if (j == q.end()) return false;
  q.erase(j);
  return true;
}

std::optional<ScheduledJob> TrainingScheduler::Next() {
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    if (shutdown_) return std::nullopt;
    if (running_ < max_concurrent_) {
      Place* best = nullptr;
      const std::string* best_name = nullptr;
      uint64_t best_since = 0;
      for (auto& [name, p] : places_) {
        if (p.training || p.queue.empty()) continue;
        const uint64_t since = std::max(p.queue.front().second, p.last_finished);
        if (best == nullptr || since < best_since) {  // Ties: map order (place name).
          best = &p;
          best_name = &name;
          best_since = since;
        }
      }
      if (best != nullptr) {
        ScheduledJob job{*best_name, best->queue.front().first};
        best->queue.pop_front();
        best->training = true;
        ++running_;
        return job;
      }
    }
    cv_.wait(lock);
  }
}

void TrainingScheduler::Finish(const std::string& place) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = places_.find(place);
  if (it == places_.end() || !it->second.training) return;
  it->second.training = false;
  it->second.last_finished = ++clock_;
  --running_;
  cv_.notify_all();
}

void TrainingScheduler::Shutdown() {
  std::lock_guard<std::mutex> lock(mu_);
  shutdown_ = true;
  cv_.notify_all();
}

int TrainingScheduler::queued(const std::string& place) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = places_.find(place);
  return it == places_.end() ? 0 : int(it->second.queue.size());
}

bool TrainingScheduler::training(const std::string& place) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = places_.find(place);
  return it != places_.end() && it->second.training;
}

int TrainingScheduler::running() const {
  std::lock_guard<std::mutex> lock(mu_);
  return running_;
}

}  // namespace clnerf
