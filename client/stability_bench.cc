// `clnerf bench stability`: the stability matrix (core/continual/stability.h): every
// method against every stressor on a small procedural changing scene. Prints
// one line per cell as it finishes, then a markdown table (rows: methods,
// columns: stressors) and JSON. Exits 4 if any cell broke an invariant (a
// non-finite model deployed, or θ_{t-1} modified by an update).
#include <chrono>
#include <cstdio>
#include <fstream>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/commands.h"
#include "client/verb_set.h"
#include "core/continual/stability.h"
#include "nlohmann/json.hpp"

namespace clnerf {

CLI::App* BindBenchStability(CLI::App* parent, BenchStabilityArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "stability", "Stability matrix: every continual method (and ub) against every stressor, through the deployment gate");
  StabilityOptions& o = a->stability;
  c->add_option("--methods", a->methods, "Methods (nt ewc er meil clnerf-noer clnerf ub)")->delimiter(',');
  c->add_option("--stressors", a->stressors,
                "Stressors (default all: none iters_x5 lr_x3 lr_x10 chain_20 blank_scan single_view far_cameras "
                "nan_gradient stale_memory)")
      ->delimiter(',');
  c->add_option("--scans", o.scans, "Scans of the procedural sequence (chain_20: 20)")->capture_default_str();
  c->add_option("--size", o.image_size, "Image size of the procedural scans")->capture_default_str();
  c->add_option("--iters", o.iterations, "Training steps per update (ub: scans x this)")->capture_default_str();
  c->add_option("--batch-samples", o.batch_samples, "Samples per training batch (rays adapt)")->capture_default_str();
  c->add_option("--seed", o.seed, "Random seed")->capture_default_str();
  BindThreadsFlag(c, &o.threads);
  c->add_option("--json", a->json, "Write JSON here ('-' = stdout)");
  c->add_option("--markdown", a->markdown, "Also write the markdown table here");
  return c;
}

int RunBenchStability(const BenchStabilityArgs& a) {
  const StabilityOptions& o = a.stability;
  SetThreads(o.threads);
  if (absl::Status s = o.Validate(); !s.ok()) return Fail(s);
  std::vector<Stressor> stressors;
  if (a.stressors.empty()) {
    stressors = AllStressors();
  } else {
    for (const std::string& n : a.stressors) {
      absl::StatusOr<Stressor> s = ParseStressor(n);
      if (!s.ok()) return Fail(s.status());
      stressors.push_back(*s);
    }
  }
  if (a.methods.empty()) return Fail(absl::InvalidArgumentError("--methods is empty"));

  const auto t0 = std::chrono::steady_clock::now();
  nlohmann::json cells = nlohmann::json::array();
  std::vector<std::vector<std::string>> table;
  bool broken = false;
  int done = 0;
  const int total = int(a.methods.size() * stressors.size());
  for (const std::string& m : a.methods) {
    std::vector<std::string> row = {m};
    for (Stressor s : stressors) {
      absl::StatusOr<StabilityCell> c = RunStabilityCell(m, s, o);
      if (!c.ok()) return Fail(c.status());
      ++done;
      const std::string summary = c->Summary();
      std::fprintf(stderr, "[%d/%d] %-11s %-12s %-24s %5.1fs %s\n", done, total, m.c_str(), StressorName(s),
                   summary.c_str(), c->seconds, c->stressed_deployed ? "" : c->reason.c_str());
      row.push_back(summary);
      broken |= !c->deployed_always_finite || !c->previous_always_intact;
      cells.push_back({{"method", m},
                       {"stressor", StressorName(s)},
                       {"applicable", c->applicable},
                       {"summary", summary},
                       {"stressed_deployed", c->stressed_deployed},
                       {"psnr", c->psnr},
                       {"refused_psnr", c->refused_psnr},
                       {"scored_scans", c->scored_scans},
                       {"updates", c->updates},
                       {"failed", c->failed},
                       {"refused", c->refused},
                       {"skipped_batches", c->skipped_batches},
                       {"reason", c->reason},
                       {"deployed_always_finite", c->deployed_always_finite},
                       {"previous_always_intact", c->previous_always_intact},
                       {"seconds", c->seconds}});
    }
    table.push_back(std::move(row));
  }
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  std::string md = "| method |";
  for (Stressor s : stressors) md += absl::StrFormat(" %s |", StressorName(s));
  md += "\n|---|";
  for (size_t i = 0; i < stressors.size(); ++i) md += "---|";
  md += "\n";
  for (const auto& row : table) md += "| " + absl::StrJoin(row, " | ") + " |\n";
  std::printf("%s", md.c_str());
  std::printf(
      "bench stability: %d methods x %d stressors on %d procedural %dx%d scans, %d iterations/update | %.0fs | "
      "invariants (no non-finite model deployed, previous model intact): %s\n",
      int(a.methods.size()), int(stressors.size()), o.scans, o.image_size, o.image_size, o.iterations, secs,
      broken ? "BROKEN" : "held in every cell");
  nlohmann::json j = {{"scans", o.scans},          {"chain_scans", o.chain_scans}, {"image_size", o.image_size},
                      {"iterations", o.iterations}, {"seed", o.seed},              {"seconds", secs},
                      {"invariants_held", !broken}, {"cells", cells}};
  std::printf("%s\n", j.dump().c_str());
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  if (!a.markdown.empty()) {
    std::ofstream f(a.markdown);
    f << md;
    if (!f) return Fail(absl::InternalError("cannot write " + a.markdown));
  }
  return broken ? 4 : 0;
}

}  // namespace clnerf
