#include "core/continual/scan_sequence.h"

#include <filesystem>

#include "core/data/procedural_scene.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

Scene Procedural(int steps, int train, int test) {
  ProceduralSceneOptions po;
  po.width = po.height = 16;
  po.num_train_views = train;
  po.num_test_views = test;
  po.num_time_steps = steps;
  po.samples_per_axis = 1;
  absl::StatusOr<Scene> s = GenerateProceduralScene(po);
  EXPECT_TRUE(s.ok()) << s.status();
  return *s;
}

TEST(ScanSequenceTest, SplitIntoContiguousTasksAndNearestTestAssignment) {
  Scene scene = Procedural(1, 20, 8);
  absl::StatusOr<ScanSequence> seq = SplitIntoTasks(scene, 4);
  ASSERT_TRUE(seq.ok()) << seq.status();
  ASSERT_EQ(seq->size(), 4);
  size_t tests = 0;
  for (int t = 0; t < 4; ++t) {
    ASSERT_EQ(seq->scans[t].train.size(), 5u);
    for (size_t i = 0; i < 5; ++i) {
      EXPECT_EQ(seq->scans[t].train[i].name, scene.train[t * 5 + i].name);  // Contiguous, in order.
      EXPECT_EQ(seq->scans[t].train[i].camera.time_step, t);
    }
    for (const View& v : seq->scans[t].test) {
      EXPECT_EQ(v.camera.time_step, t);
      // No training camera of another task is closer than the nearest of this task.
      float own = 1e30f, other = 1e30f;
      for (int u = 0; u < 4; ++u) {
        for (const View& tr : seq->scans[u].train) {
          const float d = (tr.camera.position() - v.camera.position()).norm();
          (u == t ? own : other) = std::min(u == t ? own : other, d);
        }
      }
      EXPECT_LE(own, other);
    }
    tests += seq->scans[t].test.size();
  }
  EXPECT_EQ(tests, scene.test.size());
  EXPECT_EQ(seq->Union(3).train.size(), 20u);
  EXPECT_EQ(seq->Union(0).train.size(), 5u);
  EXPECT_FALSE(SplitIntoTasks(scene, 0).ok());
  EXPECT_FALSE(SplitIntoTasks(scene, 21).ok());
}

TEST(ScanSequenceTest, FromTimeStepsGroupsViews) {
  Scene scene = Procedural(3, 6, 2);
  absl::StatusOr<ScanSequence> seq = FromTimeSteps(scene);
  ASSERT_TRUE(seq.ok()) << seq.status();
  ASSERT_EQ(seq->size(), 3);
  for (int t = 0; t < 3; ++t) {
    EXPECT_EQ(seq->scans[t].train.size(), 6u);
    EXPECT_EQ(seq->scans[t].test.size(), 2u);
    for (const View& v : seq->scans[t].train) EXPECT_EQ(v.camera.time_step, t);
  }
}

TEST(ScanSequenceTest, LoadScanFoldersInSortedOrder) {
  const std::string dir = (std::filesystem::temp_directory_path() / "clnerf_scan_folders_test").string();
  std::filesystem::remove_all(dir);
  Scene scene = Procedural(3, 4, 2);
  ASSERT_TRUE(WriteScanFolders(scene, dir).ok());
  absl::StatusOr<ScanSequence> seq = LoadScanFolders(dir, {});
  ASSERT_TRUE(seq.ok()) << seq.status();
  ASSERT_EQ(seq->size(), 3);
  for (int t = 0; t < 3; ++t) {
    EXPECT_EQ(seq->scans[t].train.size(), 4u);
    EXPECT_EQ(seq->scans[t].test.size(), 2u);
    EXPECT_EQ(seq->scans[t].train[0].camera.time_step, t);
    // The images are the ones written for that step (8-bit quantised).
    EXPECT_NEAR(seq->scans[t].train[0].image.rgb[0], scene.train[t * 4].image.rgb[0], 1.0 / 255 + 1e-6);
  }
  EXPECT_EQ(LoadScanFolders(dir + "/missing", {}).status().code(), absl::StatusCode::kNotFound);
  std::filesystem::remove_all(dir);
}

TEST(ScanSequenceTest, LoadScanSequenceDetectsTheLayout) {
  const std::string root = (std::filesystem::temp_directory_path() / "clnerf_load_scan_sequence_test").string();
  std::filesystem::remove_all(root);
  // A directory of scan folders -> one scan per folder.
  ASSERT_TRUE(WriteScanFolders(Procedural(2, 3, 1), root + "/scans").ok());
  absl::StatusOr<ScanSequence> folders = LoadScanSequence(root + "/scans", 7, {});
  ASSERT_TRUE(folders.ok()) << folders.status();
  EXPECT_EQ(folders->size(), 2);
  // A static dataset -> cut into the requested number of tasks.
  ASSERT_TRUE(WriteBlenderDataset(Procedural(1, 6, 2), root + "/static").ok());
  absl::StatusOr<ScanSequence> tasks = LoadScanSequence(root + "/static", 3, {});
  ASSERT_TRUE(tasks.ok()) << tasks.status();
  ASSERT_EQ(tasks->size(), 3);
  EXPECT_EQ(tasks->scans[2].train.size(), 2u);
  // ScanScene(t) is the header plus that scan's views.
  const Scene s2 = tasks->ScanScene(2);
  EXPECT_EQ(s2.train.size(), 2u);
  EXPECT_EQ(s2.world_scale_hint, tasks->world_scale_hint);
  EXPECT_EQ(LoadScanSequence(root + "/missing", 3, {}).status().code(), absl::StatusCode::kNotFound);
  std::filesystem::remove_all(root);
}

}  // namespace
}  // namespace clnerf
