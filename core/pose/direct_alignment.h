// Direct image alignment's shared parts (photometric_refine.h aligns one
// camera, photometric_similarity.h a whole scan's similarity): a grey photo
// with its gradients, the place map's render lifted into a keyframe of 3-D
// points with grey values, projection with its Jacobian, and the robust
// (Huber) cost at a scale from the residuals' median absolute deviation, and
// the Levenberg-Marquardt loop both solvers run.
//
// Thread-safety: plain values and pure functions; RenderKeyframe renders the
// map with the calling context's threads.
#ifndef CLNERF_CORE_POSE_DIRECT_ALIGNMENT_H_
#define CLNERF_CORE_POSE_DIRECT_ALIGNMENT_H_

#include <algorithm>
#include <limits>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/pose/place_map.h"
#include "Eigen/Core"
#include "Eigen/Dense"

namespace clnerf {

// A grey image with its central-difference gradients, sampled bilinearly at
// continuous pixel coordinates (pixel centres at +0.5).
struct GreyImage {
  int w = 0, h = 0;
  std::vector<float> v, gx, gy;
  explicit GreyImage(const Image& im);
  // False when (u, v) is too close to the border to interpolate.
  bool Sample(double u, double vv, float* value, float* dx, float* dy) const {
    const double x = u - 0.5, y = vv - 0.5;
    if (!(x >= 0 && y >= 0 && x < w - 1 && y < h - 1)) return false;
    const int x0 = int(x), y0 = int(y);
    const float fx = float(x - x0), fy = float(y - y0);
    auto lerp = [&](const std::vector<float>& a) {
      const size_t i = size_t(y0) * w + x0;
      const float top = a[i] * (1 - fx) + a[i + 1] * fx;
      const float bot = a[i + w] * (1 - fx) + a[i + w + 1] * fx;
      return top * (1 - fy) + bot * fy;
    };
    *value = lerp(v);
    *dx = lerp(gx);
    *dy = lerp(gy);
    return true;
  }
};

// The map's solid, textured pixels lifted into the world, with their grey
// values: the keyframe a photo is aligned to.
struct Keyframe {
  std::vector<Eigen::Vector3d> points;
  std::vector<float> grey;
};

// The map rendered at `camera`; pixels kept where the opacity is at least
// `min_opacity` and the render's grey gradient at least `min_gradient`.
absl::StatusOr<Keyframe> RenderKeyframe(const PlaceMap& map, const Camera& camera, float min_opacity,
                                        float min_gradient);

// World-to-camera rigid transform in doubles.
struct W2C {
  Eigen::Matrix3d r;
  Eigen::Vector3d t;
  static W2C FromPose(const Pose& c2w);
  Pose ToPose() const;
  // exp(xi) * this, xi = (rotation vector, translation), small.
  W2C Moved(const Eigen::Matrix<double, 6, 1>& xi) const;
};

// Projects a camera-space point; false when behind the camera. `jac`
// (2 x 3): d(pixel) / d(camera-space point).
bool Project(const Intrinsics& in, const Eigen::Vector3d& xc, Eigen::Vector2d* px, Eigen::Matrix<double, 2, 3>* jac);

// Robust scale: 1.4826 x the median absolute finite residual (floored at 1e-3).
double RobustSigma(const std::vector<double>& r);

// Mean Huber cost at threshold `delta` over the finite residuals (inf when none).
double HuberCost(const std::vector<double>& r, double delta);

// The same camera at another image size.
Camera AtSize(const Camera& c, int w, int h);

// A state's mean robust cost and how many residuals it could use.
struct AlignmentCost {
  double mean = std::numeric_limits<double>::infinity();
  int used = 0;
};

// Pins the first `n` unknowns of the normal equations (h, g): their step is 0.
void PinLeading(int n, Eigen::MatrixXd* h, Eigen::VectorXd* g);

// Levenberg-Marquardt's loop, shared by the one-camera (photometric_refine.h)
// and the whole-scan (photometric_similarity.h) alignment, from the state
// whose cost is `current`. Per iteration: `normal(&h, &g)` builds the normal
// equations at the current state; up to 6 damped steps are tried, each by
// `trial(step)`, which evaluates the current state moved by `step`, keeps it
// as the candidate and returns its cost; `accept()` makes the candidate
// current. A candidate is taken when its cost falls and it keeps >= 95 % of
// the used residuals (fewer usable points would fake a lower cost). Stops
// when no step helps. Returns the final state's cost.
template <class Normal, class Trial, class Accept>
AlignmentCost LevenbergMarquardt(int iterations, AlignmentCost current, Normal normal, Trial trial,
                                 Accept accept) {
  double lambda = 1e-3;
  Eigen::MatrixXd h;
  Eigen::VectorXd g;
  for (int it = 0; it < iterations; ++it) {
    normal(&h, &g);
    bool improved = false;
    for (int tries = 0; tries < 6 && !improved; ++tries) {
      Eigen::MatrixXd damped = h;
      damped.diagonal() += lambda * h.diagonal().cwiseMax(1e-9);
      const Eigen::VectorXd step = -damped.ldlt().solve(g);
      if (!step.allFinite()) break;
      const AlignmentCost c = trial(step);
      if (c.mean < current.mean && c.used >= current.used * 0.95) {
        accept();
        current = c;
        lambda = std::max(lambda * 0.5, 1e-6);
        improved = true;
      } else {
        lambda *= 4;
      }
    }
    if (!improved) break;
  }
  return current;
}

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_DIRECT_ALIGNMENT_H_
