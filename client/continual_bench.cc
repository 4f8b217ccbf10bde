// `clnerf bench continual`: runs one method through every step of a scan
// sequence (the paper's protocol), then reports accuracy, forgetting, time
// and memory as a human-readable line plus JSON.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <optional>

#include "absl/strings/str_format.h"
#include "client/commands.h"
#include "client/core_flags.h"
#include "client/verb_set.h"
#include "client/progress_bar.h"
#include "core/continual/continual_protocol.h"
#include "core/continual/continual_update.h"
#include "core/render/evaluate.h"
#include "core/train/fit.h"
#include "core/data/procedural_scene.h"
#include "core/continual/scan_sequence.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

double Since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

size_t PeakRssBytes() {
  struct rusage u {};
  getrusage(RUSAGE_SELF, &u);
  return size_t(u.ru_maxrss) * 1024;  // Linux reports kilobytes.
}

// The project's changing scene: `scans` time steps with lighting and geometry
// changes, 30 train + 10 test views each.
absl::StatusOr<ScanSequence> ProceduralSequence(int scans, int size, uint64_t seed) {
  ProceduralSceneOptions po;
  po.name = "procedural";
  po.width = po.height = size;
  po.num_train_views = 30;
  po.num_test_views = 10;
  po.num_time_steps = scans;
  po.seed = seed;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  if (!scene.ok()) return scene.status();
  return FromTimeSteps(*scene);
}

struct Scores {
  std::vector<double> psnr;  // Mean PSNR per scan's test set.
  double mean_psnr = 0, mean_ssim = 0;  // Means over all test images.
  int images = 0;
};

// Scores `model` on the test views of scans 0..last.
absl::StatusOr<Scores> Score(const NgpModel& model, const ScanSequence& seq, int last) {
  Scores s;
  for (int j = 0; j <= last; ++j) {
    if (seq.scans[j].test.empty()) {
      s.psnr.push_back(0);
      continue;
    }
    absl::StatusOr<EvalResult> ev = EvaluateViews(model, seq.scans[j].test, EvalOptions{});
    if (!ev.ok()) return ev.status();
    s.psnr.push_back(ev->psnr);
    for (const ViewScore& v : ev->views) {
      s.mean_psnr += v.psnr;
      s.mean_ssim += v.ssim;
      ++s.images;
    }
  }
  if (s.images > 0) {
    s.mean_psnr /= s.images;
    s.mean_ssim /= s.images;
  }
  return s;
}

}  // namespace

CLI::App* BindBenchContinual(CLI::App* parent, BenchContinualArgs* a) {
  CLI::App* c = parent->add_subcommand("continual", "Run one continual method through every step of a scan sequence");
  UpdateOptions& u = a->update;
  u.train.iterations = 300;  // The verb's default: a quick sequence.
  c->add_option("--method", a->method, "nt|ewc|er|meil|clnerf|clnerf-noer|ub")->capture_default_str();
  c->add_option("--data", a->data,
                "Static dataset (cut into --tasks), dataset with time steps, directory of scan folders, or "
                "'procedural'")
      ->required();
  c->add_option("--tasks", a->tasks, "Tasks for a static dataset / scans for 'procedural' (0 = 10 / 5)")
      ->capture_default_str();
  c->add_option("--iters", u.train.iterations, "Training steps per update")->capture_default_str();
  BindEnumFlag(c, "--ub-budget", &a->ub_budget, {UbBudget::kTotal, UbBudget::kPerStep}, UbBudgetName,
               "ub's iterations: tasks x --iters (equal compute) or --iters (the paper's protocol)");
  BindEnumFlag(c, "--init", &u.init, {InitMode::kWarm, InitMode::kReinit}, InitModeName,
               "Start each update from the previous model or from scratch");
  BindEnumFlag(c, "--replay", &u.replay, {ReplayMode::kOffline, ReplayMode::kOnline}, ReplayModeName,
               "Generative replay labels rendered once per update or per batch");
  c->add_option("--replay-labels-per-draw", u.replay_labels.labels_per_draw,
                 "Offline replay: labels rendered per replay ray the update draws (0 = every pixel of every past view)")
      ->capture_default_str();
  c->add_option("--replay-seen-weight", u.replay_weights.seen_weight,
                "Offline replay: weight of labels whose surface the new scan sees unchanged (1 = off, 0 = dropped)")
      ->capture_default_str();
  c->add_option("--error-share", u.view_error.error_share,
                 "Share of view draws proportional to each view's current error (0 = uniform over views)")
      ->capture_default_str();
  c->add_option("--ub-error-share", a->ub_error_share,
                 "ub only: share of view draws proportional to error (0 = uniform over views)")
      ->capture_default_str();
  c->add_option("--error-tiles", u.view_error.tiles,
                 "Error sampling: each view is cut into this many x this many tiles, each with its own error")
      ->capture_default_str();
  c->add_option("--error-decay", u.view_error.decay, "Error sampling: per-step decay of the error estimates")
      ->capture_default_str();
  c->add_flag("--seen-label-from-photo", u.replay_weights.seen_label_from_photo,
              "A replay label the new scan sees unchanged takes the new photo's colour there (with --replay-seen-weight)");
  c->add_option("--replay-agreement", u.replay_confidence.agreement_tolerance,
                 "Replay labels where θ_{t-1} and θ_{t-2} differ by this much (mean |RGB|) get half weight (0 = off)")
      ->capture_default_str();
  c->add_option("--replay-transmittance", u.replay_confidence.transmittance_weight,
                "Weight a half-opaque replay label loses, in [0, 1] (0 = off)")
      ->capture_default_str();
  c->add_option("--replay-depth-min-opacity", u.replay_labels.depth_min_opacity,
                "Offline replay: labels at least this opaque also teach θ_{t-1}'s depth (0 = off)")
      ->capture_default_str();
  c->add_option("--buffer", u.buffer_size, "Real images kept for experience replay (clnerf, er)")
      ->capture_default_str();
  c->add_flag("--prioritized", u.prioritized_buffer, "Buffer keeps the lowest-PSNR images instead of a reservoir");
  c->add_flag("!--no-embed", u.model.network.use_embeddings, "Ablation: no per-time-step embeddings");
  c->add_option("--ewc-lambda", u.ewc_lambda, "EWC strength")->capture_default_str();
  c->add_option("--warm-lr-scale", u.warm_lr_scale, "Learning-rate factor for warm-started updates")
      ->capture_default_str();
  c->add_option("--new-share", u.new_scan_share,
                "clnerf/clnerf-noer/er: fraction of each batch from the new scan (0 = uniform over all views)")
      ->capture_default_str();
  c->add_flag("--copy-embedding", u.copy_embedding,
              "Warm start: the new time step's embeddings start as a copy of the last step's");
  c->add_flag("--paper-protocol", a->paper_protocol,
              "The paper's protocol: every update re-initialises and trains for ub's whole budget (tasks x --iters); "
              "ub is unchanged");
  c->add_flag("--carry-optimizer,!--fresh-optimizer", u.carry_optimizer,
              "Warm start: continue the previous update's Adam moments and step count (or a fresh one per update)")
      ->capture_default_str();
  BindEnumFlag(c, "--lr-schedule", &u.train.lr_schedule,
               {LrSchedule::kCosine, LrSchedule::kInverseSqrt, LrSchedule::kInverseSqrtCosine}, LrScheduleName,
               "Learning rate: a cosine per update, or one inverse-sqrt schedule over the sequence (with the "
               "optimiser's step count), optionally with each update's cosine under it");
  c->add_option("--lr-timescale", u.train.lr_timescale, "tau of the inverse-sqrt schedules in steps (0 = --iters)")
      ->capture_default_str();
  c->add_option("--procedural-size", a->procedural_size, "Image size of the procedural scans")->capture_default_str();
  c->add_option("--seed", u.train.seed, "Random seed")->capture_default_str();
  c->add_option("--occupancy-decay", u.model.occupancy.decay,
                "Occupancy grid: each refreshed cell's density EMA keeps max(decay * old, new) (docs/render_cost.md)")
      ->capture_default_str();
  BindThreadsFlag(c, &u.train.threads);
  c->add_option("--json", a->json, "Write JSON here ('-' = stdout)");
  BindDatasetFlags(c, &a->dataset);
  return c;
}

int RunBenchContinual(const BenchContinualArgs& a) {
  SetThreads(a.update.train.threads);
  const bool ub = a.method == "ub";
  UpdateOptions uo = a.update;
  if (!ub) {
    absl::StatusOr<ContinualMethod> m = ParseContinualMethod(a.method);
    if (!m.ok()) return Fail(absl::InvalidArgumentError(absl::StrCat(m.status().message(), " or ub")));
    uo.method = *m;
  }
  if (uo.method == ContinualMethod::kCLNeRFNoER) uo.buffer_size = 0;
  if (absl::Status s = uo.Validate(); !s.ok()) return Fail(s);
  int iterations = uo.train.iterations;
  const uint64_t seed = uo.train.seed;

  const bool procedural = a.data == "procedural";
  const int tasks = a.tasks > 0 ? a.tasks : (procedural ? 5 : 10);
  absl::StatusOr<ScanSequence> seq_or = [&]() -> absl::StatusOr<ScanSequence> {
    if (procedural) return ProceduralSequence(tasks, a.procedural_size, seed);
    return LoadScanSequence(a.data, tasks, a.dataset);
  }();
  if (!seq_or.ok()) return Fail(seq_or.status());
  const ScanSequence& seq = *seq_or;
  const int T = seq.size();
  int num_test = 0;
  for (const Scan& s : seq.scans) num_test += int(s.test.size());
  if (a.paper_protocol && !ub) {
    // IntelLabs/CLNeRF's protocol: every step trains a fresh model for ub's
    // whole budget (its scripts give each step ub's epochs).
    uo.init = InitMode::kReinit;
    iterations = uo.train.iterations = T * iterations;
  }
  spdlog::info("bench continual: method {} on '{}': {} steps, {} test images, {} iterations per step", a.method,
               seq.name, T, num_test, iterations);

  nlohmann::json j = {{"method", a.method},
                      {"data", a.data},
                      {"scene", seq.name},
                      {"tasks", T},
                      {"iterations", iterations},
                      {"init", InitModeName(uo.init)},
                      {"replay", ReplayModeName(uo.replay)},
                      {"replay_labels_per_draw", uo.replay_labels.labels_per_draw},
                      {"buffer", uo.buffer_size},
                      {"prioritized", uo.prioritized_buffer},
                      {"embeddings", uo.model.network.use_embeddings},
                      {"seed", seed},
                      {"occupancy_decay", uo.model.occupancy.decay},
                      {"threads", uo.train.threads},
                      {"status", "ok"}};
  if (uo.method == ContinualMethod::kEWC && !ub) j["ewc_lambda"] = uo.ewc_lambda;
  const int ub_iterations = UpperBoundIterations(a.ub_budget, T, iterations);
  if (ub) {
    j["ub_error_share"] = a.ub_error_share;
    j["ub_budget"] = UbBudgetName(a.ub_budget);
    j["ub_iterations"] = ub_iterations;
  }
  if (uo.warm_lr_scale != 1.0f) j["warm_lr_scale"] = uo.warm_lr_scale;
  if (uo.new_scan_share > 0) j["new_scan_share"] = uo.new_scan_share;
  if (uo.copy_embedding) j["copy_embedding"] = true;
  j["carry_optimizer"] = uo.carry_optimizer;
  j["replay_seen_weight"] = uo.replay_weights.seen_weight;
  j["replay_depth_min_opacity"] = uo.replay_labels.depth_min_opacity;
  j["error_share"] = ub ? a.ub_error_share : uo.view_error.error_share;
  j["error_tiles"] = uo.view_error.tiles;
  j["error_decay"] = uo.view_error.decay;
  j["seen_label_from_photo"] = uo.replay_weights.seen_label_from_photo;
  j["replay_agreement"] = uo.replay_confidence.agreement_tolerance;
  j["replay_transmittance"] = uo.replay_confidence.transmittance_weight;
  j["lr_schedule"] = LrScheduleName(uo.train.lr_schedule);
  j["protocol"] = a.paper_protocol ? "paper" : "equal-compute";
  nlohmann::json matrix = nlohmann::json::array(), step_seconds = nlohmann::json::array();
  nlohmann::json steps = nlohmann::json::array();
  double total = 0, eval_seconds = 0;
  std::shared_ptr<const NgpModel> final_model;
  Scores f;  // The final model on every scan's test views.
  size_t replay_bytes = 0, camera_bytes = 0, max_cache = 0;
  double bytes_per_camera = 0;

  if (ub) {
    // Upper bound: one training run on all scans (each view keeps its own
    // time step), for the sequence's total budget (or one update's).
    FitOptions fo;
    fo.train = uo.train;
    fo.train.iterations = ub_iterations;
    fo.model = uo.model;
    fo.view_error = uo.view_error;  // Tiles and decay as the updates'; the share is ub's own.
    fo.view_error.error_share = a.ub_error_share;
    const Scene all = seq.Union(T - 1);
    ProgressBar bar(absl::StrFormat("ub %d steps", T), ub_iterations);
    const auto t0 = std::chrono::steady_clock::now();
    absl::StatusOr<FitResult> fit = FitScene(all, fo, [&](const StepStats& s, const Trainer&) {
      bar.Update(s.step, absl::StrFormat("loss %.5f | psnr %.2f", s.loss, s.psnr));
    });
    if (!fit.ok()) {
      std::fprintf(stderr, "\n");
      return Fail(fit.status());
    }
    bar.Finish();
    total = Since(t0);
    step_seconds.push_back(total);
    final_model = std::move(fit->model);
    const auto e0 = std::chrono::steady_clock::now();
    absl::StatusOr<Scores> sc = Score(*final_model, seq, T - 1);
    if (!sc.ok()) return Fail(sc.status());
    eval_seconds += Since(e0);
    matrix.push_back(sc->psnr);
    f = *sc;
  } else {
    std::optional<ContinualState> state;
    for (int t = 0; t < T; ++t) {
      std::optional<ProgressBar> bar;
      UpdatePhase phase = UpdatePhase::kFinalizing;
      auto on_progress = [&](const UpdateProgress& p) {
        if (!bar || p.phase != phase) {
          if (bar) bar->Finish();
          phase = p.phase;
          bar.emplace(absl::StrFormat("step %d/%d %s", t + 1, T, UpdatePhaseName(p.phase)), std::max(1, p.total));
        }
        bar->Update(p.iteration, p.phase == UpdatePhase::kTraining
                                     ? absl::StrFormat("loss %.5f | psnr %.2f", p.loss, p.psnr)
                                     : std::string());
      };
      UpdateReport rep;
      const auto t0 = std::chrono::steady_clock::now();
      absl::StatusOr<ContinualState> next =
          ContinualUpdate(seq.ScanScene(t), state ? &*state : nullptr, uo, on_progress, nullptr, &rep);
      const double secs = Since(t0);
      if (bar) bar->Finish();
      if (!next.ok()) {
        if (!absl::IsInternal(next.status())) return Fail(next.status());
        // Divergence (NaN/Inf) is a result, not a crash: record where.
        j["status"] = "diverged";
        j["failed_step"] = t;
        j["error"] = std::string(next.status().message());
        j["psnr_matrix"] = matrix;
        j["step_seconds"] = step_seconds;
        std::printf("bench continual %s: diverged at update %d/%d: %s\n", a.method.c_str(), t + 1, T,
                    std::string(next.status().message()).c_str());
        if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
        return 3;
      }
      state = std::move(*next);
      total += secs;
      step_seconds.push_back(secs);
      max_cache = std::max(max_cache, rep.replay_cache_bytes);
      steps.push_back({{"seconds", secs},
                       {"train_seconds", rep.train_seconds},
                       {"replay_prepare_seconds", rep.replay_prepare_seconds},
                       {"replay_cache_bytes", rep.replay_cache_bytes},
                       {"replay_labels", rep.replay_labels},
                       {"replay_seen_labels", rep.replay_seen_labels},
                       {"replay_depth_labels", rep.replay_depth_labels},
                       {"replay_weight_seconds", rep.replay_weight_seconds},
                       {"replay_confidence_mean", rep.replay_confidence_mean},
                       {"replay_compared_labels", rep.replay_compared_labels},
                       {"replay_confidence_seconds", rep.replay_confidence_seconds},
                       {"replay_view_pixels", rep.replay_view_pixels},
                       {"new_views", rep.new_views},
                       {"replay_views", rep.replay_views},
                       {"buffer_views", rep.buffer_views},
                       {"samples", rep.samples}});
      // Row t of the forgetting matrix: scans 0..t after step t.
      const auto e0 = std::chrono::steady_clock::now();
      absl::StatusOr<Scores> sc = Score(*state->model, seq, t);
      if (!sc.ok()) return Fail(sc.status());
      eval_seconds += Since(e0);
      matrix.push_back(sc->psnr);
      f = *sc;  // The last row is the final score.
      spdlog::info(
          "step {}/{}: {:.1f}s (replay prep {:.1f}s, {} labels of {} past pixels); PSNR on scan {} {:.2f} dB, on scan 0 "
          "{:.2f} dB",
          t + 1, T, secs, rep.replay_prepare_seconds, rep.replay_labels, rep.replay_view_pixels, t, sc->psnr.back(),
          sc->psnr.front());
    }
    final_model = state->model;
    camera_bytes = state->memory.camera_bytes();
    replay_bytes = camera_bytes + state->memory.buffer_bytes();
    bytes_per_camera = state->memory.bytes_per_camera();
  }

  j["psnr"] = f.mean_psnr;
  j["ssim"] = f.mean_ssim;
  j["num_images"] = f.images;
  j["psnr_per_step"] = f.psnr;
  j["psnr_matrix"] = matrix;
  j["step_seconds"] = step_seconds;
  j["total_seconds"] = total;
  j["eval_seconds"] = eval_seconds;
  j["steps"] = steps;
  j["model_bytes"] = final_model->num_bytes();
  j["replay_bytes"] = replay_bytes;
  j["replay_camera_bytes"] = camera_bytes;
  j["replay_bytes_per_camera"] = bytes_per_camera;
  j["replay_cache_peak_bytes"] = max_cache;
  j["peak_rss_bytes"] = PeakRssBytes();
  if (!ub && T > 1) j["first_scan_drop_db"] = matrix[0][0].get<double>() - f.psnr[0];
  // Forgetting (continual methods; ub has only the final row).
  std::string forgetting;
  if (!ub) {
    std::vector<std::vector<double>> r;
    for (const auto& row : matrix) r.push_back(row.get<std::vector<double>>());
    absl::StatusOr<ForgettingSummary> fs = SummarizeForgetting(r);
    if (!fs.ok()) return Fail(fs.status());
    j["final_mean_psnr_over_scans"] = fs->final_mean;
    j["backward_transfer_db"] = fs->backward_transfer;
    j["max_scan_drop_db"] = fs->max_drop;
    double max_step = 0;
    for (const auto& x : step_seconds) max_step = std::max(max_step, x.get<double>());
    const double mean_step = total / std::max(T, 1);
    j["mean_update_seconds"] = mean_step;
    j["max_update_seconds"] = max_step;
    forgetting = absl::StrFormat(" | BWT %+.2f dB | update %.1fs mean, %.1fs max", fs->backward_transfer, mean_step,
                                 max_step);
  }
  // Only the settings that matter for this method.
  std::string setting =
      ub ? absl::StrFormat("all scans at once, %d iterations (%s budget)", ub_iterations, UbBudgetName(a.ub_budget))
         : std::string(InitModeName(uo.init));
  if (!ub && (uo.method == ContinualMethod::kCLNeRF || uo.method == ContinualMethod::kCLNeRFNoER ||
              uo.method == ContinualMethod::kMEIL)) {
    setting += absl::StrCat(", ", ReplayModeName(uo.replay), " replay");
  }
  if (!ub && (uo.method == ContinualMethod::kCLNeRF || uo.method == ContinualMethod::kER)) {
    setting += absl::StrFormat(", K=%d%s", uo.buffer_size, uo.prioritized_buffer ? " prioritized" : "");
  }
  if (!uo.model.network.use_embeddings) setting += ", no-embed";
  std::printf(
      "bench continual %s (%s) on %s: %d steps x %d iters | PSNR %.2f dB, SSIM %.4f over %d "
      "images | scan 0 %.2f dB%s | total %.1fs | model %.2f MB | replay memory %zu B (%.1f B/camera) | peak RSS "
      "%.0f MB\n",
      a.method.c_str(), setting.c_str(), seq.name.c_str(), T, iterations, f.mean_psnr, f.mean_ssim, f.images, f.psnr[0],
      forgetting.c_str(), total, final_model->num_bytes() / 1e6, replay_bytes, bytes_per_camera, PeakRssBytes() / 1e6);
  std::printf("%s\n", j.dump().c_str());
  if (absl::Status s = WriteJson(a.json, j); !s.ok()) return Fail(s);
  return 0;
}

}  // namespace clnerf
