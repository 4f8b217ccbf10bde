// ProgressBar: a one-line terminal progress display for long CLI work
// (training, uploads): bar, percentage, counts, elapsed/ETA and free-form
// metrics. On a TTY it redraws in place; otherwise (CI, pipes) it prints a
// plain line every `log_every_percent`. Not thread-safe: one owner thread.
#ifndef CLNERF_CLIENT_PROGRESS_BAR_H_
#define CLNERF_CLIENT_PROGRESS_BAR_H_

#include <chrono>
#include <cstdio>
#include <string>

namespace clnerf {

class ProgressBar {
 public:
  ProgressBar(std::string label, long long total, FILE* out = stderr, int log_every_percent = 10);
  // Updates the display; `metrics` is appended after the ETA.
  void Update(long long done, const std::string& metrics = "");
  // Draws the final state and ends the line.
  void Finish(const std::string& metrics = "");
  // Ends a TTY line left mid-way (e.g. before an error message) without
  // drawing the final state.
  void Abort();
  // Uses these elapsed / remaining seconds instead of the bar's own clock,
  // for work measured elsewhere (a server-side job followed from its middle).
  void SetTiming(double elapsed_seconds, double eta_seconds);

 private:
  std::string Line(long long done, const std::string& metrics) const;
  std::string label_;
  long long total_;
  FILE* out_;
  bool tty_;
  int log_every_percent_;
  int last_logged_percent_ = -1;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
  bool finished_ = false;
  bool drawn_ = false;
  bool external_timing_ = false;
  double external_elapsed_ = 0, external_eta_ = 0;
};

// "12.3s", "4m05s", "1h02m".
std::string FormatDuration(double seconds);
// "812", "45.2k", "1.23M".
std::string FormatCount(double value);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_PROGRESS_BAR_H_
