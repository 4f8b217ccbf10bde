// `clnerf bench register`: how well a later visit is placed into a place's
// frame by its model. A capture's training views are split into two visits
// (alternate frames, so both cover the place); visit A trains θ_A (the
// place's model), then visit B is registered against θ_A's renders twice:
// as it is (already in the place's frame: the fit must be the identity) and
// moved into a frame of its own by a similarity (a rotation, a scale and a
// shift, as a separate SfM run gives). Reports, per case, the frames placed
// and the error of every frame's pose against the known one (centre as % of
// the place's extent, rotation in degrees) and the time of each stage, as
// JSON plus one human line per case.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>

#include "absl/strings/str_format.h"
#include "client/commands.h"
#include "client/visit_split.h"
#include "client/core_flags.h"
#include "core/data/dataset.h"
#include "core/data/stopwatch.h"
#include "core/io/checkpoint.h"
#include "core/pose/photometric_similarity.h"
#include "core/pose/place_map.h"
#include "Eigen/Geometry"
#include "nlohmann/json.hpp"

namespace clnerf {

namespace {

// θ_A: loaded from a.model when that file exists, else trained on visit A
// (and saved to a.model when one is named).
absl::StatusOr<NgpModel> PlaceModel(const Scene& visit_a, const BenchRegisterArgs& a) {
  if (!a.model.empty() && std::filesystem::exists(a.model)) {
    absl::StatusOr<LoadedCheckpoint> ck = LoadCheckpoint(a.model);
    if (!ck.ok()) return ck.status();
    std::fprintf(stderr, "bench register: θ_A loaded from %s\n", a.model.c_str());
    return std::move(ck->model);
  }
  absl::StatusOr<FitResult> fit = FitScene(visit_a, a.fit, {});
  if (!fit.ok()) return fit.status();
  if (!a.model.empty()) {
    if (absl::StatusOr<size_t> s = SaveCheckpoint(*fit->model, a.model); !s.ok()) return s.status();
  }
  return std::move(*fit->model);
}

// Per frame: PnP inliers/matches, reprojection RMS and, when the scan is in
// the place's frame (`truth`), the PnP pose's own error against it.
void PrintFrames(const RegistrationReport& r, const Scene* truth, double extent) {
  for (size_t k = 0; k < r.localized.size(); ++k) {
    const FrameLocalization& f = r.localized[k];
    std::printf(" %d/%d%s", f.inliers, f.matches, f.placed ? "*" : "");
    if (truth != nullptr && f.placed && k < r.tried.size()) {
      const Pose& t = truth->train[size_t(r.tried[k])].camera.c2w;
      std::printf("(%.1fpx %.2f%% %.2fdeg)", f.reprojection_px, 100 * (f.c2w.col(3) - t.col(3)).norm() / extent,
                  RotationAngleDegrees(f.c2w.leftCols<3>().cast<double>(), t.leftCols<3>().cast<double>()));
    }
  }
  std::printf("  (PnP inliers/matches per frame; * = placed%s)\n",
              truth != nullptr ? "; RMS px, centre and rotation error of the frame's own PnP pose" : "");
}

}  // namespace

// As the update worker does for a scan it did not pose: once placed (not
// the identity), its similarity refined photometrically against the place's
// renders, and the scan put back as uploaded when the two land within a
// hair of the identity (ApplyRefinedSimilarity). Returns what it did, with
// the poses' error after it.
nlohmann::json RefineLikeTheService(const RegistrationReport& r, const PlaceMap& map, double extent,
                                    const RegistrationOptions& o, const Scene& truth, Scene* scan) {
  if (!r.status.ok() || r.identity || !o.photometric_similarity) return nullptr;
  absl::StatusOr<SimilarityRefinement> s = RefineSimilarityPhotometric(map, *scan, extent, o.similarity_options);
  if (!s.ok()) return {{"status", s.status().ToString()}};
  const bool snapped = s->accepted && ApplyRefinedSimilarity(r, s->correction, o, scan);
  if (snapped) std::printf("  photometric similarity: refined to within a hair of the identity: kept as uploaded\n");
  const PoseErrors e = FrameErrors(scan->train, truth.train, extent);
  std::printf("  photometric similarity: %s (%s), turned %.3f deg, scale %.4f, %d frames, %.1f s | centre error "
              "median %.2f%% max %.2f%% | rotation median %.2f max %.2f deg\n",
              s->accepted ? "taken" : "kept as registered", s->accepted ? "cost fell" : s->why.c_str(),
              s->rotation_deg, s->scale, s->frames, s->seconds, e.centre_median, e.centre_max, e.rotation_median,
              e.rotation_max);
  return {{"accepted", s->accepted}, {"refined_to_identity", snapped}, {"why", s->why},
          {"rotation_deg", s->rotation_deg}, {"scale", s->scale},
          {"cost_before", s->cost_before}, {"cost_after", s->cost_after}, {"frames", s->frames},
          {"seconds", s->seconds}, {"centre_error_pct_median", e.centre_median}, {"centre_error_pct_max", e.centre_max},
          {"rotation_error_deg_median", e.rotation_median}, {"rotation_error_deg_max", e.rotation_max}};
}

CLI::App* BindBenchRegister(CLI::App* parent, BenchRegisterArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "register", "A capture split into two visits: the second registered into the first's model, in the place's "
                  "frame and in its own");
  // θ_A gets the place's first-scan budget, as the server gives it (TrainOptions' default).
  c->add_option("--data", a->data, "Dataset folder, or 'procedural'")->required();
  c->add_option("--iters", a->fit.train.iterations,
                "Training steps of the first visit's model (the server's first-scan budget)")
      ->capture_default_str();
  c->add_option("--rotation", a->rotation_deg, "The second visit's own frame: rotation (degrees)")
      ->capture_default_str();
  c->add_option("--scale", a->scale, "... and scale")->capture_default_str();
  c->add_option("--seed", a->seed, "Seed of its axis and shift")->capture_default_str();
  c->add_option("--references", a->registration.max_references, "Renders of the place")->capture_default_str();
  c->add_option("--max-side", a->registration.localizer.max_side, "Matching size (long side, pixels)")
      ->capture_default_str();
  c->add_option("--min-side", a->registration.localizer.min_side,
                "Smaller photos are scaled up to this long side before matching (1 = never)")
      ->capture_default_str();
  BindDatasetFlags(c, &a->dataset);
  BindThreadsFlag(c, &a->threads);
  c->add_flag("--verbose", a->verbose, "Print each frame's PnP inliers, matches and pose error");
  c->add_option("--model", a->model, "θ_A's checkpoint: loaded if the file exists, else trained and saved there");
  c->add_option("--json", a->json, "Write JSON here ('-' = stdout)");
  return c;
}

int RunBenchRegister(const BenchRegisterArgs& a) {
  SetThreads(a.threads);
  absl::StatusOr<Scene> all = LoadVisitScene(a.data, a.dataset);
  if (!all.ok()) return Fail(all.status());
  Scene visit_a, visit_b;
  SplitVisits(*all, &visit_a, &visit_b);
  std::fprintf(stderr, "bench register: %s, visit A %zu frames (trains θ_A, %d iterations), visit B %zu frames\n",
               a.data.c_str(), visit_a.train.size(), a.fit.train.iterations, visit_b.train.size());
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<NgpModel> model = PlaceModel(visit_a, a);
  if (!model.ok()) return Fail(model.status());
  const double train_seconds = SecondsSince(t0);
  std::vector<Camera> place;
  for (const View& v : visit_a.train) place.push_back(v.camera);
  const double extent = PlaceExtent(place, model->normalization());
  RenderOptions ro;
  ModelPlaceMap map(*model, ro);

  nlohmann::json out = {{"data", a.data}, {"frames_a", visit_a.train.size()}, {"frames_b", visit_b.train.size()},
                        {"train_a_seconds", train_seconds}, {"place_extent", extent}, {"cases", nlohmann::json::array()}};
  for (const char* which : {"place", "own"}) {
    Scene scan = visit_b;
    const bool own = std::string(which) == "own";
    if (own) ApplySimilarity(OwnFrame(a.rotation_deg, a.scale, a.seed, extent), &scan);
    RegistrationReport r = RegisterScan(scan, map, place, extent, a.registration);
    if (r.status.ok()) ApplySimilarity(r.transform, &scan);
    const PoseErrors e = FrameErrors(scan.train, visit_b.train, extent);
    const double seconds = r.render_seconds + r.localize_seconds + r.fit_seconds;
    std::printf("register %s, visit B in %s frame: %s, %d/%d frames localised, %d agree%s | centre error median %.2f%% "
                "max %.2f%% of the place | rotation median %.2f max %.2f deg | %.1f s (render %.1f, match %.1f)\n",
                a.data.c_str(), own ? "its own" : "the place's", r.status.ok() ? "placed" : "REFUSED",
                r.frames_localized, r.frames, r.frames_agreeing, r.identity ? " (identity)" : "", e.centre_median,
                e.centre_max, e.rotation_median, e.rotation_max, seconds, r.render_seconds, r.localize_seconds);
    if (!r.status.ok()) std::printf("  why: %s\n", std::string(r.status.message()).c_str());
    nlohmann::json refined = RefineLikeTheService(r, map, extent, a.registration, visit_b, &scan);
    out["cases"].push_back({{"frame", which}, {"placed", r.status.ok()}, {"status", r.status.ToString()},
                            {"identity", r.identity}, {"identity_likelihood_ratio", r.identity_likelihood_ratio},
                            {"frames", r.frames}, {"frames_localized", r.frames_localized},
                            {"frames_agreeing", r.frames_agreeing}, {"references", r.references},
                            {"centre_error_pct_median", e.centre_median}, {"centre_error_pct_max", e.centre_max},
                            {"rotation_error_deg_median", e.rotation_median}, {"rotation_error_deg_max", e.rotation_max},
                            {"render_seconds", r.render_seconds}, {"localize_seconds", r.localize_seconds},
                            {"fit_seconds", r.fit_seconds}, {"seconds", seconds}, {"refined", refined}});
    if (a.verbose) PrintFrames(r, own ? nullptr : &visit_b, extent);
  }
  if (!a.json.empty()) {
    if (absl::Status s = WriteJson(a.json, out); !s.ok()) return Fail(s);
  }
  return 0;
}

}  // namespace clnerf
