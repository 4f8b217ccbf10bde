#include "server/jobs/training_scheduler.h"

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

const std::string* TrainingScheduler::BestLocked() {
  const std::string* best_name = nullptr;
  uint64_t best_since = 0;
  for (auto& [name, p] : places_) {
    if (p.training || p.queue.empty()) continue;
    const uint64_t since = std::max(p.queue.front().second, p.last_finished);
    if (best_name == nullptr || since < best_since) {  // Ties: map order (place name).
      best_name = &name;
      best_since = since;
    }
  }
  return best_name;
}

std::optional<ScheduledJob> TrainingScheduler::Next() {
  std::unique_lock<std::mutex> lock(mu_);
  for (;;) {
    if (shutdown_) return std::nullopt;
    if (running_ < max_concurrent_) {
      if (const std::string* name = BestLocked()) {
        Place& p = places_[*name];
        ScheduledJob job{*name, p.queue.front().first};
        p.queue.pop_front();
        p.training = true;
        ++running_;
        return job;
      }
    }
    cv_.wait(lock);
  }
}

bool TrainingScheduler::Acquire(const std::string& place, const std::atomic<bool>* cancelled) {
  std::unique_lock<std::mutex> lock(mu_);
  const std::string ticket = "acquire-" + std::to_string(++tickets_);
  Place& mine = places_[place];
  mine.queue.emplace_back(ticket, ++clock_);
  cv_.notify_all();
  for (;;) {
    if (shutdown_ || (cancelled != nullptr && cancelled->load())) {
      auto& q = places_[place].queue;
      q.erase(std::find_if(q.begin(), q.end(), [&](const auto& e) { return e.first == ticket; }));
      cv_.notify_all();
      return false;
    }
    if (running_ < max_concurrent_) {
      const std::string* best = BestLocked();
      Place& p = places_[place];
      if (best != nullptr && *best == place && p.queue.front().first == ticket) {
        p.queue.pop_front();
        p.training = true;
        ++running_;
        return true;
      }
    }
    cv_.wait(lock);
  }
}

void TrainingScheduler::Wake() {
  std::lock_guard<std::mutex> lock(mu_);
  cv_.notify_all();
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
