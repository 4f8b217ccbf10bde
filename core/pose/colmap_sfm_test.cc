// COLMAP (Debian's colmap, run for real) poses an unposed procedural scan;
// after one similarity fit its poses match the known ones.
#include <cstdlib>
#include <fstream>
#include <filesystem>
#include <iostream>
#include <random>
#include <regex>

#include "absl/strings/str_format.h"
#include "core/data/image.h"
#include "core/data/procedural_scene.h"
#include "core/pose/place_map.h"
#include "core/pose/process.h"
#include "core/pose/sfm.h"
#include "core/pose/similarity.h"
#include "core/testing/temp_dir.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;

bool ColmapInstalled() { return std::system("command -v colmap > /dev/null 2>&1") == 0; }

std::string TempDir(const std::string& name) { return testing_util::FreshTempDir(name); }

// A textured orbit (the procedural backdrop scene, one test view) at
// width x height with `views` training views, each written to `dir` as
// photo_<i>.png, in order, into `photos`.
absl::StatusOr<Scene> OrbitPhotos(int width, int height, int views, const std::string& dir,
                                  std::vector<std::string>* photos) {
  ProceduralSceneOptions po;
  po.backdrop = true;
  po.textured = true;
  po.width = width;
  po.height = height;
  po.num_train_views = views;
  po.num_test_views = 1;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  if (!scene.ok()) return scene.status();
  for (size_t i = 0; i < scene->train.size(); ++i) {
    photos->push_back(dir + "/photo_" + std::to_string(i) + ".png");
    if (absl::Status s = WriteImage(photos->back(), scene->train[i].image); !s.ok()) return s;
  }
  return scene;
}

TEST(ProcessTest, ReportsMissingProgramsAndFailures) {
  const std::string dir = TempDir("process");
  EXPECT_TRUE(absl::IsNotFound(RunProcess({"clnerf-no-such-program"}, dir + "/log")));
  EXPECT_TRUE(RunProcess({"true"}, dir + "/log").ok());
  absl::Status s = RunProcess({"sh", "-c", "echo boom; exit 3"}, dir + "/log");
  EXPECT_TRUE(absl::IsInternal(s));
  EXPECT_NE(s.message().find("exit status 3"), std::string::npos) << s;
  EXPECT_NE(s.message().find("boom"), std::string::npos) << s;
  std::atomic<bool> cancel{true};
  EXPECT_TRUE(absl::IsCancelled(RunProcess({"sleep", "30"}, dir + "/log", &cancel)));
}

TEST(ColmapSfmTest, PosesAnUnposedScanUpToASimilarity) {
  if (!ColmapInstalled()) GTEST_SKIP() << "colmap is not installed (scripts/install-deps.sh installs it)";
  const std::string dir = TempDir("colmap_sfm");
  std::vector<std::string> photos;
  absl::StatusOr<Scene> scene = OrbitPhotos(400, 300, 24, dir, &photos);
  ASSERT_TRUE(scene.ok()) << scene.status();
  std::vector<Camera> truth;
  for (const View& v : scene->train) truth.push_back(v.camera);
  SfmOptions o;
  o.workspace = dir + "/ws";
  absl::StatusOr<SfmResult> r = ColmapSfm().Run(photos, o);
  ASSERT_TRUE(r.ok()) << r.status() << " " << o.workspace;
  std::cout << "COLMAP posed " << r->registered << " of " << photos.size() << " photos, mean reprojection "
            << r->mean_reprojection_px << " px; features " << r->features_seconds << " s, matching "
            << r->matching_seconds << " s, mapping " << r->mapping_seconds << " s\n";
  EXPECT_GE(r->registered, int(photos.size()) * 9 / 10);
  EXPECT_FALSE(fs::exists(o.workspace));  // Removed afterwards.
  std::vector<PosePair> pairs;
  std::vector<int> index;
  for (size_t i = 0; i < photos.size(); ++i) {
    if (!r->cameras[i]) continue;
    pairs.push_back({r->cameras[i]->c2w, truth[i].c2w});
    index.push_back(int(i));
    EXPECT_NEAR(r->cameras[i]->intrinsics.fx, truth[i].intrinsics.fx, 0.02 * truth[i].intrinsics.fx);
  }
  const double extent = PlaceExtent(truth, Normalization());
  absl::StatusOr<RobustSimilarity> fit = FitSimilarityRobust(pairs, extent, RobustSimilarityOptions());
  ASSERT_TRUE(fit.ok()) << fit.status();
  EXPECT_EQ(fit->inliers.size(), pairs.size());
  for (size_t k = 0; k < pairs.size(); ++k) {
    const Pose placed = fit->transform.ApplyToPose(pairs[k].from);
    EXPECT_LT((placed.col(3) - pairs[k].to.col(3)).norm() / extent, 0.01) << "photo " << index[k];
    EXPECT_LT(RotationAngleDegrees(placed.leftCols<3>().cast<double>(), pairs[k].to.leftCols<3>().cast<double>()),
              0.5)
        << "photo " << index[k];
  }
}

// A later visit's run starts from the place's camera: COLMAP reads it as
// its camera's starting parameters (its log prints the focal length it
// starts from; its own guess would be 1.2 x the long side, 384 px here).
TEST(ColmapSfmTest, StartsFromAGivenCamera) {
  if (!ColmapInstalled()) GTEST_SKIP() << "colmap is not installed";
  const std::string dir = TempDir("colmap_seeded");
  std::vector<std::string> photos;
  // 20 photos: with 16 COLMAP posed 14 in one CI run (15 needed), 14 at
  // 240 x 180 posed 12.
  absl::StatusOr<Scene> scene = OrbitPhotos(320, 240, 20, dir, &photos);
  ASSERT_TRUE(scene.ok()) << scene.status();
  const Intrinsics truth = scene->train[0].camera.intrinsics;
  SfmOptions o;
  o.workspace = dir + "/ws";
  o.keep_workspace = true;
  o.initial_camera = truth;
  o.initial_camera->fx = o.initial_camera->fy = 1.05f * truth.fx;  // Near, not equal.
  absl::StatusOr<SfmResult> r = ColmapSfm().Run(photos, o);
  ASSERT_TRUE(r.ok()) << r.status() << " " << o.workspace;
  std::ifstream log(o.workspace + "/colmap.log");
  const std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  // "  Focal Length:    350.00px (Prior)" per photo.
  const std::regex seeded(absl::StrFormat("Focal Length:\\s+%.2fpx", 1.05f * truth.fx));
  EXPECT_TRUE(std::regex_search(text, seeded)) << "the starting focal length is not in " << o.workspace
                                               << "/colmap.log";
  // A seeded camera is held (registration refines it against the place).
  for (const std::optional<Camera>& c : r->cameras) {
    if (c) {
      EXPECT_NEAR(c->intrinsics.fx, 1.05 * truth.fx, 1e-3 * truth.fx);
    }
  }
  EXPECT_GE(r->registered, 18);  // 90 %: fewer would have been mapped again.
  fs::remove_all(dir);
}

// A later visit of a forward-facing place (cameras on a small plane, content
// at 2 to 20 baselines), seeded with a camera 5 % off as the place's own
// camera would be. Mapped with the camera refined from the start, COLMAP's
// two-view start drifted the focal length to 700-40000 px and posed 3 to 5
// of the 24 in 5 of 11 runs (all its retries share the matches, so they
// failed together); held while mapping, 8 of 8 posed all.
TEST(ColmapSfmTest, SeededNarrowBaselineScanIsPosedWhole) {
  if (!ColmapInstalled()) GTEST_SKIP() << "colmap is not installed";
  const std::string dir = TempDir("colmap_forward");
  ProceduralSceneOptions po;
  po.layout = ProceduralLayout::kForwardFacing;
  po.textured = true;
  po.width = 240;
  po.height = 180;
  po.num_train_views = 48;
  po.num_test_views = 1;
  po.change_lighting = po.change_geometry = false;
  absl::StatusOr<Scene> scene = GenerateProceduralScene(po);
  ASSERT_TRUE(scene.ok()) << scene.status();
  std::vector<std::string> photos;
  for (size_t i = 1; i < scene->train.size(); i += 2) {  // A second visit: the odd frames.
    photos.push_back(dir + "/photo_" + std::to_string(i) + ".png");
    ASSERT_TRUE(WriteImage(photos.back(), scene->train[i].image).ok());
  }
  const Intrinsics truth = scene->train[0].camera.intrinsics;
  SfmOptions o;
  o.workspace = dir + "/ws";
  o.initial_camera = truth;
  o.initial_camera->fx = o.initial_camera->fy = 1.05f * truth.fx;
  absl::StatusOr<SfmResult> r = ColmapSfm().Run(photos, o);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_GE(r->registered, 22) << "of 24";
  for (const std::optional<Camera>& c : r->cameras) {
    if (c) {
      EXPECT_NEAR(c->intrinsics.fx, truth.fx, 0.08 * truth.fx);
    }
  }
  fs::remove_all(dir);
}

TEST(ColmapSfmTest, PhotosWithNothingInCommonAreRefused) {
  if (!ColmapInstalled()) GTEST_SKIP() << "colmap is not installed";
  const std::string dir = TempDir("colmap_noise");
  std::vector<std::string> photos;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0, 1);
  for (int i = 0; i < 4; ++i) {
    Image im(96, 96);
    for (float& v : im.rgb) v = u(rng);
    photos.push_back(dir + "/noise_" + std::to_string(i) + ".png");
    ASSERT_TRUE(WriteImage(photos.back(), im).ok());
  }
  SfmOptions o;
  o.workspace = dir + "/ws";
  absl::StatusOr<SfmResult> r = ColmapSfm().Run(photos, o);
  EXPECT_TRUE(absl::IsFailedPrecondition(r.status())) << r.status();
}

}  // namespace
}  // namespace clnerf
