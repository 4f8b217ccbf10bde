#include "client/progress_bar.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"

namespace clnerf {

std::string FormatDuration(double s) {
  if (!std::isfinite(s) || s < 0) return "?";
  if (s < 60) return absl::StrFormat("%.1fs", s);
  if (s < 3600) return absl::StrFormat("%dm%02ds", int(s) / 60, int(s) % 60);
  return absl::StrFormat("%dh%02dm", int(s) / 3600, (int(s) / 60) % 60);
}

std::string FormatCount(double v) {
  if (v >= 1e6) return absl::StrFormat("%.2fM", v / 1e6);
  if (v >= 1e3) return absl::StrFormat("%.1fk", v / 1e3);
  return absl::StrFormat("%.0f", v);
}

ProgressBar::ProgressBar(std::string label, long long total, FILE* out, int log_every_percent)
    : label_(std::move(label)),
      total_(std::max(total, 1LL)),
      out_(out),
      tty_(isatty(fileno(out)) != 0),
      log_every_percent_(std::max(1, log_every_percent)),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_ - std::chrono::seconds(1)) {}

std::string ProgressBar::Line(long long done, const std::string& metrics) const {
  const double frac = std::clamp(double(done) / double(total_), 0.0, 1.0);
  double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  double eta = frac > 0 ? elapsed * (1.0 - frac) / frac : NAN;
  if (external_timing_) {
    elapsed = external_elapsed_;
    eta = done >= total_ ? 0.0 : external_eta_;
  }
  constexpr int kWidth = 24;
  const int fill = int(frac * kWidth);
  std::string bar(fill, '=');
  if (fill < kWidth) bar += '>' + std::string(kWidth - fill - 1, ' ');
  std::string line = absl::StrFormat("%s [%s] %3d%% %lld/%lld | %s ETA %s", label_, bar, int(frac * 100), done,
                                     total_, FormatDuration(elapsed), FormatDuration(eta));
  if (!metrics.empty()) line += " | " + metrics;
  return line;
}

void ProgressBar::Update(long long done, const std::string& metrics) {
  const auto now = std::chrono::steady_clock::now();
  if (tty_) {
    if (now - last_draw_ < std::chrono::milliseconds(100) && done < total_) return;
    last_draw_ = now;
    drawn_ = true;
    std::fprintf(out_, "\r\033[K%s", Line(done, metrics).c_str());
    std::fflush(out_);
    return;
  }
  const int pct = int(100.0 * double(done) / double(total_));
  if (pct / log_every_percent_ > last_logged_percent_ / log_every_percent_ || last_logged_percent_ < 0) {
    last_logged_percent_ = pct;
    std::fprintf(out_, "%s\n", Line(done, metrics).c_str());
    std::fflush(out_);
  }
}

void ProgressBar::Finish(const std::string& metrics) {
  if (finished_) return;
  finished_ = true;
  std::fprintf(out_, tty_ ? "\r\033[K%s\n" : "%s\n", Line(total_, metrics).c_str());
  std::fflush(out_);
}

void ProgressBar::Abort() {
  if (finished_) return;
  finished_ = true;
  if (tty_ && drawn_) {
    std::fprintf(out_, "\n");
    std::fflush(out_);
  }
}

void ProgressBar::SetTiming(double elapsed_seconds, double eta_seconds) {
  external_timing_ = true;
  external_elapsed_ = elapsed_seconds;
  external_eta_ = eta_seconds;
}

}  // namespace clnerf
