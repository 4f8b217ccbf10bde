// Test helpers for server/store/ tests and those above: a fresh temp dir,
// tiny procedural scans and their uploads. Header-only; test code only;
// needs only the store and core.
#ifndef CLNERF_SERVER_TESTING_STORE_TEST_UTIL_H_
#define CLNERF_SERVER_TESTING_STORE_TEST_UTIL_H_

#include <filesystem>
#include <random>
#include <string>

#include "absl/strings/str_cat.h"
#include "core/data/image.h"
#include "core/data/procedural_scene.h"
#include "core/testing/temp_dir.h"
#include "gtest/gtest.h"
#include "server/store/scan_store.h"

namespace clnerf {
namespace testing_util {

// A fresh empty directory under the test temp dir, removed when the test
// passes (core/testing/temp_dir.h).
inline std::string TempDir(const std::string& name) { return FreshTempDir(name); }

// `steps` time steps of the procedural changing scene, tiny.
inline Scene TinyScans(int steps, int size = 24, int train = 12, int test = 3) {
  ProceduralSceneOptions po;
  po.width = po.height = size;
  po.num_train_views = train;
  po.num_test_views = test;
  po.num_time_steps = steps;
  po.samples_per_axis = 1;
  po.seed = 5;
  absl::StatusOr<Scene> s = GenerateProceduralScene(po);
  EXPECT_TRUE(s.ok()) << s.status();
  return *s;
}

// The frames of time step t as an upload (PNG bytes).
inline ScanUpload UploadOf(const Scene& scene, int t) {
  ScanUpload up;
  up.name = absl::StrCat("scan_t", t);
  up.scene_kind = "bounded";
  up.pose_frame = "place";  // Procedural scans share the scene's frame.
  for (int split = 0; split < 2; ++split) {
    for (const View& v : split == 0 ? scene.train : scene.test) {
      if (v.camera.time_step != t) continue;
      ScanFrame f;
      f.name = absl::StrCat(split ? "test/" : "train/", v.name);
      f.camera = v.camera;
      f.camera.time_step = 0;
      f.test = split == 1;
      absl::StatusOr<std::string> png = EncodePng(v.image);
      EXPECT_TRUE(png.ok());
      f.image = *png;
      up.frames.push_back(std::move(f));
    }
  }
  return up;
}

}  // namespace testing_util
}  // namespace clnerf

#endif  // CLNERF_SERVER_TESTING_STORE_TEST_UTIL_H_
