// `clnerf bench rescan`: a capture split into two visits, the second
// uploaded as people bring it, run through what the update worker does
// (posing, registration, CLNeRF's update) in-process, and scored on the
// capture's held-out views. Cases (--cases):
//   place           visit B in the place's frame (registration must snap to
//                   the identity);
//   own             visit B moved into a frame of its own (a similarity),
//                   registered and its similarity refined photometrically
//                   ("own-nophoto" skips that refinement, "own-frames" then
//                   also aligns each frame on its own, as for a scan the
//                   service posed);
//   unposed         visit B's photos only, posed by COLMAP started from the
//                   place's camera, registered, its camera and poses refined
//                   against the place (as the service does;
//                   "unposed-unseeded" starts COLMAP from its own guess,
//                   "unposed-unrefined" also skips the refinement,
//                   "unposed-nophoto" skips only the photometric alignment);
//   unposed-first   visit A's photos only, posed by COLMAP, as the place's
//                   first scan, against visit A posed (scored at matched
//                   poses: the held-out views posed in the same COLMAP run,
//                   as the service poses an upload's test frames, and visit
//                   A posed scored on the same views), repeated over
//                   --first-seeds training seeds, each against visit A
//                   posed and trained with the same seed (means reported).
// Per case: registration error against the known poses, seconds per stage
// (posing, registering, training), held-out PSNR at the latest time and at
// visit A's. JSON plus one human line per case.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <set>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "client/commands.h"
#include "client/core_flags.h"
#include "client/verb_set.h"
#include "client/visit_split.h"
#include "core/data/image.h"
#include "core/data/stopwatch.h"
#include "core/io/checkpoint.h"
#include "core/io/durable_file.h"
#include "core/train/optimizer_state.h"
#include "core/pose/photometric_refine.h"
#include "core/pose/photometric_similarity.h"
#include "core/pose/pose_arbitration.h"
#include "core/pose/place_map.h"
#include "core/pose/registration.h"
#include "core/pose/sfm.h"
#include "nlohmann/json.hpp"

namespace clnerf {

namespace {

// COLMAP's answer for `photos`, or read back from `cache` (a JSON file
// written here after a run when absent): COLMAP is not deterministic, so
// comparing what registration does with one answer needs it kept.
absl::StatusOr<SfmResult> RunOrLoadSfm(const std::vector<std::string>& photos, const SfmOptions& o,
                                       const std::string& cache) {
  if (!cache.empty() && std::filesystem::exists(cache)) {
    absl::StatusOr<std::string> text = ReadFileToString(cache, "posing cache");
    if (!text.ok()) return text.status();
    const nlohmann::json j = nlohmann::json::parse(*text, nullptr, false);
    if (j.is_discarded() || j.value("photos", size_t(0)) != photos.size()) {
      return absl::FailedPreconditionError(absl::StrCat("--posing-cache ", cache, " is not for these ",
                                                        photos.size(), " photos"));
    }
    SfmResult r;
    for (const nlohmann::json& c : j["cameras"]) {
      if (c.is_null()) {
        r.cameras.emplace_back();
        continue;
      }
      Camera cam;
      const std::vector<float> in = c["in"].get<std::vector<float>>(), m = c["c2w"].get<std::vector<float>>();
      cam.intrinsics = {int(in[0]), int(in[1]), in[2], in[3], in[4], in[5], in[6], in[7], in[8], in[9]};
      for (int k = 0; k < 12; ++k) cam.c2w(k / 4, k % 4) = m[size_t(k)];
      r.cameras.push_back(cam);
    }
    for (const auto& p : j["points"]) r.points.emplace_back(p[0].get<float>(), p[1].get<float>(), p[2].get<float>());
    r.registered = j["registered"].get<int>();
    r.mean_reprojection_px = j["reprojection_px"].get<double>();
    std::fprintf(stderr, "bench rescan: COLMAP's poses read from %s\n", cache.c_str());
    return r;
  }
  absl::StatusOr<SfmResult> r = ColmapSfm().Run(photos, o);
  if (!r.ok() || cache.empty()) return r;
  nlohmann::json j = {{"photos", photos.size()}, {"registered", r->registered},
                      {"reprojection_px", r->mean_reprojection_px}, {"cameras", nlohmann::json::array()},
                      {"points", nlohmann::json::array()}};
  for (const std::optional<Camera>& c : r->cameras) {
    if (!c) {
      j["cameras"].push_back(nullptr);
      continue;
    }
    const Intrinsics& in = c->intrinsics;
    std::vector<float> m;
    for (int k = 0; k < 12; ++k) m.push_back(c->c2w(k / 4, k % 4));
    j["cameras"].push_back({{"in", {float(in.width), float(in.height), in.fx, in.fy, in.cx, in.cy, in.k1, in.k2,
                                    in.p1, in.p2}},
                            {"c2w", m}});
  }
  for (const Eigen::Vector3f& p : r->points) j["points"].push_back({p.x(), p.y(), p.z()});
  if (absl::Status s = WriteJson(cache, j); !s.ok()) return s;
  return r;
}

// Visit `scan` posed by COLMAP: the frames it posed keep their images and
// get its cameras (time step kept); `posed` lists their indices in `scan`.
// `held_out` (optional) is posed in the same run, as the service poses an
// upload's test frames with its training frames: those COLMAP posed are
// kept, with its cameras, the others dropped.
absl::StatusOr<SfmResult> PoseWithColmap(Scene* scan, std::vector<int>* posed, int threads,
                                         std::vector<View>* held_out = nullptr,
                                         std::optional<Intrinsics> initial_camera = std::nullopt,
                                         const std::string& cache = "") {
  char tmpl[] = "/tmp/clnerf-bench-rescan-XXXXXX";
  if (mkdtemp(tmpl) == nullptr) return absl::InternalError("cannot create a scratch folder");
  const std::string dir = tmpl;
  std::vector<std::string> photos;
  std::vector<const View*> views;
  for (const View& v : scan->train) views.push_back(&v);
  if (held_out != nullptr) {
    for (const View& v : *held_out) views.push_back(&v);
  }
  for (size_t i = 0; i < views.size(); ++i) {
    photos.push_back(absl::StrFormat("%s/%04d.png", dir, i));
    if (absl::Status s = WriteImage(photos.back(), views[i]->image); !s.ok()) return s;
  }
  SfmOptions o;
  o.workspace = dir + "/colmap";
  o.threads = threads > 0 ? threads : 2;
  if (initial_camera && !scan->train.empty()) {
    const Intrinsics& in = scan->train[0].camera.intrinsics;
    o.initial_camera = initial_camera->Scaled(in.width, in.height);
  }
  absl::StatusOr<SfmResult> r = RunOrLoadSfm(photos, o, cache);
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
  if (!r.ok()) return r.status();
  std::vector<View> kept;
  for (size_t i = 0; i < scan->train.size(); ++i) {
    if (!r->cameras[i]) continue;
    View v = scan->train[i];
    const int t = v.camera.time_step;
    v.camera = *r->cameras[i];
    v.camera.time_step = t;
    v.depth.clear();
    kept.push_back(std::move(v));
    posed->push_back(int(i));
  }
  if (held_out != nullptr) {
    std::vector<View> test;
    for (size_t k = 0; k < held_out->size(); ++k) {
      const std::optional<Camera>& c = r->cameras[scan->train.size() + k];
      if (!c) continue;
      View v = (*held_out)[k];
      v.camera = *c;
      test.push_back(std::move(v));
    }
    *held_out = std::move(test);
  }
  scan->train = std::move(kept);
  scan->sparse_points = r->points;
  scan->content_points.clear();
  return r;
}

EvalResult HeldOutScores(const NgpModel& model, std::vector<View> test, int time_step, int max_views,
                         const std::string& save_dir = "") {
  for (View& v : test) v.camera.time_step = time_step;
  EvalOptions eo;
  eo.max_views = max_views;
  eo.save_dir = save_dir;
  absl::StatusOr<EvalResult> r = EvaluateViews(model, test, eo);
  return r.ok() ? *r : EvalResult{};
}

double HeldOutPsnr(const NgpModel& model, std::vector<View> test, int time_step, int max_views) {
  return HeldOutScores(model, std::move(test), time_step, max_views).psnr;
}

struct CaseRow {
  nlohmann::json json;
  std::string line;
};

// As the update worker does for a scan it posed: the shared camera and the
// poses refined against the place's points, then each frame aligned
// photometrically to the place's renders ("unposed-nophoto" skips that).
void RefineLikeTheService(const NgpModel& model, const RegistrationReport& r, double extent, const std::string& which,
                          const std::vector<View>& truth, const SharedCameraOptions& camera, Scene* scan,
                          nlohmann::json* row) {
  SharedCameraReport cam;
  Intrinsics in;
  const PoseErrors before = FrameErrors(scan->train, truth, extent);
  absl::Status rs = RefineAgainstPlace(r, scan, &cam, &in, camera);
  if (!rs.ok()) {
    std::printf("  %s: refinement failed: %s\n", which.c_str(), std::string(rs.message()).c_str());
    return;
  }
  const PoseErrors re = FrameErrors(scan->train, truth, extent);
  for (size_t q = 0; q < cam.frames.size(); ++q) {
    const size_t i = size_t(r.tried[size_t(cam.frames[q])]);
    std::printf("    refine frame %zu: rms %.2f -> %.2f px (%.2f), rotation error %.2f -> %.2f deg\n", i,
                cam.frame_rms[q].first, cam.frame_rms[q].second, cam.frame_rms[q].second / cam.frame_rms[q].first,
                before.rotation[i], re.rotation[i]);
  }
  (*row)["refined_fx"] = in.fx;
  (*row)["refined_k1"] = in.k1;
  (*row)["refine_rms_px"] = cam.rms_px;
  (*row)["refine_rms_guess_px"] = cam.rms_guess_px;
  (*row)["refine_rms_refined_px"] = cam.rms_refined_px;
  (*row)["camera_refined"] = cam.camera_taken;
  (*row)["refined_centre_error_pct_median"] = re.centre_median;
  (*row)["refined_rotation_error_deg_median"] = re.rotation_median;
  std::printf("  %s: camera %s: fx %.2f k1 %.4f (rms %.2f px at the start, %.2f refined); poses %.2f%% / %.2f deg "
              "from the known\n",
              which.c_str(), cam.camera_taken ? "refined" : "kept", in.fx, in.k1, cam.rms_guess_px,
              cam.rms_refined_px, re.centre_median, re.rotation_median);
  if (which == "unposed-nophoto") return;
  absl::StatusOr<ScanPhotometricReport> pr =
      RefineScanPhotometric(ModelPlaceMap(model, RenderOptions()), scan, extent, PhotometricRefineOptions());
  if (!pr.ok()) {
    std::printf("  %s: photometric refinement failed: %s\n", which.c_str(), std::string(pr.status().message()).c_str());
    return;
  }
  const PoseErrors pe = FrameErrors(scan->train, truth, extent);
  (*row)["photometric_seconds"] = pr->seconds;
  (*row)["photometric_accepted"] = pr->accepted;
  (*row)["photometric_centre_error_pct_median"] = pe.centre_median;
  (*row)["photometric_rotation_error_deg_median"] = pe.rotation_median;
  std::printf("  %s: aligned to the place's renders, %d of %d frames moved (median %.3f deg) in %.1f s; poses "
              "%.2f%% / %.2f deg from the known\n",
              which.c_str(), pr->accepted, pr->frames, pr->median_rotation_deg, pr->seconds, pe.centre_median,
              pe.rotation_median);
  if (const std::string off = pe.Outliers(); !off.empty()) {
    std::printf("  %s: frames far off after the alignment: %s\n", which.c_str(), off.c_str());
  }
  for (size_t i = 0; i < pr->why.size(); ++i) {
    if (!pr->why[i].empty()) std::printf("    frame %zu kept: %s\n", i, pr->why[i].c_str());
  }
}

// As the update worker does for a scan it did not pose, once placed off
// the identity by `r`: its whole similarity refined photometrically against
// the place's renders, and the scan put back as uploaded when the two land
// within a hair of the identity (ApplyRefinedSimilarity).
void RefineSimilarityLikeTheService(const NgpModel& model, const RegistrationReport& r, double extent,
                                    const RegistrationOptions& o, const std::vector<View>& truth, Scene* scan,
                                    nlohmann::json* row) {
  absl::StatusOr<SimilarityRefinement> s =
      RefineSimilarityPhotometric(ModelPlaceMap(model, RenderOptions()), *scan, extent, o.similarity_options);
  if (!s.ok()) {
    std::printf("  photometric similarity failed: %s\n", std::string(s.status().message()).c_str());
    return;
  }
  const bool snapped = s->accepted && ApplyRefinedSimilarity(r, s->correction, o, scan);
  (*row)["similarity_refined_to_identity"] = snapped;
  const PoseErrors e = FrameErrors(scan->train, truth, extent);
  (*row)["similarity_refined"] = s->accepted;
  (*row)["similarity_refine_why"] = s->why;
  (*row)["similarity_refine_deg"] = s->rotation_deg;
  (*row)["similarity_refine_seconds"] = s->seconds;
  (*row)["similarity_refined_centre_error_pct_median"] = e.centre_median;
  (*row)["similarity_refined_rotation_error_deg_median"] = e.rotation_median;
  std::printf("  similarity %s photometrically (turned %.3f deg, %d frames, %.1f s%s%s); poses %.2f%% / %.2f deg "
              "from the known\n",
              snapped ? "refined to the identity" : s->accepted ? "refined" : "kept", s->rotation_deg, s->frames,
              s->seconds, s->accepted ? "" : ": ", s->why.c_str(), e.centre_median, e.rotation_median);
}

// What every case shares: the two visits, the held-out views of each time,
// and visit A's model (the place).
struct RescanContext {
  const BenchRescanArgs* args = nullptr;
  Scene visit_a, visit_b;
  std::vector<View> test, test_b;  // Held out at visit A's time, at B's.
  const ContinualState* place_state = nullptr;
  std::vector<Camera> place;  // Visit A's cameras.
  double extent = 0, psnr_a = 0;
  UpdateOptions first;  // A first scan's training.
};

// One case's scan, as it goes through the stages.
struct CaseScan {
  Scene scan;
  std::vector<View> truth;        // The scan's known training views.
  std::vector<int> posed;         // Indices into `truth` of the views kept.
  std::vector<View> posed_truth;  // truth[posed[k]].
  std::vector<View> scored;       // Held-out views scored at visit A's time.
  // Frames the pose check disputed, left for the map to vouch for (as the
  // service does for a later scan it posed) instead of dropped at once.
  std::set<std::string> suspect;
  double posing_seconds = 0, register_seconds = 0, baseline = 0;
};

// COLMAP posing for the unposed cases; false (row filled) when it failed.
bool PoseCase(const RescanContext& c, const std::string& which, CaseScan* cs, nlohmann::json* row) {
  const bool first_scan = which == "unposed-first";
  // A later visit's COLMAP run starts from the place's camera, as the
  // service's does ("unposed-unseeded": from COLMAP's own guess).
  const std::optional<Intrinsics> seed = which == "unposed" || which == "unposed-nophoto"
                                             ? std::optional<Intrinsics>(c.place.back().intrinsics)
                                             : std::nullopt;
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<SfmResult> sfm =
      PoseWithColmap(&cs->scan, &cs->posed, c.args->threads, first_scan ? &cs->scored : nullptr, seed,
                     first_scan ? "" : c.args->posing_cache);
  cs->posing_seconds = SecondsSince(t0);
  (*row)["posing_seconds"] = cs->posing_seconds;
  if (!sfm.ok()) {
    (*row)["status"] = sfm.status().ToString();
    std::printf("rescan %s, %s: COLMAP could not pose it: %s\n", c.args->data.c_str(), which.c_str(),
                std::string(sfm.status().message()).c_str());
    return false;
  }
  const Intrinsics got = cs->scan.train.empty() ? Intrinsics() : cs->scan.train[0].camera.intrinsics;
  const Intrinsics& known = cs->truth[0].camera.intrinsics;
  (*row)["posed"] = sfm->registered;
  (*row)["colmap_fx"] = got.fx;
  (*row)["known_fx"] = known.fx;
  (*row)["reprojection_px"] = sfm->mean_reprojection_px;
  std::printf("  %s: COLMAP's focal %.2f px, k1 %.4f (known: %.2f px, k1 %.4f)\n", which.c_str(), got.fx, got.k1,
              known.fx, known.k1);
  return true;
}

// Removes the training frames named in `names` from `cs` (with their
// entries in `posed` and `posed_truth`); returns how many.
size_t DropCaseFrames(const std::set<std::string>& names, CaseScan* cs) {
  std::vector<View> kept, kept_truth;
  std::vector<int> posed;
  for (size_t k = 0; k < cs->scan.train.size(); ++k) {
    if (names.count(cs->scan.train[k].name)) continue;
    kept.push_back(std::move(cs->scan.train[k]));
    posed.push_back(cs->posed[k]);
    if (k < cs->posed_truth.size()) kept_truth.push_back(std::move(cs->posed_truth[k]));
  }
  const size_t dropped = cs->scan.train.size() - kept.size();
  cs->scan.train = std::move(kept);
  cs->posed = std::move(posed);
  if (!cs->posed_truth.empty()) cs->posed_truth = std::move(kept_truth);
  return dropped;
}

// Whether a case is a later visit COLMAP posed that is refined as the
// service refines a scan it posed ("unposed-unrefined": not, to compare).
bool RefinedLikeTheService(const std::string& which) {
  return which == "unposed" || which == "unposed-unseeded" || which == "unposed-nophoto";
}

// Whether a case leaves its disputed frames to arbitration after
// registration, as the service does for a scan it posed.
bool ArbitratesSuspects(const BenchRescanArgs& a, const std::string& which) {
  return a.registration.arbitrate && RefinedLikeTheService(which);
}

// The update worker's pose check (core/pose/pose_check.h) on the scan as
// posed, before registration: its disputed frames are reported and, with
// --pose-check drop (auto: for a scan COLMAP posed), left out (with their
// entries in `posed`).
void CheckCasePoses(const RescanContext& c, const std::string& which, CaseScan* cs, nlohmann::json* row) {
  const BenchRescanArgs& a = *c.args;
  const bool drop = DropsDisputed(a.pose_check, /*posed_here=*/absl::StartsWith(which, "unposed"));
  if (a.pose_check == "off" || cs->scan.train.empty()) return;
  Scene photos;  // The scan's own frames only (a first scan's held-out views are in another frame).
  photos.train = cs->scan.train;
  const std::vector<View> views = CaptureInOrder(photos);
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, a.check, a.threads);
  if (!r.ok()) {
    std::printf("  %s: pose check skipped: %s\n", which.c_str(), std::string(r.status().message()).c_str());
    return;
  }
  (*row)["pose_check_pairs"] = r->pairs.size();
  (*row)["pose_check_disputed"] = r->disputed.size();
  (*row)["pose_check_seconds"] = r->seconds;
  std::printf("  %s: pose check: %s\n", which.c_str(), r->Summary(views).c_str());
  if (!drop || r->disputed.empty()) return;
  const std::set<std::string> disputed = DisputedNames(*r, views);
  if (ArbitratesSuspects(*c.args, which)) {  // Registration decides: ArbitrateLikeTheService.
    cs->suspect = disputed;
    return;
  }
  (*row)["pose_check_dropped"] = DropCaseFrames(disputed, cs);
}

// `held` (the views to score) aligned to `model` from where they are; the
// extent is that of `frame`'s cameras (the frame the model was trained in).
// nullopt when the alignment failed.
std::optional<double> AlignedHeldOutPsnr(const RescanContext& c, const NgpModel& model, const Scene& frame,
                                         const std::vector<View>& views, int* moved) {
  Scene held = frame;
  held.train = views;
  std::vector<Camera> own;
  for (const View& v : frame.train) own.push_back(v.camera);
  absl::StatusOr<ScanPhotometricReport> pr =
      RefineScanPhotometric(ModelPlaceMap(model, RenderOptions()), &held, PlaceExtent(own, model.normalization()),
                            PhotometricRefineOptions());
  if (!pr.ok()) return std::nullopt;
  if (moved != nullptr) *moved = pr->accepted;
  return HeldOutPsnr(model, held.train, 0, c.args->eval_views);
}

// A first scan: its poses against the known ones after one similarity (when
// one fits), and visit A posed scored on the held-out views COLMAP posed
// (matched poses: they were posed in the same run, as the service poses an
// upload's test frames).
absl::Status ScoreFirstScanPoses(const RescanContext& c, const NgpModel& posed_model, CaseScan* cs,
                                 nlohmann::json* row) {
  std::vector<View> same;
  for (const View& v : c.test) {
    for (const View& p : cs->scored) {
      if (p.name == v.name) same.push_back(v);
    }
  }
  cs->baseline = HeldOutPsnr(posed_model, same, 0, c.args->eval_views);
  (*row)["held_out_posed"] = cs->scored.size();
  (*row)["psnr_posed_baseline"] = cs->baseline;
  // The same test-time alignment as the unposed model's views get, so that
  // the two are compared at matched poses (BARF's protocol) on both sides.
  if (const std::optional<double> aligned = AlignedHeldOutPsnr(c, posed_model, c.visit_a, same, nullptr)) {
    (*row)["psnr_posed_baseline_aligned"] = *aligned;
  }
  std::vector<PosePair> pairs;
  for (size_t k = 0; k < cs->posed.size(); ++k) {
    pairs.push_back({cs->posed_truth[k].camera.c2w, cs->scan.train[k].camera.c2w});
  }
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, c.extent, {});
  if (!fit.ok()) {  // COLMAP's model is not the scene up to a similarity: the service would still train on it.
    (*row)["pose_fit"] = fit.status().ToString();
    std::printf("  unposed-first: COLMAP's poses fit no similarity to the known ones: %s\n",
                std::string(fit.status().message()).c_str());
    return absl::OkStatus();
  }
  Scene back = cs->scan;
  ApplySimilarity(fit->transform.Inverse(), &back);
  const PoseErrors e = FrameErrors(back.train, cs->posed_truth, c.extent);
  (*row)["centre_error_pct_median"] = e.centre_median;
  (*row)["rotation_error_deg_median"] = e.rotation_median;
  return absl::OkStatus();
}

// As the update worker does for a scan it posed, before refining it:
// frames whose SfM pose the place's map disputes take their PnP pose.
// `r` forgets the frames dropped.
void ArbitrateLikeTheService(const RescanContext& c, RegistrationReport* r, CaseScan* cs, nlohmann::json* row) {
  std::set<std::string> drop;
  absl::StatusOr<ArbitrationReport> a =
      ArbitrateRegisteredScan(ModelPlaceMap(*c.place_state->model, RenderOptions()), c.extent,
                              c.args->registration.arbitration, cs->suspect, r, &cs->scan, &drop);
  if (!a.ok()) std::printf("  arbitration failed: %s\n", std::string(a.status().message()).c_str());
  (*row)["pose_check_dropped"] = DropCaseFrames(drop, cs);
  cs->suspect.clear();
  if (!a.ok()) return;
  (*row)["pose_check_confirmed"] = a->confirmed;
  const PoseErrors e = FrameErrors(cs->scan.train, cs->posed_truth, c.extent);
  (*row)["arbitration_disputed"] = a->disputed;
  (*row)["arbitration_moved"] = a->taken;
  (*row)["arbitration_seconds"] = a->seconds;
  (*row)["arbitrated_rotation_error_deg_max"] = e.rotation_max;
  std::printf("  %s (%.1f s); poses %.2f%% / %.2f deg from the known (max %.1f%% / %.1f deg)\n",
              a->Summary().c_str(), a->seconds, e.centre_median, e.rotation_median, e.centre_max, e.rotation_max);
}

// A later visit registered into the place (and, for a scan it posed,
// refined as the service does); false (row filled) when refused.
bool RegisterCase(const RescanContext& c, const std::string& which, CaseScan* cs, nlohmann::json* row) {
  const auto t0 = std::chrono::steady_clock::now();
  RegistrationReport r = RegisterScan(cs->scan, ModelPlaceMap(*c.place_state->model, RenderOptions()), c.place,
                                      c.extent, c.args->registration);
  if (!r.status.ok() && !cs->suspect.empty()) {  // As the service: again without the disputed frames.
    std::printf("  %s: not placed with the disputed frames (%s); again without them\n", which.c_str(),
                std::string(r.status.message()).c_str());
    (*row)["pose_check_dropped"] = DropCaseFrames(cs->suspect, cs);
    cs->suspect.clear();
    r = RegisterScan(cs->scan, ModelPlaceMap(*c.place_state->model, RenderOptions()), c.place, c.extent,
                     c.args->registration);
  }
  cs->register_seconds = SecondsSince(t0);
  (*row)["registered"] = r.status.ok();
  (*row)["identity"] = r.identity;
  (*row)["status"] = r.status.ToString();
  if (r.status.ok()) ApplySimilarity(r.transform, &cs->scan);
  const PoseErrors e = FrameErrors(cs->scan.train, cs->posed_truth, c.extent);
  std::vector<View> pnp, pnp_truth;  // Each placed frame's own PnP pose against the place's renders.
  for (size_t k = 0; k < r.tried.size(); ++k) {
    if (!r.localized[k].placed) continue;
    View v = cs->scan.train[size_t(r.tried[k])];
    v.camera.c2w = r.localized[k].c2w;
    pnp.push_back(v);
    pnp_truth.push_back(cs->posed_truth[size_t(r.tried[k])]);
  }
  const PoseErrors pe = FrameErrors(pnp, pnp_truth, c.extent);
  (*row)["pnp_centre_error_pct_median"] = pe.centre_median;
  (*row)["pnp_rotation_error_deg_median"] = pe.rotation_median;
  std::printf("  %s: registered poses %.2f%% / %.2f deg from the known; per-frame PnP poses %.2f%% / %.2f deg "
              "(%zu frames)\n",
              which.c_str(), e.centre_median, e.rotation_median, pe.centre_median, pe.rotation_median, pnp.size());
  if (const std::string off = e.Outliers(); !off.empty()) {
    std::printf("  %s: frames far off after registration: %s\n", which.c_str(), off.c_str());
    (*row)["registered_outliers"] = off;
    auto turn = [](const Pose& a, const Pose& b) {
      return RotationAngleDegrees(a.leftCols<3>().cast<double>(), b.leftCols<3>().cast<double>());
    };
    for (size_t k = 0; k < r.tried.size(); ++k) {  // What PnP said of each frame.
      const size_t i = size_t(r.tried[k]);
      const FrameLocalization& l = r.localized[k];
      std::string pnp;
      if (l.placed) {
        pnp = absl::StrFormat(", PnP %.1f deg from the known (std %.2f deg), %.1f deg from registered",
                              turn(l.c2w, cs->posed_truth[i].camera.c2w), l.rotation_std_deg,
                              turn(l.c2w, cs->scan.train[i].camera.c2w));
      }
      std::printf("    frame %zu: %s, %d inliers%s\n", i, l.placed ? "placed" : "not placed", l.inliers, pnp.c_str());
    }
  }
  // As the service: a scan it posed has its camera refined against the
  // place after registration ("unposed-unrefined": without, to compare).
  const bool refine = RefinedLikeTheService(which);
  if (refine && r.status.ok() && c.args->registration.arbitrate) {
    ArbitrateLikeTheService(c, &r, cs, row);
  }
  if (!cs->suspect.empty()) (*row)["pose_check_dropped"] = DropCaseFrames(cs->suspect, cs);
  if (refine && r.status.ok()) {
    RefineLikeTheService(*c.place_state->model, r, c.extent, which, cs->posed_truth, c.args->registration.camera,
                         &cs->scan, row);
  }
  // A scan posed by its uploader (in the place's frame or its own): its
  // similarity refined photometrically ("own-nophoto" skips it).
  if ((which == "place" || which == "own" || which == "own-frames") && r.status.ok() && !r.identity &&
      c.args->registration.photometric_similarity) {
    RefineSimilarityLikeTheService(*c.place_state->model, r, c.extent, c.args->registration, cs->posed_truth,
                                   &cs->scan, row);
  }
  if (which == "own-frames" && r.status.ok()) {  // Then each frame on its own, as for a scan the service posed.
    absl::StatusOr<ScanPhotometricReport> pr = RefineScanPhotometric(
        ModelPlaceMap(*c.place_state->model, RenderOptions()), &cs->scan, c.extent, PhotometricRefineOptions());
    if (pr.ok()) {
      const PoseErrors pe = FrameErrors(cs->scan.train, cs->posed_truth, c.extent);
      (*row)["photometric_accepted"] = pr->accepted;
      (*row)["photometric_seconds"] = pr->seconds;
      (*row)["photometric_centre_error_pct_median"] = pe.centre_median;
      (*row)["photometric_rotation_error_deg_median"] = pe.rotation_median;
      std::printf("  own-frames: %d of %d frames aligned (%.1f s); poses %.2f%% / %.2f deg from the known\n",
                  pr->accepted, pr->frames, pr->seconds, pe.centre_median, pe.rotation_median);
    }
  }
  (*row)["centre_error_pct_median"] = e.centre_median;
  (*row)["centre_error_pct_max"] = e.centre_max;
  (*row)["rotation_error_deg_median"] = e.rotation_median;
  (*row)["rotation_error_deg_max"] = e.rotation_max;
  if (!r.status.ok() && which != "place") {
    std::printf("rescan %s, %s: refused: %s\n", c.args->data.c_str(), which.c_str(),
                std::string(r.status.message()).c_str());
    return false;
  }
  return true;
}

// Test-time alignment (as BARF and nerfstudio evaluate with pose
// optimisation): a first scan's held-out views, posed by the same COLMAP
// run, aligned photometrically to the trained model before scoring.
void ScoreTestAligned(const RescanContext& c, const std::string& which, const NgpModel& model, const CaseScan& cs,
                      nlohmann::json* row) {
  int moved = 0;
  const std::optional<double> psnr = AlignedHeldOutPsnr(c, model, cs.scan, cs.scored, &moved);
  if (!psnr) return;
  (*row)["psnr_test_aligned"] = *psnr;
  std::printf("  %s: held-out views aligned to the model (%d of %zu moved): %.2f dB\n", which.c_str(), moved,
              cs.scored.size(), *psnr);
}

// UpdateOptions::refine_cameras: the cameras the update kept for visit B
// (the last ones of M_t, in the scan's order) against the known poses.
void RefinedCameraErrors(const RescanContext& c, const CaseScan& cs, const ContinualState& next, nlohmann::json* row) {
  const ReplayMemory& mem = next.memory;
  const size_t n = cs.scan.train.size();
  if (mem.num_cameras() < n || cs.posed_truth.size() != n) return;
  std::vector<View> kept = cs.scan.train;
  for (size_t i = 0; i < n; ++i) kept[i].camera = mem.GetCamera(uint32_t(mem.num_cameras() - n + i));
  const PoseErrors e = FrameErrors(kept, cs.posed_truth, c.extent);
  (*row)["camera_refined_centre_error_pct_median"] = e.centre_median;
  (*row)["camera_refined_rotation_error_deg_median"] = e.rotation_median;
  std::printf("  cameras refined while training: pose error median %.2f%% / %.2f deg\n", e.centre_median,
              e.rotation_median);
}

// Visit B's update from the registered scan, once per update seed
// (--update-seeds: --train-seed, +1, ...; visit A is the same for all), and
// its held-out scores: each seed's and their means.
absl::Status TrainCase(const RescanContext& c, const std::string& which, const CaseScan& cs, nlohmann::json* row) {
  const BenchRescanArgs& a = *c.args;
  double sum_latest = 0, sum_at_a = 0, sum_seconds = 0;
  nlohmann::json latest_seeds = nlohmann::json::array(), at_a_seeds = nlohmann::json::array();
  for (int k = 0; k < a.update_seeds; ++k) {
    UpdateOptions o = a.update;
    o.train.seed = a.update.train.seed + uint64_t(k);
    const auto t0 = std::chrono::steady_clock::now();
    absl::StatusOr<ContinualState> next = ContinualUpdate(cs.scan, c.place_state, o, {}, nullptr, nullptr);
    if (!next.ok()) return next.status();
    const double train_seconds = SecondsSince(t0);
    (*row)["refine_cameras"] = o.refine_cameras;
    if (o.refine_cameras) RefinedCameraErrors(c, cs, *next, row);
    const std::string renders =
        a.save_renders.empty() ? "" : absl::StrCat(a.save_renders, "/", which, "_seed", o.train.seed);
    const double latest = HeldOutScores(*next->model, c.test_b, 1, a.eval_views, renders).psnr;
    const double at_a = HeldOutPsnr(*next->model, cs.scored, 0, a.eval_views);
    latest_seeds.push_back(latest);
    at_a_seeds.push_back(at_a);
    sum_latest += latest;
    sum_at_a += at_a;
    sum_seconds += train_seconds;
    std::printf("rescan %s, %-13s: %zu/%zu frames posed | pose error median %.2f%% / %.2f deg | pose %.1f s, "
                "register %.1f s, train %.1f s (update seed %llu) | held-out PSNR latest %.2f dB, at visit A's "
                "time %.2f dB\n",
                a.data.c_str(), which.c_str(), cs.posed.size(), cs.truth.size(),
                row->value("centre_error_pct_median", 0.0), row->value("rotation_error_deg_median", 0.0),
                cs.posing_seconds, cs.register_seconds, train_seconds, (unsigned long long)o.train.seed, latest, at_a);
    std::fflush(stdout);
  }
  const double n = double(a.update_seeds);
  (*row)["train_seconds"] = sum_seconds / n;
  (*row)["psnr_latest"] = sum_latest / n;  // Means over the update seeds.
  (*row)["psnr_at_a"] = sum_at_a / n;
  if (a.update_seeds > 1) {
    (*row)["psnr_latest_seeds"] = latest_seeds;
    (*row)["psnr_at_a_seeds"] = at_a_seeds;
    std::printf("rescan %s, %-13s: mean over %d update seeds: held-out PSNR latest %.2f dB, at visit A's time "
                "%.2f dB\n",
                a.data.c_str(), which.c_str(), a.update_seeds, sum_latest / n, sum_at_a / n);
  }
  return absl::OkStatus();
}

// One later-visit case, start to end: its JSON row (an error only for a
// broken bench).
absl::StatusOr<nlohmann::json> RunCase(const RescanContext& c, const std::string& which) {
  const BenchRescanArgs& a = *c.args;
  nlohmann::json row = {{"case", which}};
  CaseScan cs;
  cs.scan = c.visit_b;
  cs.truth = cs.scan.train;
  cs.scored = c.test;
  const bool own = which == "own" || which == "own-nophoto" || which == "own-frames";
  if (own) ApplySimilarity(OwnFrame(a.rotation_deg, a.scale, a.seed, c.extent), &cs.scan);
  const bool known = which == "known";  // The truth: no registration at all.
  if (which != "place" && !known && !own) {
    if (!PoseCase(c, which, &cs, &row)) return row;
  } else {
    for (size_t i = 0; i < cs.scan.train.size(); ++i) cs.posed.push_back(int(i));
  }
  CheckCasePoses(c, which, &cs, &row);
  for (int i : cs.posed) cs.posed_truth.push_back(cs.truth[size_t(i)]);
  if (!known && !RegisterCase(c, which, &cs, &row)) return row;
  row["register_seconds"] = cs.register_seconds;
  if (absl::Status st = TrainCase(c, which, cs, &row); !st.ok()) return st;
  std::fflush(stdout);
  return row;
}

// Visit A with its known poses, trained with `seed`: what an unposed first
// scan trained with the same seed is compared with (the place itself for
// the bench's own seed).
absl::StatusOr<std::shared_ptr<const NgpModel>> PosedFirstScan(const RescanContext& c, uint64_t seed) {
  if (seed == c.first.train.seed) return c.place_state->model;
  UpdateOptions o = c.first;
  o.train.seed = seed;
  absl::StatusOr<ContinualState> s = ContinualUpdate(c.visit_a, nullptr, o, {}, nullptr, nullptr);
  if (!s.ok()) return s.status();
  return s->model;
}

// unposed-first with one training seed: visit A's photos posed by COLMAP
// (with its held-out views), trained as a place's first scan, and scored
// against visit A posed and trained with the same seed.
absl::StatusOr<nlohmann::json> RunFirstScanSeed(const RescanContext& c, uint64_t seed) {
  const BenchRescanArgs& a = *c.args;
  const std::string which = "unposed-first";
  nlohmann::json row = {{"seed", seed}};
  CaseScan cs;
  cs.scan = c.visit_a;
  cs.truth = cs.scan.train;
  cs.scored = c.test;
  if (!PoseCase(c, which, &cs, &row)) return row;
  for (int i : cs.posed) cs.posed_truth.push_back(cs.truth[size_t(i)]);
  absl::StatusOr<std::shared_ptr<const NgpModel>> posed = PosedFirstScan(c, seed);
  if (!posed.ok()) return posed.status();
  if (absl::Status s = ScoreFirstScanPoses(c, **posed, &cs, &row); !s.ok()) return s;
  UpdateOptions o = c.first;
  o.train.seed = seed;
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<ContinualState> next = ContinualUpdate(cs.scan, nullptr, o, {}, nullptr, nullptr);
  if (!next.ok()) return next.status();
  row["train_seconds"] = SecondsSince(t0);
  row["psnr_latest"] = HeldOutPsnr(*next->model, cs.scored, 0, a.eval_views);
  ScoreTestAligned(c, which, *next->model, cs, &row);
  std::printf("rescan %s, %s, seed %llu: %zu/%zu frames posed | pose error median %.2f%% / %.2f deg | pose %.1f s, "
              "train %.1f s | held-out PSNR %.2f dB (visit A posed, same seed and %zu views: %.2f dB)\n",
              a.data.c_str(), which.c_str(), (unsigned long long)seed, cs.posed.size(), cs.truth.size(),
              row.value("centre_error_pct_median", 0.0), row.value("rotation_error_deg_median", 0.0),
              cs.posing_seconds, row["train_seconds"].get<double>(), row["psnr_latest"].get<double>(),
              cs.scored.size(), cs.baseline);
  std::fflush(stdout);
  return row;
}

// unposed-first over --first-seeds training seeds: the per-seed rows and
// the means over the seeds COLMAP posed.
absl::StatusOr<nlohmann::json> RunFirstScanCase(const RescanContext& c) {
  nlohmann::json row = {{"case", "unposed-first"}, {"seeds", nlohmann::json::array()}};
  double sum = 0, sum_base = 0, sum_aligned = 0, sum_base_aligned = 0;
  int n = 0;
  for (int k = 0; k < c.args->first_seeds; ++k) {
    absl::StatusOr<nlohmann::json> r = RunFirstScanSeed(c, c.first.train.seed + uint64_t(k));
    if (!r.ok()) return r.status();
    row["seeds"].push_back(*r);
    if (!r->contains("psnr_latest")) continue;
    sum += (*r)["psnr_latest"].get<double>();
    sum_base += (*r)["psnr_posed_baseline"].get<double>();
    sum_aligned += r->value("psnr_test_aligned", (*r)["psnr_latest"].get<double>());
    sum_base_aligned += r->value("psnr_posed_baseline_aligned", (*r)["psnr_posed_baseline"].get<double>());
    ++n;
  }
  row["seeds_posed"] = n;
  if (n == 0) return row;
  row["psnr_latest"] = sum / n;
  row["psnr_posed_baseline"] = sum_base / n;
  row["psnr_test_aligned"] = sum_aligned / n;
  row["psnr_posed_baseline_aligned"] = sum_base_aligned / n;
  row["gap_known_poses_db"] = (sum - sum_base) / n;
  row["gap_matched_poses_db"] = (sum_aligned - sum_base_aligned) / n;
  std::printf("rescan %s, unposed-first over %d seeds: mean held-out PSNR %.2f dB against visit A posed %.2f dB "
              "(%+.2f dB); test views aligned to each model (matched poses): %.2f against %.2f (%+.2f dB)\n",
              c.args->data.c_str(), n, sum / n, sum_base / n, (sum - sum_base) / n, sum_aligned / n,
              sum_base_aligned / n, (sum_aligned - sum_base_aligned) / n);
  std::fflush(stdout);
  return row;
}

absl::Status CheckCases(const std::vector<std::string>& cases) {
  static const std::set<std::string> kCases = {"known",           "place",           "own",
                                               "own-nophoto",     "own-frames", "unposed",
                                               "unposed-unseeded", "unposed-unrefined",
                                               "unposed-nophoto", "unposed-first"};
  for (const std::string& c : cases) {
    if (!kCases.count(c)) {
      return absl::InvalidArgumentError(absl::StrCat(
          "unknown case '", c,
          "' (known, place, own, own-nophoto, own-frames, unposed, unposed-unseeded, unposed-unrefined, unposed-nophoto, unposed-first)"));
    }
  }
  return absl::OkStatus();
}

// What identifies visit A's training in a --place-cache file.
std::string PlaceCacheKey(const BenchRescanArgs& a) {
  const TrainOptions& t = a.update.train;
  return absl::StrCat("data=", a.data, " first_iterations=", a.first_iterations, " seed=", t.seed,
                      " grid_decay=", t.grid_decay, " coarse_to_fine=", t.coarse_to_fine, " distortion=",
                      t.distortion_reg, " learning_rate=", t.learning_rate, " oversample=",
                      a.update.capacity.oversample);
}

// Visit A trained as the place's first scan, or read back from
// --place-cache (written there after training when the file is absent):
// iterating on registration then skips minutes of training. The cache holds
// the model, replay memory and optimiser state exactly (float32), and the
// key it was trained under; a different key is an error, not a retrain.
absl::StatusOr<ContinualState> PlaceState(const RescanContext& c, double* train_seconds) {
  const BenchRescanArgs& a = *c.args;
  constexpr char kMemory[] = "replay_memory", kOptimizer[] = "optimizer";
  if (!a.place_cache.empty() && std::filesystem::exists(a.place_cache)) {
    absl::StatusOr<LoadedCheckpoint> ck = LoadCheckpoint(a.place_cache);
    if (!ck.ok()) return ck.status();
    const auto key = ck->extras.metadata.find("bench_rescan_key");
    if (key == ck->extras.metadata.end() || key->second != PlaceCacheKey(a)) {
      return absl::FailedPreconditionError(absl::StrCat("--place-cache ", a.place_cache, " was trained for '",
                                                        key == ck->extras.metadata.end() ? "?" : key->second,
                                                        "', not '", PlaceCacheKey(a), "'"));
    }
    const std::string* mem = ck->extras.FindSection(kMemory);
    const std::string* opt = ck->extras.FindSection(kOptimizer);
    if (mem == nullptr) return absl::DataLossError("--place-cache has no replay memory");
    absl::StatusOr<ReplayMemory> memory = ReplayMemory::Deserialize(*mem);
    if (!memory.ok()) return memory.status();
    ContinualState s;
    s.model = std::make_shared<const NgpModel>(std::move(ck->model));
    s.memory = *std::move(memory);
    if (opt != nullptr) {
      absl::StatusOr<OptimizerState> o = OptimizerState::Deserialize(*opt);
      if (!o.ok()) return o.status();
      s.optimizer = std::make_shared<const OptimizerState>(*std::move(o));
    }
    *train_seconds = std::stod(ck->extras.metadata["train_seconds"]);
    std::fprintf(stderr, "bench rescan: visit A read from %s\n", a.place_cache.c_str());
    return s;
  }
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<ContinualState> s = ContinualUpdate(c.visit_a, nullptr, c.first, {}, nullptr, nullptr);
  if (!s.ok()) return s.status();
  *train_seconds = SecondsSince(t0);
  if (a.place_cache.empty()) return s;
  CheckpointExtras extras;
  extras.metadata["bench_rescan_key"] = PlaceCacheKey(a);
  extras.metadata["train_seconds"] = absl::StrCat(*train_seconds);
  extras.sections.emplace_back(kMemory, s->memory.Serialize());
  if (s->optimizer != nullptr) extras.sections.emplace_back(kOptimizer, s->optimizer->Serialize());
  if (absl::StatusOr<size_t> w = SaveCheckpoint(*s->model, a.place_cache, extras); !w.ok()) return w.status();
  return s;
}

}  // namespace

CLI::App* BindBenchRescan(CLI::App* parent, BenchRescanArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "rescan", "A capture split into two visits; the second as people bring it (place frame, own frame, unposed) "
                "posed, registered, trained and scored on held-out views");
  a->update.train.iterations = 1000;
  c->add_option("--data", a->data,
                "Dataset folder, 'procedural' (forward-facing) or 'procedural-moved' (objects moved between visits)")
      ->required();
  c->add_option("--first-iters", a->first_iterations, "Training steps of visit A (the first scan)")
      ->capture_default_str();
  c->add_option("--iters", a->update.train.iterations, "Training steps of visit B's update")->capture_default_str();
  c->add_option("--cases", a->cases, "Comma-separated: known (visit B at its known poses, not registered), place, own, own-nophoto, unposed, unposed-unseeded, unposed-unrefined, unposed-nophoto, unposed-first")->capture_default_str();
  c->add_option("--rotation", a->rotation_deg, "Visit B's own frame: rotation (degrees)")->capture_default_str();
  c->add_option("--min-side", a->registration.localizer.min_side,
                "Registration: photos smaller than this (long side, pixels) are matched at this size")
      ->capture_default_str();
  c->add_option("--arbitrate", a->registration.arbitrate,
                "Unposed cases: frames whose COLMAP pose the place's map disputes take their PnP pose, and the "
                "frames the pose check disputes are kept only where the map vouches for them (false: dropped "
                "before registration; pose_arbitration.h)")
      ->capture_default_str();
  c->add_option("--similarity-frames", a->registration.similarity_options.max_frames,
                "Registration: frames the photometric similarity refinement renders and aligns")
      ->capture_default_str();
  c->add_option("--scale", a->scale, "... and scale")->capture_default_str();
  c->add_option("--seed", a->seed, "Seed of its axis and shift")->capture_default_str();
  c->add_option("--eval-views", a->eval_views, "Held-out views scored (0 = all)")->capture_default_str();
  c->add_option("--update-seeds", a->update_seeds,
                "Visit B's update trained with this many seeds (--train-seed, +1, ...) after one registration; "
                "PSNRs are their means (one seed's update varies by ~0.2 dB)")
      ->check(CLI::Range(1, 20))
      ->capture_default_str();
  c->add_option("--train-seed", a->update.train.seed, "Training seed of visit A and of every update")
      ->capture_default_str();
  c->add_option("--refine-cameras", a->update.refine_cameras,
                "Visit B's update learns a pose correction per photo while it trains (camera_refiner.h)")
      ->capture_default_str();
  c->add_option("--camera-lr", a->update.camera_refine.learning_rate, "... at this learning rate")
      ->capture_default_str();
  BindRegulariserFlags(c, &a->update.train);  // Every training of the bench.
  c->add_option("--oversample", a->update.capacity.oversample,
                "Finest hash-grid cells per pixel footprint (capacity.h), every training")
      ->capture_default_str();
  c->add_option("--max-finest", a->update.capacity.max_finest_resolution,
                "Upper bound on the derived finest hash-grid resolution (0 = 2048 per unit of bound)")
      ->capture_default_str();
  c->add_option("--place-cache", a->place_cache,
                "Visit A's trained place: read from this file when it exists (trained with the same --data, "
                "--first-iters and --train-seed), else trained and written there");
  c->add_option("--posing-cache", a->posing_cache,
                "COLMAP's poses of visit B (unposed cases): read from this JSON file when it exists, else "
                "written there (COLMAP is not deterministic; this keeps one answer to compare against)");
  c->add_option("--camera-min-rms-gain", a->registration.camera.min_rms_gain,
                "Unposed cases: the camera refined against the place is taken only when it cuts the reprojection "
                "error by this fraction (-1 and --camera-max-change 1: always, as before session 56)")
      ->capture_default_str();
  c->add_option("--camera-max-change", a->registration.camera.max_focal_change,
                "... and moves the focal length by at most this fraction (k1 by at most this much)")
      ->capture_default_str()
      ->each([a](const std::string&) {
        a->registration.camera.max_k1_change = a->registration.camera.max_focal_change;
      });
  c->add_option("--save-renders", a->save_renders, "Write visit A's held-out renders (and the photos) here, and each case's update's in CASE_seedN/");
  c->add_option("--first-seeds", a->first_seeds,
                "unposed-first: training seeds compared (each with its own COLMAP run and posed baseline)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  BindDatasetFlags(c, &a->dataset);
  BindThreadsFlag(c, &a->threads);
  c->add_option("--pose-check", a->pose_check,
                "Visit B's poses checked against its photos before registration, as the service does: auto (its "
                "default: drop the disputed frames of a scan COLMAP posed, warn otherwise), warn, drop (train "
                "without the disputed frames) or off")
      ->check(CLI::IsMember({"auto", "warn", "drop", "off"}))
      ->capture_default_str();
  BindPoseCheckFlags(c, &a->check);
  c->add_option("--json", a->json, "Write JSON here ('-' = stdout)");
  return c;
}

int RunBenchRescan(const BenchRescanArgs& a) {
  SetThreads(a.threads);
  absl::StatusOr<Scene> all = LoadVisitScene(a.data, a.dataset);
  if (!all.ok()) return Fail(all.status());
  RescanContext c;
  c.args = &a;
  SplitVisits(*all, &c.visit_a, &c.visit_b);
  // Held-out views of visit A's time, and of visit B's (the same views
  // when the capture has one time).
  c.test = HeldOutAt(*all, 0);
  c.test_b = HeldOutAt(*all, 1);
  if (c.test.empty()) return Fail(absl::InvalidArgumentError("the capture has no held-out (test or val) views"));
  for (View& v : c.visit_b.train) v.camera.time_step = 1;
  for (View& v : c.visit_a.train) v.camera.time_step = 0;
  c.visit_a.test.clear();
  c.visit_a.val.clear();
  const std::vector<std::string> cases = absl::StrSplit(a.cases, ',', absl::SkipEmpty());
  if (absl::Status s = CheckCases(cases); !s.ok()) return Fail(s);
  std::fprintf(stderr, "bench rescan: %s, visit A %zu frames (%d iterations), visit B %zu frames (%d), %zu held out\n",
               a.data.c_str(), c.visit_a.train.size(), a.first_iterations, c.visit_b.train.size(),
               a.update.train.iterations, c.test.size());
  c.first = a.update;
  c.first.train.iterations = a.first_iterations;
  double train_a = 0;
  absl::StatusOr<ContinualState> state_a = PlaceState(c, &train_a);
  if (!state_a.ok()) return Fail(state_a.status());
  c.place_state = &*state_a;
  const EvalResult scores_a = HeldOutScores(*state_a->model, c.test, 0, a.eval_views, a.save_renders);
  c.psnr_a = scores_a.psnr;
  // Four of visit A's own photos: a held-out score far below this is a field
  // that fits its photos and fails between them (floaters, speckle).
  const EvalResult fit_a = HeldOutScores(*state_a->model, c.visit_a.train, 0, 4,
                                         a.save_renders.empty() ? "" : a.save_renders + "/train");
  std::printf("rescan %s: visit A trained in %.1f s, held-out PSNR %.2f dB, speckle %.4f, blur %.4f "
              "(4 of its training views: %.2f dB)\n",
              a.data.c_str(), train_a, c.psnr_a, scores_a.speckle, scores_a.blur, fit_a.psnr);
  for (const View& v : c.visit_a.train) c.place.push_back(v.camera);
  c.extent = PlaceExtent(c.place, state_a->model->normalization());
  nlohmann::json out = {{"data", a.data}, {"frames_a", c.visit_a.train.size()}, {"frames_b", c.visit_b.train.size()},
                        {"held_out", c.test.size()}, {"first_iterations", a.first_iterations},
                        {"iterations", a.update.train.iterations}, {"train_seed", a.update.train.seed},
                        {"update_seeds", a.update_seeds},
                        {"grid_decay", a.update.train.grid_decay}, {"coarse_to_fine", a.update.train.coarse_to_fine},
                        {"distortion", a.update.train.distortion_reg}, {"learning_rate", a.update.train.learning_rate},
                        {"similarity_frames", a.registration.similarity_options.max_frames},
                        {"oversample", a.update.capacity.oversample},
                        {"train_a_seconds", train_a},
                        {"psnr_a", c.psnr_a}, {"speckle_a", scores_a.speckle}, {"blur_a", scores_a.blur},
                        {"psnr_a_train_views", fit_a.psnr},
                        {"grid", {{"levels", state_a->model->options().grid.levels},
                                  {"log2_table_size", state_a->model->options().grid.log2_table_size},
                                  {"finest_resolution", state_a->model->options().grid.finest_resolution}}},
                        {"cases", nlohmann::json::array()}};
  for (const std::string& which : cases) {
    absl::StatusOr<nlohmann::json> row = which == "unposed-first" ? RunFirstScanCase(c) : RunCase(c, which);
    if (!row.ok()) return Fail(row.status());
    out["cases"].push_back(*row);
  }
  if (!a.json.empty()) {
    if (absl::Status s = WriteJson(a.json, out); !s.ok()) return Fail(s);
  }
  return 0;
}

}  // namespace clnerf
