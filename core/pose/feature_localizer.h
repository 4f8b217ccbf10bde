// FeatureLocalizer: finds where a photo was taken in a place's frame from
// renders of the place (PlaceMap): SIFT features of each render, lifted to
// 3-D through the render's depth where the surface is solid, are matched to
// the photo's SIFT features (Lowe's ratio test), and the photo's pose is
// solved by PnP with RANSAC, then refined (Levenberg-Marquardt) on the
// inliers. OpenCV (Debian's libopencv, 4.6) does the features, matching and
// PnP; it is used nowhere else, and stays out of this header.
//
// Renders are softer than photos and a place changes between scans: a frame
// is placed only with enough inliers, and callers (registration.h) fit one
// similarity over many frames rather than trusting any single one.
//
// Thread-safety: Build once; Localize is const and may run on several threads
// at once (OpenCV's own threading is turned off by Build, so callers
// parallelise over frames).
#ifndef CLNERF_CORE_POSE_FEATURE_LOCALIZER_H_
#define CLNERF_CORE_POSE_FEATURE_LOCALIZER_H_

#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "core/data/camera.h"
#include "core/data/image.h"
#include "core/pose/place_map.h"

namespace clnerf {

struct LocalizerOptions {
  // Photos are matched at most this many pixels on their long side (the
  // renders are made at that size too). Larger finds more, slower.
  int max_side = 480;
  // ... and at least this many (smaller photos are scaled up, their renders
  // made at that size). lego_100's 100 px photos localised 5 of 50 frames at
  // their own size and 33 of 50 at 240 (256: 33, 300: 33, 400: 34). The fit
  // was then 0.27 degrees off, which cost the update 2.9 dB until the
  // similarity was refined photometrically (photometric_similarity.h: 0.03
  // degrees, 30.65 dB held out against 30.73 in the place's frame). Scaling
  // 240 x 180 photos to 320 localised 5 of 16 frames where their own size
  // localised 14, so photos of 240 px and more keep their size. 1 = never
  // scale up.
  int min_side = 240;
  // SIFT keypoints kept per image (strongest first).
  int max_features = 2000;
  // Lowe's ratio test: best / second-best descriptor distance below this.
  float ratio = 0.8f;
  // A render's keypoint gets a 3-D point only where the render is this
  // opaque and its depth varies by less than max_depth_jump (relative)
  // across the 4 x 4 pixels around it (no points on silhouettes or haze).
  float min_opacity = 0.95f;
  float max_depth_jump = 0.05f;
  // Each photo uses the correspondences of the renders it matched best.
  int references_per_frame = 3;
  // PnP: RANSAC threshold (pixels at the matching size), hypotheses, and the
  // inliers a frame needs to count as placed.
  float reprojection_px = 4.0f;
  int ransac_iterations = 1000;
  int min_inliers = 15;
  // A frame with fewer inliers but at least this many still gets its pose,
  // as a candidate only (FrameLocalization::weak): nothing fits or refines
  // on it, but pose arbitration may take it for a frame whose own pose is
  // disputed, once the map's render at it resembles the photo clearly better
  // (pose_arbitration.h). At least 6; above min_inliers it is min_inliers.
  // Off by default (= min_inliers): on beer_2 at 8 it rescued a mirrored
  // frame from 13 inliers whose pose was 8.5 degrees off (its render still
  // correlated 0.87 against 0.18), for no gain (docs/registration.md).
  int weak_min_inliers = 15;
  absl::Status Validate() const;
};

struct FrameLocalization {
  bool placed = false;
  // Not placed, but posed from at least weak_min_inliers: `c2w` is a
  // candidate that only pose arbitration reads.
  bool weak = false;
  Pose c2w = Pose::Identity();  // The photo's pose in the place's frame.
  int matches = 0;              // 2-D/3-D correspondences tried.
  int inliers = 0;              // PnP inliers.
  double reprojection_px = 0;   // RMS over the inliers, at the matching size.
  // How well the inliers fix the orientation: the largest marginal standard
  // deviation (degrees) of the PnP rotation, from the residuals and the
  // Gauss-Newton normal matrix over rotation and translation together. A few
  // points on one plane (a bare floor) give a pose whose rotation trades for
  // a translation: several degrees here, where 100 spread inliers give 0.1.
  double rotation_std_deg = 0;
  // The inlier correspondences: place points and the photo's pixels (at its
  // own size, pixel centres at +0.5), for a refinement over many frames.
  std::vector<Eigen::Vector3f> inlier_points;
  std::vector<Eigen::Vector2f> inlier_pixels;
};

// Covariance (radians^2) of a PnP pose's orientation, marginal over its
// translation: sigma^2 (J^T J)^-1 of the Gauss-Newton normal matrix of the
// normalised reprojections, J over (omega, delta t) for x' = exp(omega) x +
// delta t, sigma^2 = squared_error / (2 n - 6). `points` are the inliers in
// the camera's frame at the pose, `squared_error` the sum of their squared
// normalised reprojection errors. Infinite when under-determined.
Eigen::Matrix3d PnPRotationCovariance(const std::vector<Eigen::Vector3d>& points, double squared_error);
// Its largest axis's standard deviation, in degrees.
double RotationStdDeg(const Eigen::Matrix3d& covariance);

struct SharedCameraOptions {
  // A frame's refined pose is taken only within this turn of its start.
  double max_turn_deg = 3.0;
  // The refined camera is taken only when, with every frame's pose fitted
  // under each, its RMS reprojection error is at least min_rms_gain below
  // the starting camera's, its focal length within max_focal_change
  // (relative) and its k1 within max_k1_change of the start.
  double min_rms_gain = 0.05;
  double max_focal_change = 0.05;
  double max_k1_change = 0.05;
};

struct SharedCameraReport {
  double rms_guess_px = 0, rms_refined_px = 0;  // Poses fitted under each camera.
  double rms_px = 0;                            // Of the camera returned.
  bool camera_taken = false;                    // False: the guess was kept.
  // Under the guess, per refined frame (index into the frames): RMS at its
  // starting pose and at its fitted one.
  std::vector<int> frames;
  std::vector<std::pair<double, double>> frame_rms;
};

// Refines one camera shared by many localised frames of a scan (focal
// length and radial k1; principal point, aspect and the rest fixed) and
// then each frame's pose, by least squares over all their inlier
// correspondences with the place's points held fixed (OpenCV's
// calibrateCamera started from `guess` for the camera; Levenberg-Marquardt
// per frame from its pose in `poses`): the self-calibration of a
// structure-from-motion run over a few frames is corrected against the
// place. The refined camera is kept only when the points clearly prefer it
// (SharedCameraOptions); otherwise `guess` is returned, with the poses
// fitted under it. `poses` holds one starting pose per frame (the frames'
// registered poses); a placed frame's is replaced by its refined pose when
// that turns less than max_turn_deg away. INVALID_ARGUMENT with fewer than
// 3 placed frames; FAILED_PRECONDITION when the refinement diverges (focal
// moved by more than 20 %, or non-finite).
absl::StatusOr<Intrinsics> RefineSharedCamera(const std::vector<FrameLocalization>& frames, const Intrinsics& guess,
                                             std::vector<Pose>* poses, SharedCameraReport* report = nullptr,
                                             const SharedCameraOptions& options = {});

class FeatureLocalizer {
 public:
  ~FeatureLocalizer();
  // Detects and lifts the features of every render. INVALID_ARGUMENT for bad
  // options or renders whose buffers do not match their camera.
  static absl::StatusOr<std::unique_ptr<FeatureLocalizer>> Build(const std::vector<MapView>& renders,
                                                                 const LocalizerOptions& options);
  // Localises one photo taken with `camera`'s intrinsics (its pose is not
  // used). The image is resized to the matching size here.
  FrameLocalization Localize(const Image& image, const Camera& camera) const;
  // 3-D points over all renders (a map with none cannot place anything).
  int num_points() const;

 private:
  struct Impl;
  explicit FeatureLocalizer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_FEATURE_LOCALIZER_H_
