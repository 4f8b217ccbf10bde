// SIFT features of photos and renders through OpenCV, shared by the .cc files
// of core/pose (feature_localizer.cc, pose_check.cc). Internal: it includes
// OpenCV, so no public header of core/pose includes it.
//
// Thread-safety: free functions without shared state; OpenCV's own threading
// is the caller's to set (cv::setNumThreads).
#ifndef CLNERF_CORE_POSE_SIFT_FEATURES_H_
#define CLNERF_CORE_POSE_SIFT_FEATURES_H_

#include <vector>

#include "core/data/image.h"
#include "opencv2/core.hpp"
#include "opencv2/features2d.hpp"

namespace clnerf {

// `image`'s luma as 8-bit grey.
cv::Mat ToGray(const Image& image);

// `gray` resized to width x height (cubic when enlarging, area when
// shrinking); unchanged when it already has that size.
cv::Mat ResizedGray(const cv::Mat& gray, int width, int height);

struct Features {
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;  // One CV_32F row per keypoint.
};

// At most `max_features` SIFT keypoints (the strongest) and their descriptors.
Features Detect(const cv::Mat& gray, int max_features);

// Lowe's ratio test: for each row of `query`, its nearest row of `train` when
// that is closer than `ratio` times the second nearest. Empty when either has
// fewer than 2 rows.
std::vector<cv::DMatch> RatioMatches(const cv::Mat& query, const cv::Mat& train, float ratio);

}  // namespace clnerf

#endif  // CLNERF_CORE_POSE_SIFT_FEATURES_H_
