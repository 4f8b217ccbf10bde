#include "core/pose/registration.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <set>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/data/stopwatch.h"

namespace clnerf {

namespace {

bool Cancelled(const std::atomic<bool>* cancel) { return cancel != nullptr && cancel->load(); }

// Step 2: where each of the chosen frames is in the place's frame.
std::vector<FrameLocalization> LocalizeFrames(const FeatureLocalizer& loc, const std::vector<const View*>& frames,
                                              const RegistrationProgressFn& progress,
                                              const std::atomic<bool>* cancel) {
  std::vector<FrameLocalization> out(frames.size());
  std::atomic<int> done{0};
#pragma omp parallel for schedule(dynamic, 1)
  for (int i = 0; i < int(frames.size()); ++i) {
    if (Cancelled(cancel)) continue;
    out[i] = loc.Localize(frames[i]->image, frames[i]->camera);
    const int d = ++done;
    if (progress) {
#pragma omp critical(registration_progress)
      progress(d, int(frames.size()));
    }
  }
  return out;
}

// Step 4: the checks a fit must pass; sets report->status.
void Accept(const RobustSimilarity& fit, const std::vector<PosePair>& pairs, const std::vector<Camera>& place,
            const RegistrationOptions& o, RegistrationReport* r) {
  r->frames_agreeing = int(fit.inliers.size());
  r->median_centre_residual = fit.median_centre_error / r->place_extent;
  r->median_rotation_residual_deg = fit.median_rotation_error_deg;
  const int need = std::max({o.min_frames, int(std::ceil(o.min_frame_fraction * r->frames_localized)),
                             int(std::ceil(o.min_tried_fraction * r->frames))});
  if (r->frames_agreeing < need) {
    r->status = absl::FailedPreconditionError(
        absl::StrCat("only ", r->frames_agreeing, " frames agree on where the scan is (", need, " needed)"));
    return;
  }
  if (r->median_centre_residual > o.max_centre_residual ||
      r->median_rotation_residual_deg > o.max_rotation_residual_deg) {
    r->status = absl::FailedPreconditionError("the frames disagree too much about where the scan is");
    return;
  }
  Eigen::Vector3d mid = Eigen::Vector3d::Zero();
  for (const Camera& c : place) mid += c.position().cast<double>();
  mid /= double(std::max<size_t>(1, place.size()));
  for (const PosePair& p : pairs) {
    const Eigen::Vector3d c = fit.transform.Apply(Eigen::Vector3d(p.from.col(3).cast<double>()));
    if ((c - mid).norm() > o.max_distance * r->place_extent) {
      r->status = absl::FailedPreconditionError("implausible scale: the placed scan reaches far outside the place");
      return;
    }
  }
  // Snap a fit within a hair of the identity.
  std::vector<Eigen::Vector3d> centres;
  for (const PosePair& p : pairs) centres.push_back(p.from.col(3).cast<double>());
  auto within = [&](double k) { return WithinIdentityHair(fit.transform, centres, r->place_extent, o, k); };
  r->identity_likelihood_ratio = IdentityLikelihoodRatio(fit, pairs);
  r->identity = within(1.0) || (within(o.identity_noise_limit) &&
                                r->identity_likelihood_ratio <= o.identity_chi_square);
  r->transform = r->identity ? Similarity() : fit.transform;
  r->status = absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::vector<MapView>> RenderPlaceReferences(const PlaceMap& map, const std::vector<Camera>& cameras,
                                                           const RegistrationOptions& o,
                                                           const std::atomic<bool>* cancel) {
  std::vector<MapView> out;
  for (int i : SpreadCameras(cameras, o.max_references)) {
    if (Cancelled(cancel)) return absl::CancelledError("registration cancelled");
    absl::StatusOr<MapView> v = map.Render(CameraWithSideIn(cameras[i], o.localizer.min_side, o.localizer.max_side));
    if (!v.ok()) return v.status();
    out.push_back(*std::move(v));
  }
  return out;
}

absl::Status RegistrationOptions::Validate() const {
  if (absl::Status s = localizer.Validate(); !s.ok()) return s;
  if (absl::Status s = fit.Validate(); !s.ok()) return s;
  if (absl::Status s = photometric_options.Validate(); !s.ok()) return s;
  if (absl::Status s = arbitration.Validate(); !s.ok()) return s;
  if (absl::Status s = similarity_options.Validate(); !s.ok()) return s;
  if (max_references < 1) return absl::InvalidArgumentError("max_references must be >= 1");
  if (max_frames < 2) return absl::InvalidArgumentError("max_frames must be >= 2");
  if (min_frames < 2) return absl::InvalidArgumentError("min_frames must be >= 2");
  if (!(min_frame_fraction >= 0 && min_frame_fraction <= 1) || !(min_tried_fraction >= 0 && min_tried_fraction <= 1)) {
    return absl::InvalidArgumentError("min_frame_fraction and min_tried_fraction must be in [0, 1]");
  }
  if (!(max_centre_residual > 0) || !(max_rotation_residual_deg > 0) || !(max_distance > 0)) {
    return absl::InvalidArgumentError("registration residual limits must be > 0");
  }
  if (!(identity_chi_square >= 0) || !(identity_noise_limit >= 1)) {
    return absl::InvalidArgumentError("identity_chi_square must be >= 0 and identity_noise_limit >= 1");
  }
  if (identity_scale < 0 || identity_rotation_deg < 0 || identity_centre < 0) {
    return absl::InvalidArgumentError("identity tolerances must be >= 0");
  }
  if (!(camera.max_turn_deg > 0) || !(camera.min_rms_gain < 1) || !(camera.max_focal_change >= 0) ||
      !(camera.max_k1_change >= 0)) {
    return absl::InvalidArgumentError(
        "registration camera: max_turn_deg must be > 0, min_rms_gain < 1, max_focal_change and max_k1_change >= 0");
  }
  return absl::OkStatus();
}

std::string RegistrationReport::Summary() const {
  std::string s = absl::StrFormat(
      "%d of %d frames localised against %d renders, %d agree; residual %.2f%% of the place, %.2f deg",
      frames_localized, frames, references, frames_agreeing, 100 * median_centre_residual,
      median_rotation_residual_deg);
  if (status.ok()) {
    absl::StrAppend(&s, identity ? "; already in the place's frame"
                                 : absl::StrFormat("; moved by scale %.4f, rotation %.2f deg", transform.scale,
                                                   transform.RotationDegrees()));
  }
  return s;
}

void RegistrationReport::DropFrames(const std::vector<int>& frames) {
  const std::set<int> gone(frames.begin(), frames.end());
  std::vector<FrameLocalization> kept_localized;
  std::vector<int> kept_tried;
  for (size_t k = 0; k < tried.size() && k < localized.size(); ++k) {
    if (gone.count(tried[k])) continue;
    // Frames before it that are gone shift it down.
    const int shift = int(std::distance(gone.begin(), gone.lower_bound(tried[k])));
    kept_tried.push_back(tried[k] - shift);
    kept_localized.push_back(localized[k]);
  }
  tried = std::move(kept_tried);
  localized = std::move(kept_localized);
}

absl::StatusOr<ArbitrationReport> ArbitrateRegisteredScan(const PlaceMap& map, double extent,
                                                          const ArbitrationOptions& options,
                                                          const std::set<std::string>& suspect,
                                                          RegistrationReport* report, Scene* scene,
                                                          std::set<std::string>* drop) {
  std::vector<int> distrusted;
  for (size_t i = 0; i < scene->train.size(); ++i) {
    if (suspect.count(scene->train[i].name)) distrusted.push_back(int(i));
  }
  absl::StatusOr<ArbitrationReport> a =
      ArbitrateDisputedFrames(report->localized, report->tried, map, extent, scene, options, distrusted);
  drop->clear();
  for (int i : a.ok() ? a->dropped : distrusted) drop->insert(scene->train[size_t(i)].name);
  report->DropFrames(a.ok() ? a->dropped : distrusted);
  return a;
}

void RegistrationReport::AddMetrics(std::map<std::string, double>* m) const {
  (*m)["registration_frames"] = frames;
  (*m)["registration_frames_localized"] = frames_localized;
  (*m)["registration_frames_agreeing"] = frames_agreeing;
  (*m)["registration_pnp_inliers"] = double(pnp_inliers);
  (*m)["registration_identity"] = identity ? 1 : 0;
  (*m)["registration_scale"] = transform.scale;
  (*m)["registration_rotation_deg"] = transform.RotationDegrees();
  (*m)["registration_translation"] = transform.translation.norm();
  (*m)["registration_centre_residual"] = median_centre_residual;
  (*m)["registration_rotation_residual_deg"] = median_rotation_residual_deg;
  (*m)["registration_seconds"] = render_seconds + localize_seconds + fit_seconds;
}

RegistrationReport RegisterScan(const Scene& scan, const PlaceMap& map, const std::vector<Camera>& place_cameras,
                                double place_extent, const RegistrationOptions& options,
                                const RegistrationProgressFn& progress, const std::atomic<bool>* cancel) {
  RegistrationReport r;
  r.place_extent = place_extent;
  if (absl::Status s = options.Validate(); !s.ok()) return r.status = s, r;
  if (!(place_extent > 0) || place_cameras.empty()) {
    r.status = absl::FailedPreconditionError("the place has no cameras to register against");
    return r;
  }
  auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<std::vector<MapView>> renders = RenderPlaceReferences(map, place_cameras, options, cancel);
  if (!renders.ok()) return r.status = renders.status(), r;
  r.references = int(renders->size());
  absl::StatusOr<std::unique_ptr<FeatureLocalizer>> loc = FeatureLocalizer::Build(*renders, options.localizer);
  if (!loc.ok()) return r.status = loc.status(), r;
  r.map_points = (*loc)->num_points();
  r.render_seconds = SecondsSince(t0);

  t0 = std::chrono::steady_clock::now();
  std::vector<Camera> scan_cams;
  for (const View& v : scan.train) scan_cams.push_back(v.camera);
  std::vector<const View*> frames;
  for (int i : SpreadCameras(scan_cams, options.max_frames)) {
    if (scan.train[i].image.empty()) continue;
    frames.push_back(&scan.train[i]);
    r.tried.push_back(i);
  }
  r.frames = int(frames.size());
  std::vector<FrameLocalization> found = LocalizeFrames(**loc, frames, progress, cancel);
  if (Cancelled(cancel)) return r.status = absl::CancelledError("registration cancelled"), r;
  r.localize_seconds = SecondsSince(t0);
  r.localized = found;

  t0 = std::chrono::steady_clock::now();
  std::vector<PosePair> pairs;
  std::vector<int> pnp;
  for (size_t i = 0; i < found.size(); ++i) {
    if (!found[i].placed) continue;
    pairs.push_back({frames[i]->camera.c2w, found[i].c2w});
    pnp.push_back(found[i].inliers);
  }
  r.frames_localized = int(pairs.size());
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, place_extent, options.fit);
  r.fit_seconds = SecondsSince(t0);
  if (!fit.ok()) {
    r.status = absl::FailedPreconditionError(
        absl::StrCat("the scan does not match the place: ", fit.status().message()));
  } else {
    for (int i : fit->inliers) r.pnp_inliers += pnp[i];
    Accept(*fit, pairs, place_cameras, options, &r);
  }
  if (!r.status.ok()) r.status = absl::Status(r.status.code(), absl::StrCat(r.status.message(), " (", r.Summary(), ")"));
  return r;
}

absl::Status RefineAgainstPlace(const RegistrationReport& report, Scene* scene, SharedCameraReport* camera,
                                Intrinsics* refined, const SharedCameraOptions& options) {
  if (scene->train.empty()) return absl::InvalidArgumentError("the scan has no frames");
  std::vector<Pose> poses(report.localized.size(), Pose::Zero());
  for (size_t k = 0; k < report.tried.size() && k < poses.size(); ++k) {
    poses[k] = scene->train[size_t(report.tried[k])].camera.c2w;
  }
  absl::StatusOr<Intrinsics> in = RefineSharedCamera(report.localized, scene->train[0].camera.intrinsics, &poses,
                                                     camera, options);
  if (!in.ok()) return in.status();
  for (std::vector<View>* views : {&scene->train, &scene->val, &scene->test}) {
    for (View& v : *views) v.camera.intrinsics = in->Scaled(v.camera.intrinsics.width, v.camera.intrinsics.height);
  }
  for (size_t k = 0; k < report.tried.size() && k < poses.size(); ++k) {
    if (report.localized[k].placed && poses[k].allFinite()) {
      scene->train[size_t(report.tried[k])].camera.c2w = poses[k];
    }
  }
  if (refined != nullptr) *refined = *in;
  return absl::OkStatus();
}

void ApplySimilarity(const Similarity& s, Scene* scene) {
  for (std::vector<View>* split : {&scene->train, &scene->val, &scene->test}) {
    for (View& v : *split) {
      v.camera.c2w = s.ApplyToPose(v.camera.c2w);
      for (DepthPoint& d : v.depth) d.world = s.Apply(d.world);
    }
  }
  for (Eigen::Vector3f& p : scene->sparse_points) p = s.Apply(p);
  for (Eigen::Vector3f& p : scene->content_points) p = s.Apply(p);
}

bool WithinIdentityHair(const Similarity& t, const std::vector<Eigen::Vector3d>& centres, double place_extent,
                        const RegistrationOptions& o, double k) {
  double moved = 0;
  for (const Eigen::Vector3d& c : centres) moved = std::max(moved, (t.Apply(c) - c).norm());
  return std::abs(t.scale - 1) <= k * o.identity_scale && t.RotationDegrees() <= k * o.identity_rotation_deg &&
         moved <= k * o.identity_centre * place_extent;
}

bool RefinedToIdentity(const RegistrationReport& report, const Similarity& correction,
                       const std::vector<Eigen::Vector3d>& uploaded, const RegistrationOptions& o) {
  return !report.identity &&
         WithinIdentityHair(correction.Compose(report.transform), uploaded, report.place_extent, o);
}

bool ApplyRefinedSimilarity(const RegistrationReport& report, const Similarity& correction,
                            const RegistrationOptions& o, Scene* scene) {
  const Similarity back = report.transform.Inverse();
  std::vector<Eigen::Vector3d> uploaded;
  for (const View& v : scene->train) {
    uploaded.push_back(back.Apply(Eigen::Vector3d(v.camera.position().cast<double>())));
  }
  const bool identity = RefinedToIdentity(report, correction, uploaded, o);
  ApplySimilarity(identity ? back : correction, scene);
  return identity;
}

}  // namespace clnerf
