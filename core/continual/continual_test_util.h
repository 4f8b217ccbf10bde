// Test fixtures shared by the continual module's tests: a tiny procedural
// changing scene cut into scans, and update options small enough for unit
// tests (seconds, fixed seeds). Header-only; test code only.
#ifndef CLNERF_CORE_CONTINUAL_CONTINUAL_TEST_UTIL_H_
#define CLNERF_CORE_CONTINUAL_CONTINUAL_TEST_UTIL_H_

#include "core/continual/continual_update.h"
#include "core/continual/scan_sequence.h"
#include "core/data/procedural_scene.h"
#include "gtest/gtest.h"

namespace clnerf {

inline ScanSequence TinySequence(int steps, int size = 24, int train = 20, int samples_per_axis = 1) {
  ProceduralSceneOptions po;
  po.width = po.height = size;
  po.num_train_views = train;
  po.num_test_views = 4;
  po.num_time_steps = steps;
  po.samples_per_axis = samples_per_axis;
  po.seed = 3;
  absl::StatusOr<Scene> s = GenerateProceduralScene(po);
  EXPECT_TRUE(s.ok()) << s.status();
  absl::StatusOr<ScanSequence> seq = FromTimeSteps(*s);
  EXPECT_TRUE(seq.ok()) << seq.status();
  return *seq;
}

inline UpdateOptions TinyOptions(ContinualMethod method, int iterations) {
  UpdateOptions o;
  o.method = method;
  o.train.iterations = iterations;
  o.train.threads = 2;
  o.train.seed = 1;
  o.train.target_samples = 1 << 13;
  o.train.batch_rays = 512;
  o.model.grid.levels = 8;
  o.capacity.max_log2_table_size = 14;
  o.model.occupancy.warmup_iterations = 64;
  return o;
}

}  // namespace clnerf

#endif  // CLNERF_CORE_CONTINUAL_CONTINUAL_TEST_UTIL_H_
