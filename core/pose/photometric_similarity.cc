#include "core/pose/photometric_similarity.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/data/stopwatch.h"
#include "core/pose/direct_alignment.h"
#include "Eigen/Dense"
#include "Eigen/Geometry"

namespace clnerf {

absl::Status SimilarityRefineOptions::Validate() const {
  if (absl::Status s = alignment.Validate(); !s.ok()) return s;
  if (max_frames < 1) return absl::InvalidArgumentError("similarity refinement max_frames must be at least 1");
  if (min_frames < 1 || min_frames > max_frames) {
    return absl::InvalidArgumentError("similarity refinement min_frames must be in [1, max_frames]");
  }
  return absl::OkStatus();
}

namespace photometric_similarity_internal {

Similarity Increment(const Eigen::Matrix<double, 7, 1>& d, const Eigen::Vector3d& pivot) {
  Similarity s;
  const Eigen::Vector3d w = d.head<3>();
  const double angle = w.norm();
  s.rotation = angle > 0 ? Eigen::AngleAxisd(angle, w / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
  s.scale = std::exp(d(6));
  s.translation = pivot - s.scale * (s.rotation * pivot) + d.segment<3>(3);
  return s;
}

// Moving the camera by a left increment of its similarity is moving each
// point by the increment's inverse: X' = X - w x (X - p) - shift - s (X - p)
// to first order (the camera's own scale does not change a projection).
bool Residual(const GreyImage& photo, const Intrinsics& in, const W2C& cam, const Eigen::Vector3d& x, float grey,
              double gain, double bias, const Eigen::Vector3d& pivot, double* r, Gradient* j) {
  Eigen::Vector2d px;
  Eigen::Matrix<double, 2, 3> dpx;
  if (!Project(in, cam.r * x + cam.t, &px, &dpx)) return false;
  float value, dx, dy;
  if (!photo.Sample(px.x(), px.y(), &value, &dx, &dy)) return false;
  *r = gain * value + bias - grey;
  if (j == nullptr) return true;
  // d(residual) / d(world point), through the camera's rotation.
  const Eigen::Vector3d b =
      cam.r.transpose() * (gain * (double(dx) * dpx.row(0) + double(dy) * dpx.row(1)).transpose());
  const Eigen::Vector3d q = x - pivot;
  const Eigen::Vector3d rot = b.cross(q);
  *j << rot.x(), rot.y(), rot.z(), -b.x(), -b.y(), -b.z(), -b.dot(q), double(value), 1.0;
  return true;
}

}  // namespace photometric_similarity_internal

namespace {

using photometric_similarity_internal::Increment;
using photometric_similarity_internal::Residual;
constexpr int kSim = 7;  // Rotation vector, shift, log scale.
using Row = photometric_similarity_internal::Gradient;

// One frame at one pyramid level: its keyframe, its photo, its robust scale.
struct FrameLevel {
  Pose base;  // The frame's pose before any correction (place frame).
  Intrinsics in;
  Keyframe key;
  GreyImage grey;
  double delta = 0;
};

// What the solver moves: the correction and each frame's gain and bias.
struct State {
  Similarity t;
  std::vector<double> gain, bias;
};

struct FrameResiduals {
  std::vector<double> r;  // NaN where unusable.
  std::vector<Row> j;     // Over (similarity, this frame's gain, bias).
  int used = 0;
};

// Residuals of one frame with its camera moved by `t` (Residual per point).
FrameResiduals Evaluate(const FrameLevel& f, const Similarity& t, double gain, double bias,
                        const Eigen::Vector3d& pivot, bool with_jacobian) {
  FrameResiduals out;
  out.r.assign(f.key.points.size(), std::nan(""));
  if (with_jacobian) out.j.resize(f.key.points.size());
  const W2C cam = W2C::FromPose(t.ApplyToPose(f.base));
  for (size_t i = 0; i < f.key.points.size(); ++i) {
    double r;
    if (!Residual(f.grey, f.in, cam, f.key.points[i], f.key.grey[i], gain, bias, pivot, &r,
                  with_jacobian ? &out.j[i] : nullptr)) {
      continue;
    }
    out.r[i] = r;
    ++out.used;
  }
  return out;
}

using Cost = AlignmentCost;

Cost TotalCost(const std::vector<FrameLevel>& frames, const std::vector<FrameResiduals>& res) {
  double sum = 0;
  Cost c;
  for (size_t f = 0; f < frames.size(); ++f) {
    const double mean = HuberCost(res[f].r, frames[f].delta);
    if (res[f].used > 0) sum += mean * res[f].used;
    c.used += res[f].used;
  }
  if (c.used > 0) c.mean = sum / c.used;
  return c;
}

std::vector<FrameResiduals> EvaluateAll(const std::vector<FrameLevel>& frames, const State& s,
                                        const Eigen::Vector3d& pivot, bool with_jacobian) {
  std::vector<FrameResiduals> res(frames.size());
  for (size_t f = 0; f < frames.size(); ++f) {
    res[f] = Evaluate(frames[f], s.t, s.gain[f], s.bias[f], pivot, with_jacobian);
  }
  return res;
}

// Gauss-Newton's normal equations over (similarity, per frame gain and
// bias), Huber-weighted; the similarity's rows pinned when !pose_free.
void NormalEquations(const std::vector<FrameLevel>& frames, const std::vector<FrameResiduals>& res, bool pose_free,
                     Eigen::MatrixXd* h, Eigen::VectorXd* g) {
  const int n = kSim + 2 * int(frames.size());
  h->setZero(n, n);
  g->setZero(n);
  for (size_t f = 0; f < frames.size(); ++f) {
    const int e = kSim + 2 * int(f);
    for (size_t i = 0; i < res[f].r.size(); ++i) {
      const double r = res[f].r[i];
      if (!std::isfinite(r)) continue;
      const double w = std::abs(r) <= frames[f].delta ? 1.0 : frames[f].delta / std::abs(r);
      const Row& j = res[f].j[i];
      const Eigen::Matrix<double, kSim + 2, kSim + 2> jj = w * j.transpose() * j;
      h->topLeftCorner<kSim, kSim>() += jj.topLeftCorner<kSim, kSim>();
      h->block<kSim, 2>(0, e) += jj.topRightCorner<kSim, 2>();
      h->block<2, kSim>(e, 0) += jj.bottomLeftCorner<2, kSim>();
      h->block<2, 2>(e, e) += jj.bottomRightCorner<2, 2>();
      g->head<kSim>() += w * r * j.head<kSim>().transpose();
      g->segment<2>(e) += w * r * j.tail<2>().transpose();
    }
  }
  if (!pose_free) PinLeading(kSim, h, g);
}

// Levenberg-Marquardt from `s`; returns the final mean robust cost.
double Solve(const std::vector<FrameLevel>& frames, const Eigen::Vector3d& pivot, int iterations, bool pose_free,
             State* s) {
  std::vector<FrameResiduals> res = EvaluateAll(frames, *s, pivot, true), cand;
  State next;
  const Cost cost = LevenbergMarquardt(
      iterations, TotalCost(frames, res),
      [&](Eigen::MatrixXd* h, Eigen::VectorXd* g) { NormalEquations(frames, res, pose_free, h, g); },
      [&](const Eigen::VectorXd& step) {
        next = *s;
        next.t = Increment(step.head<kSim>(), pivot).Compose(s->t);
        for (size_t f = 0; f < frames.size(); ++f) {
          next.gain[f] += step(kSim + 2 * int(f));
          next.bias[f] += step(kSim + 2 * int(f) + 1);
        }
        cand = EvaluateAll(frames, next, pivot, true);
        return TotalCost(frames, cand);
      },
      [&] {
        *s = std::move(next);
        res = std::move(cand);
      });
  return cost.mean;
}

// The used frames at one level: keyframes rendered where `t` puts them.
// Frames with fewer than `min_pixels` keyframe pixels are left out.
absl::StatusOr<std::vector<FrameLevel>> BuildLevel(const PlaceMap& map, const Scene& scene,
                                                   const std::vector<int>& picked, const Similarity& t, int level,
                                                   int min_pixels, const SimilarityRefineOptions& o,
                                                   const std::function<void()>& rendered,
                                                   const std::atomic<bool>* cancel) {
  std::vector<FrameLevel> frames;
  for (int i : picked) {
    if (cancel != nullptr && cancel->load()) return absl::CancelledError("similarity refinement cancelled");
    const View& v = scene.train[size_t(i)];
    const double shrink = std::min(1.0, double(o.alignment.max_side) / std::max(v.image.width, v.image.height));
    const int w = std::max(8, int(std::lround(v.image.width * shrink)) >> level);
    const int h = std::max(8, int(std::lround(v.image.height * shrink)) >> level);
    Camera c = AtSize(v.camera, w, h);
    c.c2w = t.ApplyToPose(v.camera.c2w);
    absl::StatusOr<Keyframe> k = RenderKeyframe(map, c, o.alignment.min_opacity, o.alignment.min_gradient);
    if (!k.ok()) return k.status();
    if (rendered) rendered();
    if (int(k->points.size()) < min_pixels) continue;
    frames.push_back(FrameLevel{v.camera.c2w, c.intrinsics, *std::move(k), GreyImage(ResizeImage(v.image, w, h))});
  }
  return frames;
}

// Each frame's Huber scale from its residuals after an exposure-only fit.
void SetScales(const Eigen::Vector3d& pivot, double huber_k, std::vector<FrameLevel>* frames, State* s) {
  for (FrameLevel& f : *frames) f.delta = 1.0;  // Least squares for the exposure's first fit.
  s->gain.assign(frames->size(), 1.0);
  s->bias.assign(frames->size(), 0.0);
  Solve(*frames, pivot, 8, false, s);
  const std::vector<FrameResiduals> res = EvaluateAll(*frames, *s, pivot, false);
  for (size_t f = 0; f < frames->size(); ++f) (*frames)[f].delta = huber_k * RobustSigma(res[f].r);
}

// The finest level: the scan where registration put it and where the
// solver moves it, scored against the same keyframes, each with its own
// exposure fit; fills the costs, frames and pixels of `out`.
void FinestLevel(const std::vector<FrameLevel>& frames, const Eigen::Vector3d& pivot,
                 const SimilarityRefineOptions& o, State* s, SimilarityRefinement* out) {
  State before;
  before.gain.assign(frames.size(), 1.0);
  before.bias.assign(frames.size(), 0.0);
  out->cost_before = Solve(frames, pivot, 4 * o.alignment.iterations, false, &before);
  // The fine level starts from the coarse levels' result and, in case a
  // blurry map's coarse optimum lies elsewhere, from where registration
  // put the scan; the lower cost wins.
  State from_start = before;
  Solve(frames, pivot, o.alignment.iterations, true, s);
  Solve(frames, pivot, o.alignment.iterations, true, &from_start);
  out->cost_after = Solve(frames, pivot, 4 * o.alignment.iterations, false, s);
  const double cost_from_start = Solve(frames, pivot, 4 * o.alignment.iterations, false, &from_start);
  if (cost_from_start < out->cost_after) {
    *s = std::move(from_start);
    out->cost_after = cost_from_start;
  }
  out->frames = int(frames.size());
  for (const FrameLevel& f : frames) out->pixels += int(f.key.points.size());
}

double FarthestMove(const Scene& scene, const std::vector<int>& picked, const Similarity& t) {
  double worst = 0;
  for (int i : picked) {
    const Eigen::Vector3d c = scene.train[size_t(i)].camera.c2w.col(3).cast<double>();
    worst = std::max(worst, (t.Apply(c) - c).norm());
  }
  return worst;
}

// Accepts or refuses `r->correction` against the limits and the cost.
void Judge(const SimilarityRefineOptions& o, SimilarityRefinement* r) {
  if (!(r->cost_after < r->cost_before * (1 - o.alignment.min_improvement))) {
    r->why = absl::StrFormat("no better: robust cost %.4g -> %.4g", r->cost_before, r->cost_after);
  } else if (r->rotation_deg > o.alignment.max_rotation_deg || r->max_centre > o.alignment.max_centre) {
    r->why = absl::StrFormat("moved too far (%.2f deg, a camera %.2f%% of the place)", r->rotation_deg,
                             100 * r->max_centre);
  } else {
    r->accepted = true;
    return;
  }
  r->correction = Similarity();
}

}  // namespace

absl::StatusOr<SimilarityRefinement> RefineSimilarityPhotometric(const PlaceMap& map, const Scene& scene,
                                                                 double extent, const SimilarityRefineOptions& o,
                                                                 const SimilarityRefineProgressFn& progress,
                                                                 const std::atomic<bool>* cancel) {
  if (absl::Status s = o.Validate(); !s.ok()) return s;
  for (const View& v : scene.train) {
    if (v.image.width != v.camera.intrinsics.width || v.image.height != v.camera.intrinsics.height ||
        v.image.empty()) {
      return absl::InvalidArgumentError(absl::StrFormat("photo %s is %dx%d but its camera %dx%d", v.name,
                                                        v.image.width, v.image.height, v.camera.intrinsics.width,
                                                        v.camera.intrinsics.height));
    }
  }
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Camera> cams;
  for (const View& v : scene.train) cams.push_back(v.camera);
  const std::vector<int> picked = SpreadCameras(cams, o.max_frames);
  Eigen::Vector3d pivot = Eigen::Vector3d::Zero();
  for (int i : picked) pivot += cams[size_t(i)].c2w.col(3).cast<double>();
  pivot /= std::max<size_t>(picked.size(), 1);
  int renders = 0;
  const int total = int(picked.size()) * o.alignment.levels;
  auto rendered = [&] {
    if (progress) progress(++renders, total);
  };
  State s;
  SimilarityRefinement out;
  for (int level = o.alignment.levels - 1; level >= 0; --level) {
    const int min_pixels = level == 0 ? o.alignment.min_pixels : o.alignment.min_pixels / 4;
    absl::StatusOr<std::vector<FrameLevel>> frames =
        BuildLevel(map, scene, picked, s.t, level, min_pixels, o, rendered, cancel);
    if (!frames.ok()) return frames.status();
    if (int(frames->size()) < o.min_frames) {
      if (level > 0) continue;
      out.why = absl::StrCat("only ", frames->size(), " frames show enough solid, textured pixels (", o.min_frames,
                             " needed)");
      out.seconds = SecondsSince(t0);
      return out;
    }
    SetScales(pivot, o.alignment.huber_k, &*frames, &s);
    if (level > 0) {
      Solve(*frames, pivot, o.alignment.iterations, true, &s);
      continue;
    }
    FinestLevel(*frames, pivot, o, &s, &out);
  }
  out.correction = s.t;
  out.rotation_deg = s.t.RotationDegrees();
  out.scale = s.t.scale;
  out.max_centre = FarthestMove(scene, picked, s.t) / std::max(extent, 1e-12);
  Judge(o, &out);
  out.seconds = SecondsSince(t0);
  return out;
}

}  // namespace clnerf
