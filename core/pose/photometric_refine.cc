#include "core/pose/photometric_refine.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/data/stopwatch.h"
#include "core/pose/direct_alignment.h"
#include "Eigen/Dense"
#include "Eigen/Geometry"

namespace clnerf {

absl::Status PhotometricRefineOptions::Validate() const {
  if (levels < 1 || levels > 6) return absl::InvalidArgumentError("photometric levels must be in [1, 6]");
  if (max_side < 32) return absl::InvalidArgumentError("photometric max_side must be at least 32");
  if (iterations < 1) return absl::InvalidArgumentError("photometric iterations must be at least 1");
  if (!(min_opacity >= 0 && min_opacity <= 1)) return absl::InvalidArgumentError("min_opacity must be in [0, 1]");
  if (!(min_gradient >= 0)) return absl::InvalidArgumentError("min_gradient must be >= 0");
  if (!(huber_k > 0)) return absl::InvalidArgumentError("huber_k must be > 0");
  if (!(max_rotation_deg > 0) || !(max_centre > 0)) {
    return absl::InvalidArgumentError("photometric max_rotation_deg and max_centre must be > 0");
  }
  if (!(min_improvement >= 0 && min_improvement < 1)) {
    return absl::InvalidArgumentError("photometric min_improvement must be in [0, 1)");
  }
  if (min_pixels < 8) return absl::InvalidArgumentError("photometric min_pixels must be at least 8");
  return absl::OkStatus();
}

namespace {

using Vec8 = Eigen::Matrix<double, 8, 1>;
using Mat8 = Eigen::Matrix<double, 8, 8>;

struct Residuals {
  std::vector<double> r;                  // Per point; NaN where unusable.
  std::vector<Eigen::Matrix<double, 1, 8>> j;  // Filled when asked.
  int used = 0;
};

// Photo residuals gain x photo(projection) + bias - keyframe grey, and their
// Jacobian over (rotation, translation, gain, bias) when `with_jacobian`.
Residuals Evaluate(const Keyframe& k, const GreyImage& photo, const Intrinsics& in, const W2C& pose, double gain,
                   double bias, bool with_jacobian) {
  Residuals out;
  out.r.assign(k.points.size(), std::nan(""));
  if (with_jacobian) out.j.resize(k.points.size());
  for (size_t i = 0; i < k.points.size(); ++i) {
    const Eigen::Vector3d xc = pose.r * k.points[i] + pose.t;
    Eigen::Vector2d px;
    Eigen::Matrix<double, 2, 3> dpx;
    if (!Project(in, xc, &px, &dpx)) continue;
    float value, dx, dy;
    if (!photo.Sample(px.x(), px.y(), &value, &dx, &dy)) continue;
    out.r[i] = gain * value + bias - k.grey[i];
    ++out.used;
    if (!with_jacobian) continue;
    // d(camera point)/d(rotation w) = w x xc, so a . (w x xc) = w . (xc x a).
    const Eigen::Vector3d a = gain * (double(dx) * dpx.row(0) + double(dy) * dpx.row(1)).transpose();
    const Eigen::Vector3d rot = xc.cross(a);
    out.j[i] << rot.x(), rot.y(), rot.z(), a.x(), a.y(), a.z(), double(value), 1.0;
  }
  return out;
}

struct AlignState {
  W2C pose;
  double gain = 1, bias = 0;
};

// Levenberg-Marquardt on the keyframe; `pose_free` false fits only gain and
// bias. Returns the final mean Huber cost at the scale `delta` (computed at
// the start when delta <= 0, and written back).
double Align(const Keyframe& k, const GreyImage& photo, const Intrinsics& in, int iterations, bool pose_free,
             double huber_k, double* delta, AlignState* s) {
  Residuals res = Evaluate(k, photo, in, s->pose, s->gain, s->bias, true), cand;
  if (*delta <= 0) *delta = huber_k * RobustSigma(res.r);
  AlignState next;
  const AlignmentCost cost = LevenbergMarquardt(
      iterations, AlignmentCost{HuberCost(res.r, *delta), res.used},
      [&](Eigen::MatrixXd* h, Eigen::VectorXd* g) {
        Mat8 hf = Mat8::Zero();
        Vec8 gf = Vec8::Zero();
        for (size_t i = 0; i < res.r.size(); ++i) {
          const double r = res.r[i];
          if (!std::isfinite(r)) continue;
          const double w = std::abs(r) <= *delta ? 1.0 : *delta / std::abs(r);
          hf.noalias() += w * res.j[i].transpose() * res.j[i];
          gf.noalias() += w * r * res.j[i].transpose();
        }
        *h = hf;
        *g = gf;
        if (!pose_free) PinLeading(6, h, g);
      },
      [&](const Eigen::VectorXd& step) {
        next.pose = s->pose.Moved(step.head<6>());
        next.gain = s->gain + step(6);
        next.bias = s->bias + step(7);
        cand = Evaluate(k, photo, in, next.pose, next.gain, next.bias, true);
        return AlignmentCost{HuberCost(cand.r, *delta), cand.used};
      },
      [&] {
        *s = next;
        res = std::move(cand);
      });
  return cost.mean;
}

}  // namespace

absl::StatusOr<PhotometricRefinement> RefinePosePhotometric(const PlaceMap& map, const Image& photo,
                                                            const Camera& camera, double extent,
                                                            const PhotometricRefineOptions& o) {
  if (absl::Status s = o.Validate(); !s.ok()) return s;
  if (photo.width != camera.intrinsics.width || photo.height != camera.intrinsics.height || photo.empty()) {
    return absl::InvalidArgumentError(absl::StrFormat("the photo is %dx%d but its camera %dx%d", photo.width,
                                                      photo.height, camera.intrinsics.width,
                                                      camera.intrinsics.height));
  }
  const double shrink = std::min(1.0, double(o.max_side) / std::max(photo.width, photo.height));
  const int w0 = std::max(8, int(std::lround(photo.width * shrink)));
  const int h0 = std::max(8, int(std::lround(photo.height * shrink)));
  PhotometricRefinement out;
  out.c2w = camera.c2w;
  AlignState s{W2C::FromPose(camera.c2w)};
  for (int level = o.levels - 1; level >= 1; --level) {
    const int w = std::max(8, w0 >> level), h = std::max(8, h0 >> level);
    Camera c = AtSize(camera, w, h);
    c.c2w = s.pose.ToPose();
    absl::StatusOr<Keyframe> k = RenderKeyframe(map, c, o.min_opacity, o.min_gradient);
    if (!k.ok()) return k.status();
    if (int(k->points.size()) < o.min_pixels / 4) continue;
    double delta = 0;
    Align(*k, GreyImage(ResizeImage(photo, w, h)), c.intrinsics, o.iterations, true, o.huber_k, &delta, &s);
  }
  // The finest level, keyed at the pose the coarse levels found. The photo
  // at the input pose and at the refined one is scored against the same
  // keyframe, each with its own exposure fit.
  Camera fine = AtSize(camera, w0, h0);
  fine.c2w = s.pose.ToPose();
  const GreyImage grey(ResizeImage(photo, w0, h0));
  absl::StatusOr<Keyframe> k = RenderKeyframe(map, fine, o.min_opacity, o.min_gradient);
  if (!k.ok()) return k.status();
  out.pixels = int(k->points.size());
  if (out.pixels < o.min_pixels) {
    out.why = absl::StrCat("only ", out.pixels, " solid, textured pixels (", o.min_pixels, " needed)");
    return out;
  }
  // Gain and bias alone are a linear fit: given enough steps to converge, so
  // that before and after compare poses, not how far the fit got.
  const int exposure_steps = 4 * o.iterations;
  double delta = 0;
  AlignState before{W2C::FromPose(camera.c2w)};
  out.cost_before = Align(*k, grey, fine.intrinsics, exposure_steps, false, o.huber_k, &delta, &before);
  Align(*k, grey, fine.intrinsics, o.iterations, true, o.huber_k, &delta, &s);
  out.cost_after = Align(*k, grey, fine.intrinsics, exposure_steps, false, o.huber_k, &delta, &s);
  Camera moved = fine;
  moved.c2w = s.pose.ToPose();
  out.gain = s.gain;
  out.bias = s.bias;
  const Eigen::Matrix3d dr = W2C::FromPose(camera.c2w).r * s.pose.r.transpose();
  out.rotation_deg = Eigen::AngleAxisd(dr).angle() * 180.0 / M_PI;
  out.centre = (moved.position() - camera.position()).cast<double>().norm() / std::max(extent, 1e-12);
  if (!(out.cost_after < out.cost_before * (1 - o.min_improvement))) {
    out.why = absl::StrFormat("no better: robust cost %.3g -> %.3g", out.cost_before, out.cost_after);
  } else if (out.rotation_deg > o.max_rotation_deg || out.centre > o.max_centre) {
    out.why = absl::StrFormat("moved too far (%.2f deg, %.2f%% of the place)", out.rotation_deg, 100 * out.centre);
  } else {
    out.accepted = true;
    out.c2w = moved.c2w;
  }
  return out;
}

absl::StatusOr<ScanPhotometricReport> RefineScanPhotometric(const PlaceMap& map, Scene* scene, double extent,
                                                            const PhotometricRefineOptions& options,
                                                            const PhotometricProgressFn& progress,
                                                            const std::atomic<bool>* cancel) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  const auto t0 = std::chrono::steady_clock::now();
  ScanPhotometricReport report;
  report.frames = int(scene->train.size());
  std::vector<double> rotations, centres;
  for (size_t i = 0; i < scene->train.size(); ++i) {
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("photometric refinement cancelled");
    View& v = scene->train[i];
    absl::StatusOr<PhotometricRefinement> r = RefinePosePhotometric(map, v.image, v.camera, extent, options);
    if (!r.ok()) return r.status();
    report.why.push_back(r->accepted ? "" : r->why);
    if (r->accepted) {
      v.camera.c2w = r->c2w;
      ++report.accepted;
      rotations.push_back(r->rotation_deg);
      centres.push_back(r->centre);
    }
    if (progress) progress(int(i) + 1, report.frames);
  }
  auto median = [](std::vector<double> a) {
    if (a.empty()) return 0.0;
    std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
    return a[a.size() / 2];
  };
  report.median_rotation_deg = median(rotations);
  report.median_centre = median(centres);
  report.seconds = SecondsSince(t0);
  return report;
}

}  // namespace clnerf
