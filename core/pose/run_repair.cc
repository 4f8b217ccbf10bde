#include "core/pose/run_repair.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "Eigen/Dense"

namespace clnerf {

absl::Status RunRepairOptions::Validate() const {
  if (!(max_spread_deg > 0 && max_spread_deg < 180)) {
    return absl::InvalidArgumentError("run repair: max_spread_deg must be in (0, 180)");
  }
  if (min_pairs < 2) return absl::InvalidArgumentError("run repair: min_pairs must be >= 2");
  return absl::OkStatus();
}

namespace {

// A pair that crosses between the runs, in world terms: the disputed
// frame's rotation as the photos give it, turned from its given one
// (`turn`), and the ray from its partner's centre on which its true centre
// lies.
struct Crossing {
  Eigen::Matrix3d turn;
  Eigen::Vector3d partner_centre, direction, given_centre;
};

std::vector<Crossing> Crossings(const PoseCheckReport& report, const std::vector<View>& views) {
  std::vector<bool> disputed(views.size(), false);
  for (int i : report.disputed) disputed[i] = true;
  std::vector<Crossing> out;
  for (const PairCheck& p : report.pairs) {
    if (disputed[p.a] == disputed[p.b]) continue;
    const bool a_kept = !disputed[p.a];
    const Camera& kept = views[a_kept ? p.a : p.b].camera;
    const Camera& moved = views[a_kept ? p.b : p.a].camera;
    const Eigen::Matrix3d rk = kept.c2w.leftCols<3>().cast<double>();
    const Eigen::Matrix3d rm = moved.c2w.leftCols<3>().cast<double>();
    // x_b = R x_a + t: b's centre is -R^T t in a's coordinates, a's is t in b's.
    const Eigen::Matrix3d truth = a_kept ? Eigen::Matrix3d(rk * p.rotation.transpose()) : Eigen::Matrix3d(rk * p.rotation);
    Crossing c;
    c.turn = truth * rm.transpose();
    c.direction = (a_kept ? Eigen::Vector3d(rk * (-p.rotation.transpose() * p.baseline)) : Eigen::Vector3d(rk * p.baseline))
                      .normalized();
    c.partner_centre = kept.position().cast<double>();
    c.given_centre = moved.position().cast<double>();
    out.push_back(c);
  }
  return out;
}

// The largest set of crossings whose turns lie within `spread` of one of
// theirs; returns their indices.
std::vector<int> Consensus(const std::vector<Crossing>& cs, double spread) {
  std::vector<int> best;
  for (size_t k = 0; k < cs.size(); ++k) {
    std::vector<int> near;
    for (size_t m = 0; m < cs.size(); ++m) {
      if (RotationAngleDegrees(cs[k].turn, cs[m].turn) <= spread) near.push_back(int(m));
    }
    if (near.size() > best.size()) best = near;
  }
  return best;
}

// The rotation nearest (chordally) to the mean of `rs`.
Eigen::Matrix3d MeanRotation(const std::vector<Eigen::Matrix3d>& rs) {
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  for (const Eigen::Matrix3d& r : rs) sum += r;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

}  // namespace

absl::StatusOr<RunRepair> SolveRunRepair(const PoseCheckReport& report, const std::vector<View>& views,
                                         const RunRepairOptions& o) {
  if (absl::Status s = o.Validate(); !s.ok()) return s;
  if (report.disputed.empty()) return absl::FailedPreconditionError("run repair: no frame is disputed");
  const std::vector<Crossing> cs = Crossings(report, views);
  RunRepair r;
  r.crossing_pairs = int(cs.size());
  const std::vector<int> used = Consensus(cs, o.max_spread_deg);
  r.pairs_used = int(used.size());
  if (r.pairs_used < o.min_pairs) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "run repair: %d of %d pairs across the runs agree on one turn (%d needed)", r.pairs_used, r.crossing_pairs,
        o.min_pairs));
  }
  std::vector<Eigen::Matrix3d> turns;
  for (int k : used) turns.push_back(cs[k].turn);
  r.transform.rotation = MeanRotation(turns);
  std::vector<double> spread;
  for (const Eigen::Matrix3d& t : turns) spread.push_back(RotationAngleDegrees(r.transform.rotation, t));
  std::nth_element(spread.begin(), spread.begin() + spread.size() / 2, spread.end());
  r.rotation_spread_deg = spread[spread.size() / 2];
  // scale * R c_given + t - mu_k d_k = c_partner, for (scale,) t and each
  // mu_k; rigid: scale 1, its column moved to the right-hand side.
  const int n = int(used.size()), s0 = o.rigid ? 0 : 1;
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(3 * n, s0 + 3 + n);
  Eigen::VectorXd b(3 * n);
  for (int k = 0; k < n; ++k) {
    const Crossing& c = cs[used[k]];
    const Eigen::Vector3d turned = r.transform.rotation * c.given_centre;
    if (!o.rigid) a.block<3, 1>(3 * k, 0) = turned;
    a.block<3, 3>(3 * k, s0) = Eigen::Matrix3d::Identity();
    a.block<3, 1>(3 * k, s0 + 3 + k) = -c.direction;
    b.segment<3>(3 * k) = c.partner_centre - (o.rigid ? turned : Eigen::Vector3d::Zero());
  }
  const Eigen::VectorXd x = a.colPivHouseholderQr().solve(b);
  r.transform.scale = o.rigid ? 1.0 : x(0);
  r.transform.translation = x.segment<3>(s0);
  r.centre_residual = std::sqrt((a * x - b).squaredNorm() / double(n));
  r.turn_deg = r.transform.RotationDegrees();
  if (!(r.transform.scale > 0) || !std::isfinite(r.centre_residual)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("run repair: degenerate solution (scale %.3f)", r.transform.scale));
  }
  return r;
}

void ApplyRunRepair(const RunRepair& repair, const std::set<std::string>& names, Scene* scene) {
  for (std::vector<View>* split : {&scene->train, &scene->val, &scene->test}) {
    for (View& v : *split) {
      if (!names.count(v.name)) continue;
      v.camera.c2w = repair.transform.ApplyToPose(v.camera.c2w);
      for (DepthPoint& d : v.depth) d.world = repair.transform.Apply(d.world);
    }
  }
}

std::string RunRepair::Summary() const {
  return absl::StrFormat(
      "turned %.1f deg, scale %.3f, from %d of %d pairs across the runs (their rotations within %.1f deg of it, "
      "median); centres off their rays by %.3f (RMS)",
      turn_deg, transform.scale, pairs_used, crossing_pairs, rotation_spread_deg, centre_residual);
}

}  // namespace clnerf
