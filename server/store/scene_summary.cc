#include "server/store/scene_summary.h"

#include <algorithm>

#include "Eigen/Eigenvalues"

namespace clnerf {

SceneSummary Summarize(const Servable& servable) {
  SceneSummary s;
  const NgpModel& model = servable.model();
  const ReplayMemory& memory = servable.memory();
  s.version = servable.info.version;
  s.time_steps = model.num_time_steps();
  s.bounded = model.kind() == SceneKind::kBounded;
  const Normalization& norm = model.normalization();
  s.focus = norm.center;
  s.radius = norm.bound / std::max(norm.scale, 1e-12f) * 2;
  s.cameras = memory.num_cameras();
  if (memory.num_cameras() == 0) return s;

  std::vector<Camera> cams;
  cams.reserve(memory.num_cameras());
  for (uint32_t i = 0; i < memory.num_cameras(); ++i) cams.push_back(memory.GetCamera(i));
  Eigen::Vector3f up = Eigen::Vector3f::Zero();
  // Least squares point nearest every optical axis: sum (I - d d^T) p = sum (I - d d^T) c.
  Eigen::Matrix3f a = Eigen::Matrix3f::Zero();
  Eigen::Vector3f b = Eigen::Vector3f::Zero();
  for (const Camera& c : cams) {
    up -= c.c2w.col(1);  // OpenCV: y points down in the image.
    const Eigen::Vector3f d = c.c2w.col(2).normalized();
    const Eigen::Matrix3f m = Eigen::Matrix3f::Identity() - d * d.transpose();
    a += m;
    b += m * c.position();
  }
  if (up.norm() > 1e-6f) s.up = up.normalized();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3f> eig(a / float(cams.size()));
  // Near-parallel axes (a forward-facing rig) leave the point unconstrained
  // along them: keep the box centre then.
  if (eig.eigenvalues().minCoeff() > 0.02f) {
    const Eigen::Vector3f p = a.ldlt().solve(b);
    if (p.allFinite()) s.focus = p;
  }
  std::vector<float> dist;
  for (const Camera& c : cams) dist.push_back((c.position() - s.focus).norm());
  std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
  if (dist[dist.size() / 2] > 0) s.radius = dist[dist.size() / 2];

  s.scan_cameras.resize(size_t(s.time_steps));
  std::vector<bool> seen(size_t(s.time_steps), false);
  for (const Camera& c : cams) {
    if (c.time_step < 0 || c.time_step >= s.time_steps || seen[size_t(c.time_step)]) continue;
    seen[size_t(c.time_step)] = true;
    s.scan_cameras[size_t(c.time_step)] = c;
  }
  // A time step without a recorded camera (not expected) borrows the nearest earlier one.
  for (size_t t = 0; t < seen.size(); ++t) {
    if (!seen[t]) s.scan_cameras[t] = t > 0 ? s.scan_cameras[t - 1] : cams.front();
    s.scan_cameras[t].time_step = int(t);
  }
  s.default_camera = s.scan_cameras.empty() ? cams.back() : s.scan_cameras.back();
  return s;
}

}  // namespace clnerf
