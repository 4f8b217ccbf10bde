// The continual-learning protocol's bookkeeping, shared by the benchmarks:
//  * the upper bound's budget: `ub` trains once on every scan, and by
//    default for the sequence's total compute (tasks x iterations per
//    update), so that it is compared with a continual method at equal
//    compute; UbBudget::kPerStep keeps the paper's protocol (the iterations
//    of one update);
//  * scores from the PSNR matrix R, where R[i][j] is the PSNR on scan j's
//    test views after update i (j <= i; row i has i + 1 entries): the final
//    mean (mean of the last row), backward transfer
//      BWT = mean over j < T-1 of (R[T-1][j] - R[j][j])
//    (Lopez-Paz & Ranzato, 2017; negative = forgetting), and the largest
//    single-scan drop.
// Pure functions; thread-safe.
#ifndef CLNERF_CORE_CONTINUAL_CONTINUAL_PROTOCOL_H_
#define CLNERF_CORE_CONTINUAL_CONTINUAL_PROTOCOL_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace clnerf {

enum class UbBudget {
  kTotal,    // tasks x iterations per update (equal compute; the default).
  kPerStep,  // The iterations of one update (the paper's protocol).
};

absl::StatusOr<UbBudget> ParseUbBudget(const std::string& name);  // "total" | "per-step"
const char* UbBudgetName(UbBudget b);
// Training iterations of the upper bound for a sequence of `tasks` scans.
int UpperBoundIterations(UbBudget budget, int tasks, int iterations_per_update);

struct ForgettingSummary {
  int tasks = 0;
  double final_mean = 0;         // Mean of R[T-1][*].
  double backward_transfer = 0;  // 0 when T == 1.
  double max_drop = 0;           // max over j < T-1 of R[j][j] - R[T-1][j] (>= 0 means some scan lost that much).
  std::vector<double> final_per_scan;  // R[T-1].
};

// INVALID_ARGUMENT unless R is lower-triangular as described (row i has
// i + 1 finite entries) and non-empty.
absl::StatusOr<ForgettingSummary> SummarizeForgetting(const std::vector<std::vector<double>>& psnr_matrix);

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_CONTINUAL_PROTOCOL_H_
