#include "core/continual/continual_protocol.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"

namespace clnerf {

absl::StatusOr<UbBudget> ParseUbBudget(const std::string& name) {
  if (name == "total") return UbBudget::kTotal;
  if (name == "per-step") return UbBudget::kPerStep;
  return absl::InvalidArgumentError(absl::StrFormat("unknown ub budget '%s' (total, per-step)", name));
}

const char* UbBudgetName(UbBudget b) { return b == UbBudget::kTotal ? "total" : "per-step"; }

int UpperBoundIterations(UbBudget budget, int tasks, int iterations_per_update) {
  if (budget == UbBudget::kPerStep) return iterations_per_update;
  const long long total = (long long)std::max(tasks, 1) * iterations_per_update;
  return int(std::min<long long>(total, std::numeric_limits<int>::max()));
}

absl::StatusOr<ForgettingSummary> SummarizeForgetting(const std::vector<std::vector<double>>& r) {
  if (r.empty()) return absl::InvalidArgumentError("PSNR matrix is empty");
  for (size_t i = 0; i < r.size(); ++i) {
    if (r[i].size() != i + 1) {
      return absl::InvalidArgumentError(
          absl::StrFormat("PSNR matrix row %d has %d entries, expected %d", int(i), int(r[i].size()), int(i + 1)));
    }
    for (double x : r[i]) {
      if (!std::isfinite(x)) return absl::InvalidArgumentError(absl::StrFormat("PSNR matrix row %d is not finite", int(i)));
    }
  }
  ForgettingSummary s;
  const size_t T = r.size();
  s.tasks = int(T);
  s.final_per_scan = r.back();
  for (double x : r.back()) s.final_mean += x;
  s.final_mean /= double(T);
  if (T > 1) {
    double sum = 0;
    s.max_drop = -std::numeric_limits<double>::infinity();
    for (size_t j = 0; j + 1 < T; ++j) {
      const double d = r[T - 1][j] - r[j][j];
      sum += d;
      s.max_drop = std::max(s.max_drop, -d);
    }
    s.backward_transfer = sum / double(T - 1);
  }
  return s;
}

}  // namespace clnerf
