// TrainingScheduler: which place's update trains next, when many places
// share a fixed number of training slots (max_concurrent_trainings).
//
// Rules:
//   * each place's jobs train one at a time, in upload order (a place's
//     next scan trains on top of its previous one);
//   * among places waiting for a slot, the one whose wait started earliest
//     goes first, where a place's wait starts when its oldest queued job was
//     enqueued or when its previous job finished, whichever is later. With
//     free slots that is plain oldest-job-first; under contention it is
//     round robin, so a place with a long queue cannot starve the others: a
//     scan uploaded to a quiet place waits for at most one job of each busy
//     place per slot.
// Time is a logical clock (enqueues and finishes), so the order does not
// depend on timer resolution and tests are deterministic.
//
// Two ways to use it: a dispatcher (Enqueue, Next, Finish), or one update
// worker per place asking for a slot for its next job (Acquire, Finish),
// which is how the server shares max_concurrent_trainings among places.
//
// Thread-safety: every method is thread-safe; Next() blocks.
#ifndef CLNERF_SERVER_TRAINING_SCHEDULER_H_
#define CLNERF_SERVER_TRAINING_SCHEDULER_H_

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <string>

namespace clnerf {

struct ScheduledJob {
  std::string place;
  std::string job_id;
};

class TrainingScheduler {
 public:
  explicit TrainingScheduler(int max_concurrent) : max_concurrent_(max_concurrent < 1 ? 1 : max_concurrent) {}

  // Queues a job behind the place's earlier ones.
  void Enqueue(const std::string& place, const std::string& job_id);
  // Removes a queued (not yet started) job; false if it is not queued.
  bool Cancel(const std::string& place, const std::string& job_id);
  // Blocks until a slot is free and a place that is not training has a
  // queued job, then starts it (the caller must call Finish(place) when it
  // ends). nullopt once Shutdown() was called.
  std::optional<ScheduledJob> Next();
  // Ends the running job of `place` and frees its slot.
  void Finish(const std::string& place);

  // The form used by one update worker per place: waits its turn for a slot
  // as if a job of `place` had been queued now (so a worker coming back for
  // its place's next scan queues behind places already waiting), and takes
  // it. False when `cancelled` became true (checked on every Wake()) or on
  // Shutdown(); the caller then holds no slot. Release with Finish(place).
  bool Acquire(const std::string& place, const std::atomic<bool>* cancelled);
  // Makes waiting Acquire calls re-check their `cancelled` flags.
  void Wake();
  // Wakes every Next() with nullopt; queued jobs stay queued.
  void Shutdown();

  int queued(const std::string& place) const;
  bool training(const std::string& place) const;
  int running() const;
  int max_concurrent() const { return max_concurrent_; }

 private:
  // The waiting place to start next (free slot assumed), or null.
  const std::string* BestLocked();

  struct Place {
    std::deque<std::pair<std::string, uint64_t>> queue;  // (job id, enqueue time).
    uint64_t last_finished = 0;
    bool training = false;
  };

  const int max_concurrent_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::string, Place> places_;
  uint64_t clock_ = 0;
  int running_ = 0;
  uint64_t tickets_ = 0;
  bool shutdown_ = false;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_TRAINING_SCHEDULER_H_
