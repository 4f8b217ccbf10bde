#include "client/remote_format.h"

#include <map>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"

namespace clnerf {

std::string PhaseName(clnerf::v1::JobPhase phase) {
  std::string name = clnerf::v1::JobPhase_Name(phase);
  constexpr absl::string_view kPrefix = "JOB_PHASE_";
  if (absl::StartsWith(name, kPrefix)) name = name.substr(kPrefix.size());
  return name.empty() ? absl::StrFormat("PHASE_%d", int(phase)) : name;
}

bool IsTerminal(clnerf::v1::JobPhase phase) {
  return phase == clnerf::v1::JOB_PHASE_DONE || phase == clnerf::v1::JOB_PHASE_FAILED ||
         phase == clnerf::v1::JOB_PHASE_CANCELLED;
}

std::string FormatUnixMs(int64_t unix_ms) {
  if (unix_ms <= 0) return "-";
  return absl::FormatTime("%Y-%m-%d %H:%M:%S", absl::FromUnixMillis(unix_ms), absl::LocalTimeZone());
}

std::string FormatBytes(int64_t b) {
  if (b < 1000) return absl::StrFormat("%d B", b);
  if (b < 1000000) return absl::StrFormat("%.1f KB", b / 1e3);
  if (b < 1000000000) return absl::StrFormat("%.2f MB", b / 1e6);
  return absl::StrFormat("%.2f GB", b / 1e9);
}

std::string FormatMetrics(const google::protobuf::Map<std::string, double>& metrics) {
  if (metrics.empty()) return "-";
  const std::map<std::string, double> sorted(metrics.begin(), metrics.end());
  std::string out;
  for (const auto& [k, v] : sorted) {
    if (!out.empty()) out += ' ';
    out += absl::StrFormat("%s=%.4g", k, v);
  }
  return out;
}

}  // namespace clnerf
