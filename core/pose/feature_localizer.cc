#include "core/pose/feature_localizer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "absl/strings/str_cat.h"
#include "core/data/image.h"
#include "core/pose/sift_features.h"
#include "Eigen/Eigenvalues"
#include "Eigen/Geometry"
#include "Eigen/LU"
#include "opencv2/calib3d.hpp"
#include "opencv2/core.hpp"
#include "opencv2/features2d.hpp"
#include "opencv2/imgproc.hpp"

namespace clnerf {

namespace {

// The render's distance at keypoint `p` (OpenCV pixel coordinates: pixel i's
// centre at i), interpolated bilinearly, if the surface around it is solid
// and smooth.
bool SolidDepth(const MapView& v, const cv::Point2f& p, const LocalizerOptions& o, float* depth) {
  const int w = v.camera.intrinsics.width, h = v.camera.intrinsics.height;
  const int x0 = int(std::floor(p.x)), y0 = int(std::floor(p.y));
  if (x0 < 1 || y0 < 1 || x0 + 2 >= w || y0 + 2 >= h) return false;
  const float fx = p.x - x0, fy = p.y - y0;
  auto at = [&](int x, int y) { return v.depth[size_t(y) * w + x]; };
  const float d = (1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x0 + 1, y0)) +
                  fy * ((1 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1));
  if (!(d > 0) || !std::isfinite(d)) return false;
  for (int y = y0 - 1; y <= y0 + 2; ++y) {
    for (int x = x0 - 1; x <= x0 + 2; ++x) {
      if (v.opacity[size_t(y) * w + x] < o.min_opacity) return false;
      if (!(std::abs(at(x, y) - d) <= o.max_depth_jump * d)) return false;
    }
  }
  *depth = d;
  return true;
}

}  // namespace

absl::Status LocalizerOptions::Validate() const {
  if (max_side < 32) return absl::InvalidArgumentError("localizer max_side must be >= 32");
  if (min_side < 1 || min_side > max_side) return absl::InvalidArgumentError("localizer min_side must be in [1, max_side]");
  if (max_features < 50) return absl::InvalidArgumentError("localizer max_features must be >= 50");
  if (!(ratio > 0 && ratio <= 1)) return absl::InvalidArgumentError("localizer ratio must be in (0, 1]");
  if (!(min_opacity >= 0 && min_opacity <= 1)) return absl::InvalidArgumentError("min_opacity must be in [0, 1]");
  if (!(max_depth_jump > 0)) return absl::InvalidArgumentError("max_depth_jump must be > 0");
  if (references_per_frame < 1) return absl::InvalidArgumentError("references_per_frame must be >= 1");
  if (!(reprojection_px > 0)) return absl::InvalidArgumentError("reprojection_px must be > 0");
  if (ransac_iterations < 10) return absl::InvalidArgumentError("ransac_iterations must be >= 10");
  if (min_inliers < 6) return absl::InvalidArgumentError("min_inliers must be >= 6");
  if (weak_min_inliers < 6) return absl::InvalidArgumentError("weak_min_inliers must be >= 6");
  return absl::OkStatus();
}

struct FeatureLocalizer::Impl {
  LocalizerOptions options;
  struct Reference {
    cv::Mat descriptors;                  // Only of keypoints with a 3-D point.
    std::vector<cv::Point3f> points;      // Row i of descriptors.
  };
  std::vector<Reference> refs;
  int num_points = 0;
};

FeatureLocalizer::FeatureLocalizer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
FeatureLocalizer::~FeatureLocalizer() = default;

int FeatureLocalizer::num_points() const { return impl_->num_points; }

absl::StatusOr<std::unique_ptr<FeatureLocalizer>> FeatureLocalizer::Build(const std::vector<MapView>& renders,
                                                                           const LocalizerOptions& options) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  cv::setNumThreads(1);  // Callers parallelise over frames.
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->refs.resize(renders.size());
  for (const MapView& v : renders) {
    const size_t n = size_t(v.camera.intrinsics.width) * v.camera.intrinsics.height;
    if (v.rgb.width != v.camera.intrinsics.width || v.rgb.height != v.camera.intrinsics.height ||
        v.depth.size() != n || v.opacity.size() != n) {
      return absl::InvalidArgumentError("FeatureLocalizer: a render's buffers do not match its camera");
    }
  }
#pragma omp parallel for schedule(dynamic, 1)
  for (int r = 0; r < int(renders.size()); ++r) {
    const MapView& v = renders[r];
    Features f = Detect(ToGray(v.rgb), options.max_features);
    Impl::Reference& ref = impl->refs[r];
    std::vector<int> rows;
    for (int k = 0; k < int(f.keypoints.size()); ++k) {
      const cv::Point2f& p = f.keypoints[k].pt;
      float d = 0;
      if (!SolidDepth(v, p, options, &d)) continue;
      Eigen::Vector3f o, dir;
      v.camera.Ray(p.x + 0.5f, p.y + 0.5f, &o, &dir);
      const Eigen::Vector3f x = o + dir * d;
      ref.points.emplace_back(x.x(), x.y(), x.z());
      rows.push_back(k);
    }
    ref.descriptors = cv::Mat(int(rows.size()), f.descriptors.cols, CV_32F);
    for (int i = 0; i < int(rows.size()); ++i) f.descriptors.row(rows[i]).copyTo(ref.descriptors.row(i));
  }
  for (const auto& r : impl->refs) impl->num_points += int(r.points.size());
  return std::unique_ptr<FeatureLocalizer>(new FeatureLocalizer(std::move(impl)));
}

namespace {

// OpenCV's world-to-camera rotation vector and translation as a
// camera-to-world pose (OpenCV convention).
Pose CameraToWorld(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat rm;
  cv::Rodrigues(rvec, rm);
  Eigen::Matrix3d r;
  Eigen::Vector3d t;
  for (int i = 0; i < 3; ++i) {
    t(i) = tvec.at<double>(i);
    for (int j = 0; j < 3; ++j) r(i, j) = rm.at<double>(i, j);
  }
  Pose c2w;
  c2w.leftCols<3>() = r.transpose().cast<float>();
  c2w.col(3) = (-r.transpose() * t).cast<float>();
  return c2w;
}

// Sum of squared reprojection errors of `object` against `image` at pose
// (rvec, tvec) under camera (k, dist), in the units of `image`.
double SquaredReprojection(const std::vector<cv::Point3f>& object, const std::vector<cv::Point2f>& image,
                           const cv::Mat& rvec, const cv::Mat& tvec, cv::InputArray k, cv::InputArray dist) {
  std::vector<cv::Point2f> proj;
  cv::projectPoints(object, rvec, tvec, k, dist, proj);
  double sq = 0;
  for (size_t i = 0; i < proj.size(); ++i) {
    const cv::Point2f e = proj[i] - image[i];
    sq += double(e.x) * e.x + double(e.y) * e.y;
  }
  return sq;
}

// `object` in the camera's frame at pose (rvec, tvec).
std::vector<Eigen::Vector3d> InCamera(const std::vector<cv::Point3f>& object, const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat rm;
  cv::Rodrigues(rvec, rm);
  Eigen::Matrix3d r;
  Eigen::Vector3d t;
  for (int i = 0; i < 3; ++i) {
    t(i) = tvec.at<double>(i);
    for (int j = 0; j < 3; ++j) r(i, j) = rm.at<double>(i, j);
  }
  std::vector<Eigen::Vector3d> out;
  out.reserve(object.size());
  for (const cv::Point3f& p : object) out.push_back(r * Eigen::Vector3d(p.x, p.y, p.z) + t);
  return out;
}

}  // namespace

Eigen::Matrix3d PnPRotationCovariance(const std::vector<Eigen::Vector3d>& points, double squared_error) {
  Eigen::Matrix<double, 6, 6> jtj = Eigen::Matrix<double, 6, 6>::Zero();
  int used = 0;
  for (const Eigen::Vector3d& x : points) {
    if (x.z() <= 1e-9) continue;
    ++used;
    Eigen::Matrix<double, 2, 3> dp;  // d(x/z, y/z) / dx
    dp << 1 / x.z(), 0, -x.x() / (x.z() * x.z()), 0, 1 / x.z(), -x.y() / (x.z() * x.z());
    Eigen::Matrix<double, 3, 6> dx;  // dx / d(omega, delta t) for x' = exp(omega) x + delta t
    dx.leftCols<3>() << 0, x.z(), -x.y(), -x.z(), 0, x.x(), x.y(), -x.x(), 0;
    dx.rightCols<3>().setIdentity();
    const Eigen::Matrix<double, 2, 6> j = dp * dx;
    jtj += j.transpose() * j;
  }
  const double inf = std::numeric_limits<double>::infinity();
  Eigen::FullPivLU<Eigen::Matrix<double, 6, 6>> lu(jtj);
  if (used < 3 || !lu.isInvertible()) return Eigen::Matrix3d::Identity() * inf;
  const double dof = std::max(1.0, 2.0 * used - 6.0);
  return (squared_error / dof) * lu.inverse().topLeftCorner<3, 3>();
}

double RotationStdDeg(const Eigen::Matrix3d& covariance) {
  if (!covariance.allFinite()) return std::numeric_limits<double>::infinity();
  const double worst = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(covariance).eigenvalues().maxCoeff();
  return std::sqrt(std::max(0.0, worst)) * 180.0 / M_PI;
}

FrameLocalization FeatureLocalizer::Localize(const Image& image, const Camera& camera) const {
  const LocalizerOptions& o = impl_->options;
  FrameLocalization out;
  const Camera cam = CameraWithSideIn(camera, o.min_side, o.max_side);
  const cv::Mat gray = ResizedGray(ToGray(image), cam.intrinsics.width, cam.intrinsics.height);
  const Features q = Detect(gray, o.max_features);
  if (q.descriptors.empty()) return out;
  // Ratio-test matches against every render; keep the best renders'.
  std::vector<std::vector<cv::DMatch>> good(impl_->refs.size());
  for (size_t r = 0; r < impl_->refs.size(); ++r) good[r] = RatioMatches(q.descriptors, impl_->refs[r].descriptors, o.ratio);
  std::vector<int> order(impl_->refs.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = int(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return good[a].size() > good[b].size(); });
  // One correspondence per photo keypoint: the closest descriptor.
  std::map<int, std::pair<float, cv::Point3f>> by_query;
  for (int k = 0; k < std::min<int>(o.references_per_frame, int(order.size())); ++k) {
    const int r = order[k];
    for (const cv::DMatch& m : good[r]) {
      auto it = by_query.find(m.queryIdx);
      if (it == by_query.end() || m.distance < it->second.first) {
        by_query[m.queryIdx] = {m.distance, impl_->refs[r].points[m.trainIdx]};
      }
    }
  }
  out.matches = int(by_query.size());
  const int weak = std::min(o.weak_min_inliers, o.min_inliers);
  if (out.matches < weak) return out;
  std::vector<cv::Point3f> object;
  std::vector<cv::Point2f> normalised, pixels;
  for (const auto& [qi, m] : by_query) {
    const cv::Point2f& p = q.keypoints[qi].pt;
    pixels.push_back(p);
    const Eigen::Vector3f d = cam.CameraDirection(p.x + 0.5f, p.y + 0.5f);
    object.push_back(m.second);
    normalised.emplace_back(d.x() / d.z(), d.y() / d.z());
  }
  const double f = 0.5 * (cam.intrinsics.fx + cam.intrinsics.fy);
  const cv::Mat k = cv::Mat::eye(3, 3, CV_64F);
  cv::Mat rvec, tvec;
  std::vector<int> inliers;
  const bool ok = cv::solvePnPRansac(object, normalised, k, cv::noArray(), rvec, tvec, false, o.ransac_iterations,
                                     float(o.reprojection_px / f), 0.999, inliers, cv::SOLVEPNP_EPNP);
  if (!ok || int(inliers.size()) < weak) {
    out.inliers = int(inliers.size());
    return out;
  }
  std::vector<cv::Point3f> obj_in;
  std::vector<cv::Point2f> img_in;
  for (int i : inliers) {
    obj_in.push_back(object[i]);
    img_in.push_back(normalised[i]);
  }
  cv::solvePnPRefineLM(obj_in, img_in, k, cv::noArray(), rvec, tvec);
  const double sq = SquaredReprojection(obj_in, img_in, rvec, tvec, k, cv::noArray());
  out.c2w = CameraToWorld(rvec, tvec);
  out.inliers = int(inliers.size());
  out.reprojection_px = std::sqrt(sq / double(std::max<size_t>(1, img_in.size()))) * f;
  out.rotation_std_deg = RotationStdDeg(PnPRotationCovariance(InCamera(obj_in, rvec, tvec), sq));
  const float sx = float(camera.intrinsics.width) / cam.intrinsics.width;
  const float sy = float(camera.intrinsics.height) / cam.intrinsics.height;
  for (int i : inliers) {
    out.inlier_points.emplace_back(object[i].x, object[i].y, object[i].z);
    out.inlier_pixels.emplace_back((pixels[i].x + 0.5f) * sx, (pixels[i].y + 0.5f) * sy);
  }
  const bool enough = out.inliers >= o.min_inliers;
  out.placed = enough && out.c2w.allFinite();
  out.weak = !enough && out.c2w.allFinite();
  return out;
}

namespace {

// Each frame's pose by Levenberg-Marquardt from `poses`, under camera (k,
// dist) (calibrateCamera's own per-view poses can flip); a pose is taken
// into `out` only if it stays within max_turn_deg of where it started.
// Returns the RMS reprojection error (pixels) over every correspondence at
// the poses LM found.
double PosesUnderCamera(const std::vector<std::vector<cv::Point3f>>& object,
                        const std::vector<std::vector<cv::Point2f>>& image, const std::vector<size_t>& which,
                        const cv::Mat& k, const cv::Mat& dist, const std::vector<Pose>& poses, double max_turn_deg,
                        std::vector<Pose>* out, std::vector<std::pair<double, double>>* frame_rms = nullptr) {
  double sq = 0;
  size_t n = 0;
  auto rms = [](double squared, size_t count) { return std::sqrt(squared / double(std::max<size_t>(1, count))); };
  if (frame_rms != nullptr) frame_rms->clear();
  for (size_t v = 0; v < which.size(); ++v) {
    const Pose& start = poses[which[v]];
    const Eigen::Matrix3d r0 = start.leftCols<3>().cast<double>().transpose();  // World -> camera.
    const Eigen::Vector3d t0 = -r0 * start.col(3).cast<double>();
    cv::Mat rm0(3, 3, CV_64F), rvec, tvec(3, 1, CV_64F);
    for (int i = 0; i < 3; ++i) {
      tvec.at<double>(i) = t0(i);
      for (int j = 0; j < 3; ++j) rm0.at<double>(i, j) = r0(i, j);
    }
    cv::Rodrigues(rm0, rvec);
    const size_t count = image[v].size();
    const double start_sq =
        frame_rms != nullptr ? SquaredReprojection(object[v], image[v], rvec, tvec, k, dist) : 0.0;
    cv::solvePnPRefineLM(object[v], image[v], k, dist, rvec, tvec);
    const double fitted_sq = SquaredReprojection(object[v], image[v], rvec, tvec, k, dist);
    if (frame_rms != nullptr) frame_rms->emplace_back(rms(start_sq, count), rms(fitted_sq, count));
    sq += fitted_sq;
    n += count;
    const Pose c2w = CameraToWorld(rvec, tvec);
    const Eigen::Matrix3d r = c2w.leftCols<3>().cast<double>().transpose();
    const double turn = Eigen::AngleAxisd(r * r0.transpose()).angle() * 180 / M_PI;
    if (c2w.allFinite() && turn < max_turn_deg) (*out)[which[v]] = c2w;
  }
  return rms(sq, n);
}

}  // namespace

absl::StatusOr<Intrinsics> RefineSharedCamera(const std::vector<FrameLocalization>& frames, const Intrinsics& guess,
                                             std::vector<Pose>* poses, SharedCameraReport* report,
                                             const SharedCameraOptions& options) {
  std::vector<std::vector<cv::Point3f>> object;
  std::vector<std::vector<cv::Point2f>> image;
  std::vector<size_t> which;
  for (size_t f = 0; f < frames.size(); ++f) {
    const FrameLocalization& l = frames[f];
    if (!l.placed || l.inlier_points.size() < 6 || f >= poses->size()) continue;
    object.emplace_back();
    image.emplace_back();
    for (size_t i = 0; i < l.inlier_points.size(); ++i) {
      const Eigen::Vector3f& P = l.inlier_points[i];
      const Eigen::Vector2f& p = l.inlier_pixels[i];
      object.back().emplace_back(P.x(), P.y(), P.z());
      image.back().emplace_back(p.x() - 0.5f, p.y() - 0.5f);  // OpenCV: pixel centres at integers.
    }
    which.push_back(f);
  }
  if (which.size() < 3) return absl::InvalidArgumentError("refining a shared camera needs 3 placed frames");
  const cv::Mat k0 = (cv::Mat_<double>(3, 3) << guess.fx, 0, guess.cx - 0.5, 0, guess.fy, guess.cy - 0.5, 0, 0, 1);
  const cv::Mat dist0 = (cv::Mat_<double>(1, 5) << guess.k1, guess.k2, guess.p1, guess.p2, 0);
  cv::Mat k = k0.clone(), dist = dist0.clone();
  std::vector<cv::Mat> rvecs, tvecs;
  const int flags = cv::CALIB_USE_INTRINSIC_GUESS | cv::CALIB_FIX_ASPECT_RATIO | cv::CALIB_FIX_PRINCIPAL_POINT |
                    cv::CALIB_ZERO_TANGENT_DIST | cv::CALIB_FIX_K2 | cv::CALIB_FIX_K3;
  try {
    cv::calibrateCamera(object, image, cv::Size(guess.width, guess.height), k, dist, rvecs, tvecs, flags);
  } catch (const cv::Exception& e) {
    return absl::FailedPreconditionError(absl::StrCat("shared camera refinement failed: ", e.what()));
  }
  Intrinsics out = guess;
  out.fx = float(k.at<double>(0, 0));
  out.fy = float(k.at<double>(1, 1));
  out.k1 = float(dist.at<double>(0));
  if (!std::isfinite(out.fx) || !std::isfinite(out.k1) || std::abs(out.fx / guess.fx - 1) > 0.2) {
    return absl::FailedPreconditionError("shared camera refinement diverged");
  }
  // The refined camera against the one it started from, each with every
  // frame's pose fitted under it: taken only if the place's points clearly
  // prefer it and it stays near (points lifted from a hazy map pull the
  // camera as much as a wrong focal length does).
  std::vector<Pose> at_guess = *poses, at_refined = *poses;
  SharedCameraReport rep;
  rep.rms_guess_px =
      PosesUnderCamera(object, image, which, k0, dist0, *poses, options.max_turn_deg, &at_guess, &rep.frame_rms);
  for (size_t f : which) rep.frames.push_back(int(f));
  rep.rms_refined_px = PosesUnderCamera(object, image, which, k, dist, *poses, options.max_turn_deg, &at_refined);
  rep.camera_taken = rep.rms_refined_px <= (1 - options.min_rms_gain) * rep.rms_guess_px &&
                     std::abs(out.fx / guess.fx - 1) <= options.max_focal_change &&
                     std::abs(out.k1 - guess.k1) <= options.max_k1_change;
  *poses = rep.camera_taken ? at_refined : at_guess;
  rep.rms_px = rep.camera_taken ? rep.rms_refined_px : rep.rms_guess_px;
  if (report != nullptr) *report = rep;
  return rep.camera_taken ? out : guess;
}

}  // namespace clnerf
