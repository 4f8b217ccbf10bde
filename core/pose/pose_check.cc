#include "core/pose/pose_check.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/pose/place_map.h"
#include "core/pose/sift_features.h"
#include "core/pose/similarity.h"
#include "Eigen/Geometry"
#include "opencv2/calib3d.hpp"

namespace clnerf {

absl::Status PoseCheckOptions::Validate() const {
  if (max_side < 32) return absl::InvalidArgumentError("pose check: max_side must be >= 32");
  if (max_features < 8) return absl::InvalidArgumentError("pose check: max_features must be >= 8");
  if (!(ratio > 0 && ratio <= 1)) return absl::InvalidArgumentError("pose check: ratio must be in (0, 1]");
  if (sequence_neighbours < 1 || sequence_neighbours > 6) {
    return absl::InvalidArgumentError("pose check: sequence_neighbours must be in [1, 6]");
  }
  if (min_inliers < 8) return absl::InvalidArgumentError("pose check: min_inliers must be >= 8");
  if (!(ransac_px > 0)) return absl::InvalidArgumentError("pose check: ransac_px must be > 0");
  if (!(max_disagreement_deg > 0 && max_disagreement_deg < 180)) {
    return absl::InvalidArgumentError("pose check: max_disagreement_deg must be in (0, 180)");
  }
  if (estimator != "usac" && estimator != "ransac") {
    return absl::InvalidArgumentError(
        absl::StrCat("pose check: estimator must be 'ransac' or 'usac', not '", estimator, "'"));
  }
  if (!(min_chance_ratio >= 0)) return absl::InvalidArgumentError("pose check: min_chance_ratio must be >= 0");
  if (!(pose_px > 0)) return absl::InvalidArgumentError("pose check: pose_px must be > 0");
  if (!(min_explained_fraction >= 0 && min_explained_fraction <= 1)) {
    return absl::InvalidArgumentError("pose check: min_explained_fraction must be in [0, 1]");
  }
  if (!(max_conflict_fraction >= 0 && max_conflict_fraction <= 1)) {
    return absl::InvalidArgumentError("pose check: max_conflict_fraction must be in [0, 1]");
  }
  return absl::OkStatus();
}

namespace {

struct FrameFeatures {
  std::vector<cv::Point2f> normalised;  // Undistorted, z = 1 camera coordinates, per keypoint.
  cv::Mat descriptors;
  float focal = 1;                      // Pixels at the matching size.
};

FrameFeatures Extract(const View& view, const PoseCheckOptions& o) {
  FrameFeatures f;
  const Camera cam = CameraWithSideIn(view.camera, 1, o.max_side);
  const Intrinsics& in = cam.intrinsics;
  const Features s = Detect(ResizedGray(ToGray(view.image), in.width, in.height), o.max_features);
  f.descriptors = s.descriptors;
  f.focal = 0.5f * (in.fx + in.fy);
  if (s.keypoints.empty()) return f;
  std::vector<cv::Point2f> pixels;
  for (const cv::KeyPoint& k : s.keypoints) pixels.push_back(k.pt);
  // OpenCV's pixel i has its centre at i; ours at i + 0.5.
  const cv::Mat k = (cv::Mat_<double>(3, 3) << in.fx, 0, in.cx - 0.5, 0, in.fy, in.cy - 0.5, 0, 0, 1);
  const cv::Mat dist = (cv::Mat_<double>(1, 4) << in.k1, in.k2, in.p1, in.p2);
  cv::undistortPoints(pixels, f.normalised, k, dist);
  return f;
}

Eigen::Matrix3d ToEigen(const cv::Mat& m) {
  Eigen::Matrix3d r;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) r(i, j) = m.at<double>(i, j);
  }
  return r;
}

// The pairs to check: each frame with the next few in order.
std::vector<std::pair<int, int>> CandidatePairs(int n, const PoseCheckOptions& o) {
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i < n; ++i) {
    for (int d = 1; d <= o.sequence_neighbours && i + d < n; ++d) pairs.push_back({i, i + d});
  }
  return pairs;
}

// How many of the matches (normalised coordinates) the poses' epipolar
// geometry explains: Sampson distance within `tolerance` (normalised units),
// with E = [t]x R from camera a's coordinates to b's. All of them when the
// poses put both cameras at one centre (no epipolar geometry to test).
int ExplainedByPoses(const std::vector<cv::Point2f>& pa, const std::vector<cv::Point2f>& pb, const Camera& ca,
                     const Camera& cb, double tolerance) {
  const Eigen::Matrix3d ra = ca.c2w.leftCols<3>().cast<double>(), rb = cb.c2w.leftCols<3>().cast<double>();
  const Eigen::Vector3d t = rb.transpose() * (ca.c2w.col(3) - cb.c2w.col(3)).cast<double>();
  if (t.norm() < 1e-9) return int(pa.size());
  Eigen::Matrix3d tx;
  tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  const Eigen::Matrix3d e = tx * (rb.transpose() * ra) / t.norm();
  int explained = 0;
  for (size_t i = 0; i < pa.size(); ++i) {
    const Eigen::Vector3d xa(pa[i].x, pa[i].y, 1), xb(pb[i].x, pb[i].y, 1);
    const Eigen::Vector3d ea = e * xa, eb = e.transpose() * xb;
    const double r = xb.dot(ea), d = ea.head<2>().squaredNorm() + eb.head<2>().squaredNorm();
    explained += d > 0 && r * r <= tolerance * tolerance * d;
  }
  return explained;
}

// The essential matrix from a to b of normalised points (K = I), with the
// estimator named in the options; `mask` marks its inliers.
cv::Mat Essential(const std::vector<cv::Point2f>& pa, const std::vector<cv::Point2f>& pb, double threshold,
                  const std::string& estimator, cv::Mat& mask) {
  const int method = estimator == "ransac" ? cv::RANSAC : cv::USAC_DEFAULT;
  return cv::findEssentialMat(pa, pb, cv::Mat::eye(3, 3, CV_64F), method, 0.999, threshold, mask);
}

// The most essential-matrix inliers RANSAC finds among the same matches with
// b's points shuffled (two shuffles, seeded by the pair): what a pair's
// inlier count is worth when its matches are mostly wrong.
int ChanceInliers(int a, int b, const std::vector<cv::Point2f>& pa, const std::vector<cv::Point2f>& pb,
                  double threshold, const std::string& estimator) {
  std::mt19937 rng(uint32_t(a) * 7919u + uint32_t(b));
  int most = 0;
  for (int k = 0; k < 2; ++k) {
    std::vector<cv::Point2f> shuffled = pb;
    std::shuffle(shuffled.begin(), shuffled.end(), rng);
    cv::Mat mask;
    const cv::Mat e = Essential(pa, shuffled, threshold, estimator, mask);
    if (!e.empty()) most = std::max(most, cv::countNonZero(mask));
  }
  return most;
}

// The photos' rotation from a to b against the poses'; inliers = 0 when the
// photos do not hold enough matches, or no more inliers than chance.
PairCheck CheckPair(int a, int b, const FrameFeatures& fa, const FrameFeatures& fb, const Camera& ca,
                    const Camera& cb, const PoseCheckOptions& o) {
  PairCheck p;
  p.a = a;
  p.b = b;
  const std::vector<cv::DMatch> matches = RatioMatches(fa.descriptors, fb.descriptors, o.ratio);
  p.matches = int(matches.size());
  if (int(matches.size()) < o.min_inliers) return p;
  std::vector<cv::Point2f> pa, pb;
  for (const cv::DMatch& m : matches) {
    pa.push_back(fa.normalised[m.queryIdx]);
    pb.push_back(fb.normalised[m.trainIdx]);
  }
  const double threshold = o.ransac_px / std::min(fa.focal, fb.focal);
  cv::Mat mask;
  const cv::Mat e = Essential(pa, pb, threshold, o.estimator, mask);
  if (e.rows != 3 || e.cols != 3) return p;  // None, or several solutions: too weak a pair.
  cv::Mat r, t;
  const int inliers = cv::recoverPose(e, pa, pb, cv::Mat::eye(3, 3, CV_64F), r, t, mask);
  if (inliers < o.min_inliers) return p;
  // An essential matrix holds two rotations (the second turned 180 degrees
  // about the baseline: the "twisted pair"), and few or repetitive matches
  // can make the wrong one look in front of both cameras; the poses agree
  // with the photos when either is close.
  cv::Mat r1, r2, baseline;
  cv::decomposeEssentialMat(e, r1, r2, baseline);
  const Eigen::Matrix3d ra = ca.c2w.leftCols<3>().cast<double>(), rb = cb.c2w.leftCols<3>().cast<double>();
  const Eigen::Matrix3d poses = rb.transpose() * ra;  // Camera a's coordinates to camera b's, from the poses.
  p.rotation = ToEigen(r);
  p.baseline = Eigen::Vector3d(t.at<double>(0), t.at<double>(1), t.at<double>(2)).normalized();
  p.disagreement_deg =
      float(std::min(RotationAngleDegrees(poses, ToEigen(r1)), RotationAngleDegrees(poses, ToEigen(r2))));
  p.inliers = inliers;
  if (p.disagreement_deg <= o.max_disagreement_deg) return p;
  // Turned: only a pair that holds more than chance, and whose matches the
  // poses cannot explain, disagrees. (Only turned pairs pay for the shuffled
  // RANSAC: with few true matches it runs its full 1000 iterations.)
  if (o.min_chance_ratio > 0) {
    p.chance_inliers = ChanceInliers(a, b, pa, pb, threshold, o.estimator);
    if (inliers < o.min_chance_ratio * p.chance_inliers) {
      p.inliers = 0;  // Counted in pairs_below_chance.
      return p;
    }
  }
  p.explained = ExplainedByPoses(pa, pb, ca, cb, o.pose_px / std::min(fa.focal, fb.focal));
  p.disagrees = o.min_explained_fraction <= 0 || p.explained < o.min_explained_fraction * double(inliers);
  return p;
}

// Labels the frames 0 or 1 so that the pairs that agree join frames of one
// label and the pairs that disagree frames of two, weighing each pair by its
// inliers; neighbours in order whose poses turn little (`continuous[i]`:
// frames i and i + 1) add a weak vote for one label, as a video's neighbours
// are one run unless their poses jump. Pairs join frames at most `k` apart,
// so the best labelling is found exactly by dynamic programming over the
// labels of the last k frames.
std::vector<int> BestLabels(int n, int k, const std::vector<PairCheck>& pairs, const std::vector<bool>& continuous) {
  constexpr double kContinuity = 1.0, kTie = 1e-6;  // Pairs weigh >= min_inliers (8).
  std::vector<std::vector<double>> same(n, std::vector<double>(k, 0.0)), apart = same;
  for (const PairCheck& p : pairs) (p.disagrees ? apart : same)[p.b][p.b - p.a - 1] += p.inliers;
  for (int i = 0; i + 1 < n; ++i) same[i + 1][0] += continuous[i] ? kContinuity : kTie;
  const int states = 1 << k, all = states - 1;  // Bit d: the label of the frame d back.
  const double none = -std::numeric_limits<double>::infinity();
  std::vector<double> score(states, none);
  score[0] = score[1] = 0;
  std::vector<std::vector<int>> from(n, std::vector<int>(states, -1));
  for (int i = 1; i < n; ++i) {
    std::vector<double> next(states, none);
    for (int m = 0; m < states; ++m) {
      if (score[m] == none) continue;
      for (int label = 0; label < 2; ++label) {
        double gain = 0;
        for (int d = 1; d <= k && i - d >= 0; ++d) {
          gain += ((m >> (d - 1)) & 1) == label ? same[i][d - 1] : apart[i][d - 1];
        }
        const int to = ((m << 1) | label) & all;
        if (score[m] + gain > next[to]) {
          next[to] = score[m] + gain;
          from[i][to] = m;
        }
      }
    }
    score = std::move(next);
  }
  int m = int(std::max_element(score.begin(), score.end()) - score.begin());
  std::vector<int> labels(n);
  for (int i = n - 1; i >= 0; --i) {
    labels[i] = m & 1;
    if (i > 0) m = from[i][m];
  }
  return labels;
}

// Labels the frames (BestLabels), counts the pairs the labels do not
// explain, and disputes the frames of the smaller label.
void Group(const PoseCheckOptions& o, const std::vector<bool>& continuous, PoseCheckReport* r) {
  std::vector<int> in_pair(r->frames, 0);
  std::vector<double> agreeing;
  for (const PairCheck& p : r->pairs) {
    r->disagreeing_pairs += p.disagrees;
    const bool turned = p.disagreement_deg > o.max_disagreement_deg;
    r->explained_pairs += turned && !p.disagrees;
    if (!turned) agreeing.push_back(p.disagreement_deg);
    in_pair[p.a] = in_pair[p.b] = 1;
  }
  if (!agreeing.empty()) {
    std::nth_element(agreeing.begin(), agreeing.begin() + agreeing.size() / 2, agreeing.end());
    r->median_agreeing_deg = agreeing[agreeing.size() / 2];
  }
  for (int i = 0; i < r->frames; ++i) {
    if (!in_pair[i]) r->unchecked.push_back(i);
  }
  if (r->frames == 0) return;
  const std::vector<int> labels = BestLabels(r->frames, o.sequence_neighbours, r->pairs, continuous);
  for (const PairCheck& p : r->pairs) r->conflicts += (labels[p.a] != labels[p.b]) != p.disagrees;
  for (int i = 0; i + 1 < r->frames; ++i) r->continuity_links += continuous[i] && labels[i] == labels[i + 1];
  if (r->conflicts > o.max_conflict_fraction * double(r->pairs.size())) {
    r->inconclusive = true;
    return;
  }
  std::array<int, 2> count = {0, 0};
  for (int i = 0; i < r->frames; ++i) count[labels[i]] += in_pair[i];
  const int minority = count[1] < count[0] ? 1 : 0;
  if (count[0] == count[1]) return;  // No side to prefer.
  for (int i = 0; i < r->frames; ++i) {
    if (labels[i] == minority && in_pair[i]) r->disputed.push_back(i);
  }
}

}  // namespace

absl::StatusOr<PoseCheckReport> CheckPoses(const std::vector<View>& views, const PoseCheckOptions& options,
                                           int threads) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  for (const View& v : views) {
    if (v.image.width != v.camera.intrinsics.width || v.image.height != v.camera.intrinsics.height) {
      return absl::InvalidArgumentError(absl::StrCat("pose check: view '", v.name, "' has no image of its camera's size"));
    }
  }
  const auto start = std::chrono::steady_clock::now();
  const int nthreads = threads > 0 ? threads : omp_get_max_threads();
  cv::setNumThreads(1);  // Parallel over frames and pairs instead.
  PoseCheckReport r;
  r.frames = int(views.size());
  r.threshold_deg = options.max_disagreement_deg;
  std::vector<FrameFeatures> features(views.size());
#pragma omp parallel for schedule(dynamic, 1) num_threads(nthreads)
  for (int i = 0; i < int(views.size()); ++i) features[i] = Extract(views[i], options);
  const std::vector<std::pair<int, int>> candidates = CandidatePairs(int(views.size()), options);
  r.pairs_tried = int(candidates.size());
  std::vector<PairCheck> checked(candidates.size());
#pragma omp parallel for schedule(dynamic, 1) num_threads(nthreads)
  for (int k = 0; k < int(candidates.size()); ++k) {
    const auto [a, b] = candidates[k];
    checked[k] = CheckPair(a, b, features[a], features[b], views[a].camera, views[b].camera, options);
  }
  for (const PairCheck& p : checked) {
    if (p.inliers > 0) r.pairs.push_back(p);
    r.pairs_below_chance += p.inliers == 0 && p.chance_inliers > 0;
  }
  std::vector<bool> continuous(views.size(), false);
  for (size_t i = 0; i + 1 < views.size(); ++i) {
    const Eigen::Matrix3d a = views[i].camera.c2w.leftCols<3>().cast<double>();
    const Eigen::Matrix3d b = views[i + 1].camera.c2w.leftCols<3>().cast<double>();
    continuous[i] = RotationAngleDegrees(a, b) < options.max_disagreement_deg;
  }
  Group(options, continuous, &r);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return r;
}

std::vector<View> CaptureInOrder(const Scene& scene) {
  std::vector<View> views = scene.train;
  views.insert(views.end(), scene.test.begin(), scene.test.end());
  std::stable_sort(views.begin(), views.end(), [](const View& x, const View& y) { return x.name < y.name; });
  return views;
}

std::set<std::string> DisputedNames(const PoseCheckReport& report, const std::vector<View>& views) {
  std::set<std::string> names;
  for (int i : report.disputed) names.insert(views[i].name);
  return names;
}

bool DropsDisputed(const std::string& action, bool posed_here) {
  return action == "drop" || (action == "auto" && posed_here);
}

size_t DropViewsNamed(const std::set<std::string>& names, std::vector<View>* views) {
  const size_t before = views->size();
  views->erase(std::remove_if(views->begin(), views->end(), [&](const View& v) { return names.count(v.name) > 0; }),
               views->end());
  return before - views->size();
}

std::string PoseCheckReport::Summary(const std::vector<View>& views) const {
  std::string s =
      absl::StrFormat("%d of %d frame pairs matched; %d disagree with the poses by > %.0f deg (agreeing: median %.1f deg)",
                      int(pairs.size()), pairs_tried, disagreeing_pairs, threshold_deg, median_agreeing_deg);
  if (pairs_below_chance > 0) absl::StrAppend(&s, "; ", pairs_below_chance, " more matched no better than chance");
  if (explained_pairs > 0) {
    absl::StrAppend(&s, "; ", explained_pairs, " more turned by the photos' own estimate but explained by the poses");
  }
  if (inconclusive) return absl::StrCat(s, "; inconclusive (", conflicts, " pairs contradict the grouping)");
  if (disputed.empty()) return absl::StrCat(s, "; every checked frame agrees");
  std::vector<std::string> which;
  for (int i : disputed) which.push_back(i < int(views.size()) ? views[i].name : absl::StrCat(i));
  return absl::StrCat(s, "; ", disputed.size(), " of ", frames, " frames disputed: ", absl::StrJoin(which, " "));
}

}  // namespace clnerf
