#include "core/train/camera_refiner.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_format.h"
#include "Eigen/Geometry"

namespace clnerf {
namespace {

constexpr double kPi = 3.14159265358979323846;

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

absl::Status CameraRefineOptions::Validate() const {
  if (!(learning_rate > 0) || !std::isfinite(learning_rate)) {
    return absl::InvalidArgumentError("camera refinement: learning_rate must be positive and finite");
  }
  if (!(max_rotation_deg > 0 && max_rotation_deg <= 90) || !(max_translation > 0) || !std::isfinite(max_translation)) {
    return absl::InvalidArgumentError(
        "camera refinement: max_rotation_deg must be in (0, 90] and max_translation positive and finite");
  }
  if (start_iteration < 0) return absl::InvalidArgumentError("camera refinement: start_iteration must be >= 0");
  return absl::OkStatus();
}

CameraRefiner::CameraRefiner(std::vector<Camera> cameras, std::vector<uint8_t> refine,
                             const CameraRefineOptions& options)
    : options_(options), base_(cameras), current_(std::move(cameras)), refine_(std::move(refine)) {
  refine_.resize(base_.size(), 0);
  clamped_.assign(base_.size(), 0);
  const Eigen::Matrix<double, 6, 1> zero = Eigen::Matrix<double, 6, 1>::Zero();
  param_.assign(base_.size(), zero);
  grad_.assign(base_.size(), zero);
  m_.assign(base_.size(), zero);
  v_.assign(base_.size(), zero);
}

int CameraRefiner::num_refined() const { return int(std::count(refine_.begin(), refine_.end(), uint8_t(1))); }

void CameraRefiner::ZeroGradients() {
  for (auto& g : grad_) g.setZero();
}

void CameraRefiner::AddRayGradient(int view, const Eigen::Vector3f& dir, const Eigen::Vector3f& d_origin,
                                   const Eigen::Vector3f& d_dir) {
  if (!Refines(view)) return;
  const Eigen::Vector3d d = dir.cast<double>(), gd = d_dir.cast<double>();
  grad_[size_t(view)].head<3>() += d.cross(gd);  // delta d = omega x d.
  grad_[size_t(view)].tail<3>() += d_origin.cast<double>();
}

bool CameraRefiner::Step(int step, float lr_scale) {
  for (size_t v = 0; v < grad_.size(); ++v) {
    if (refine_[v] && !grad_[v].allFinite()) return false;
  }
  // Adam with the trainer's betas (tiny-cuda-nn's 0.9 / 0.99).
  const double b1 = 0.9, b2 = 0.99, eps = 1e-12;
  const double c1 = 1.0 - std::pow(b1, std::max(step, 1)), c2 = 1.0 - std::pow(b2, std::max(step, 1));
  const double lr = double(options_.learning_rate) * double(lr_scale);
  const double max_turn = double(options_.max_rotation_deg) * kPi / 180.0;
  for (size_t v = 0; v < grad_.size(); ++v) {
    if (!refine_[v] || grad_[v].isZero(0)) continue;
    m_[v] = b1 * m_[v] + (1 - b1) * grad_[v];
    v_[v] = b2 * v_[v] + (1 - b2) * grad_[v].cwiseProduct(grad_[v]);
    const Eigen::Matrix<double, 6, 1> mh = m_[v] / c1, vh = v_[v] / c2;
    param_[v] -= lr * mh.cwiseQuotient((vh.cwiseSqrt().array() + eps).matrix());
    const double turn = param_[v].head<3>().norm(), shift = param_[v].tail<3>().norm();
    if (turn > max_turn) {
      param_[v].head<3>() *= max_turn / turn;
      clamped_[v] = 1;
    }
    if (shift > options_.max_translation) {
      param_[v].tail<3>() *= options_.max_translation / shift;
      clamped_[v] = 1;
    }
    Apply(int(v));
  }
  return true;
}

void CameraRefiner::Apply(int view) {
  const Eigen::Matrix<double, 6, 1>& p = param_[size_t(view)];
  const double angle = p.head<3>().norm();
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  if (angle > 0) R = Eigen::AngleAxisd(angle, p.head<3>() / angle).toRotationMatrix();
  const Camera& b = base_[size_t(view)];
  Camera& c = current_[size_t(view)];
  c.c2w.leftCols<3>() = (R * b.c2w.leftCols<3>().cast<double>()).cast<float>();
  c.c2w.col(3) = b.c2w.col(3) + p.tail<3>().cast<float>();
}

double CameraRefiner::rotation_deg(int view) const { return param_[size_t(view)].head<3>().norm() * 180.0 / kPi; }

double CameraRefiner::translation(int view) const { return param_[size_t(view)].tail<3>().norm(); }

int CameraRefiner::clamped() const { return int(std::count(clamped_.begin(), clamped_.end(), uint8_t(1))); }

CameraRefiner::Stats CameraRefiner::CorrectionStats() const {
  std::vector<double> turns, shifts;
  for (size_t v = 0; v < refine_.size(); ++v) {
    if (!refine_[v]) continue;
    turns.push_back(rotation_deg(int(v)));
    shifts.push_back(translation(int(v)));
  }
  Stats s;
  if (turns.empty()) return s;
  s.turn_median_deg = Median(turns);
  s.turn_max_deg = *std::max_element(turns.begin(), turns.end());
  s.shift_median = Median(shifts);
  s.shift_max = *std::max_element(shifts.begin(), shifts.end());
  return s;
}

std::string CameraRefiner::Summary() const {
  const Stats s = CorrectionStats();
  return absl::StrFormat("%d photos: median turn %.3f deg (max %.3f), median shift %.4f (max %.4f), %d clamped",
                         num_refined(), s.turn_median_deg, s.turn_max_deg, s.shift_median, s.shift_max, clamped());
}

}  // namespace clnerf
