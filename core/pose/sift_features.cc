#include "core/pose/sift_features.h"

#include <algorithm>
#include <cmath>

#include "opencv2/imgproc.hpp"

namespace clnerf {

cv::Mat ToGray(const Image& image) {
  cv::Mat gray(image.height, image.width, CV_8UC1);
  for (int y = 0; y < image.height; ++y) {
    uint8_t* row = gray.ptr<uint8_t>(y);
    for (int x = 0; x < image.width; ++x) {
      const float l = Luma(image.pixel(x, y));
      row[x] = uint8_t(std::clamp(std::lround(l * 255.0f), 0l, 255l));
    }
  }
  return gray;
}

cv::Mat ResizedGray(const cv::Mat& gray, int width, int height) {
  if (gray.cols == width && gray.rows == height) return gray;
  cv::Mat resized;
  const bool up = width > gray.cols;
  cv::resize(gray, resized, cv::Size(width, height), 0, 0, up ? cv::INTER_CUBIC : cv::INTER_AREA);
  return resized;
}

Features Detect(const cv::Mat& gray, int max_features) {
  Features f;
  cv::Ptr<cv::SIFT> sift = cv::SIFT::create(max_features);
  sift->detectAndCompute(gray, cv::noArray(), f.keypoints, f.descriptors);
  return f;
}

std::vector<cv::DMatch> RatioMatches(const cv::Mat& query, const cv::Mat& train, float ratio) {
  std::vector<cv::DMatch> good;
  if (query.rows < 2 || train.rows < 2) return good;
  cv::BFMatcher matcher(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(query, train, knn, 2);
  for (const auto& m : knn) {
    if (m.size() == 2 && m[0].distance < ratio * m[1].distance) good.push_back(m[0]);
  }
  return good;
}

}  // namespace clnerf
