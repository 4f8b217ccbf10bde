// Capacity: the derived sizes (DeriveModelOptions) and CapacityOverrides (unset
// fields keep the derived sizes, set ones win).
#include "core/field/capacity.h"

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(CapacityOverridesTest, EmptyOverridesChangeNothing) {
  ModelOptions base;
  base.grid.log2_table_size = 15;
  base.march.cone_angle = 0.25f;
  const CapacityOverrides none;
  EXPECT_TRUE(none.empty());
  const ModelOptions out = none.ApplyTo(base);
  EXPECT_EQ(out.grid.log2_table_size, 15);
  EXPECT_EQ(out.grid.finest_resolution, base.grid.finest_resolution);
  EXPECT_EQ(out.occupancy.resolution, base.occupancy.resolution);
  EXPECT_EQ(out.march.steps_per_diagonal, base.march.steps_per_diagonal);
  EXPECT_EQ(out.march.cone_angle, 0.25f);
  EXPECT_EQ(out.march.near, base.march.near);
  EXPECT_EQ(out.occupancy.density_threshold, base.occupancy.density_threshold);
}

TEST(CapacityOverridesTest, SetFieldsWinAndOnlyThose) {
  ModelOptions base;
  CapacityOverrides o;
  o.log2_table_size = 12;
  o.cone_angle = 0.0f;  // A set zero is a value, not "unset".
  o.occupancy_threshold = 0.5f;
  EXPECT_FALSE(o.empty());
  base.march.cone_angle = 1.0f / 256;
  const ModelOptions out = o.ApplyTo(base);
  EXPECT_EQ(out.grid.log2_table_size, 12);
  EXPECT_EQ(out.march.cone_angle, 0.0f);
  EXPECT_EQ(out.occupancy.density_threshold, 0.5f);
  EXPECT_EQ(out.grid.finest_resolution, base.grid.finest_resolution);
  EXPECT_EQ(out.march.steps_per_diagonal, base.march.steps_per_diagonal);
  EXPECT_TRUE(out.Validate().ok()) << out.Validate();
}

TEST(CapacityOverridesTest, OverridesThatWouldNotMeanWhatTheySayAreRefused) {
  EXPECT_TRUE(CapacityOverrides{}.Validate().ok());
  CapacityOverrides o;
  o.log2_table_size = 0;
  EXPECT_FALSE(o.Validate().ok());
  // Zero is not "derive": the occupancy grid would silently fall back to its
  // own 0.01 / min step rule instead of the derived threshold.
  CapacityOverrides t;
  t.occupancy_threshold = 0.0f;
  EXPECT_FALSE(t.Validate().ok());
  CapacityOverrides s;
  s.steps_per_diagonal = -3.0f;
  EXPECT_FALSE(s.Validate().ok());
  CapacityOverrides n;
  n.near = -0.1f;
  EXPECT_FALSE(n.Validate().ok());
  CapacityOverrides ok;
  ok.cone_angle = 0.0f;
  ok.near = 0.0f;
  EXPECT_TRUE(ok.Validate().ok());
  // In range for the overrides, out of range for the model.
  CapacityOverrides big;
  big.log2_table_size = 40;
  EXPECT_TRUE(big.Validate().ok());
  EXPECT_FALSE(big.ApplyTo(ModelOptions{}).Validate().ok());
}

// A camera close to a small box with a long focal length needs a finest
// resolution beyond upstream's 2048 per unit of bound; max_finest_resolution
// caps it, and the table follows the capped resolution.
TEST(CapacityDeriveTest, MaxFinestResolutionCapsTheDerivedResolution) {
  Scene scene;
  scene.kind = SceneKind::kBounded;
  View v;
  v.camera.intrinsics.width = v.camera.intrinsics.height = 100;
  v.camera.intrinsics.fx = v.camera.intrinsics.fy = 4000.0f;
  v.camera.c2w = Pose::Identity();
  v.camera.c2w.col(3) = Eigen::Vector3f(0.0f, 0.0f, -1.0f);
  scene.train.push_back(v);
  Normalization norm;  // bound 0.5: upstream's finest is 1024.
  CapacityOptions cap;
  CapacityReport free_report, capped_report;
  DeriveModelOptions(scene, norm, cap, ModelOptions(), &free_report);
  EXPECT_EQ(free_report.finest_resolution, 1024);
  cap.max_finest_resolution = 256;
  ASSERT_TRUE(cap.Validate().ok());
  const ModelOptions capped = DeriveModelOptions(scene, norm, cap, ModelOptions(), &capped_report);
  EXPECT_EQ(capped.grid.finest_resolution, 256);
  EXPECT_EQ(capped_report.log2_table_size, 14);  // 256^2 / 16 = 2^12, raised to the minimum.
  cap.max_finest_resolution = -1;
  EXPECT_FALSE(cap.Validate().ok());
}

}  // namespace
}  // namespace clnerf
