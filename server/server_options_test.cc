#include "server/server_options.h"

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(ServerOptionsTest, DefaultsAreValidAndConfigOverrides) {
  ServerOptions o;
  ASSERT_TRUE(o.Validate().ok()) << o.Validate();
  EXPECT_EQ(o.update.train.iterations, 300);
  ASSERT_TRUE(ApplyConfigJson(R"({"max_queue": 3, "iterations_per_update": 120, "method": "clnerf-noer",
                                  "gate": {"min_new_psnr": 21.5}})", &o).ok());
  EXPECT_EQ(o.max_queue, 3);
  EXPECT_EQ(o.update.train.iterations, 120);
  EXPECT_EQ(o.update.method, ContinualMethod::kCLNeRFNoER);
  EXPECT_FLOAT_EQ(o.gate.min_new_psnr, 21.5f);
  EXPECT_TRUE(o.Validate().ok());
  // The bake's budgets: an unbounded scene's and an object's.
  EXPECT_EQ(o.bake.max_object_asset_bytes, 4'000'000);
  EXPECT_TRUE(o.bake.in_between_views);
  ASSERT_TRUE(ApplyConfigJson(R"({"bake": {"max_asset_bytes": 9000000, "max_object_asset_bytes": 2000000,
                                           "fit_max_entries": 40000000, "density_fit_rays": 65536,
                                           "in_between_views": false}})", &o).ok());
  EXPECT_EQ(o.bake.density_fit.rays, 65536);
  EXPECT_FALSE(o.bake.in_between_views);
  EXPECT_EQ(o.bake.max_asset_bytes, 9'000'000);
  EXPECT_EQ(o.bake.max_object_asset_bytes, 2'000'000);
  EXPECT_EQ(o.bake.fit.max_nonzeros, 40'000'000);
  EXPECT_FALSE(ApplyConfigJson(R"({"bake": {"max_object_bytes": 1}})", &o).ok());
  // Registration: photos under 240 px are matched at 240 unless min_side
  // says otherwise.
  EXPECT_EQ(o.registration.localizer.min_side, 240);
  // A scan in its own frame has its similarity refined photometrically.
  EXPECT_TRUE(o.registration.photometric_similarity);
  ASSERT_TRUE(ApplyConfigJson(
      R"({"registration": {"min_side": 1, "identity_chi_square": 0, "photometric_similarity": false}})", &o).ok());
  EXPECT_EQ(o.registration.localizer.min_side, 1);
  EXPECT_EQ(o.registration.identity_chi_square, 0.0);
  EXPECT_FALSE(o.registration.photometric_similarity);
  EXPECT_TRUE(o.Validate().ok());
  // A scan the service posed keeps COLMAP's camera unless the place's
  // points cut the reprojection error by 5 %.
  EXPECT_EQ(o.registration.camera.min_rms_gain, 0.05);
  ASSERT_TRUE(ApplyConfigJson(R"({"registration": {"camera_min_rms_gain": 0.1, "camera_max_change": 0.02}})", &o).ok());
  EXPECT_EQ(o.registration.camera.min_rms_gain, 0.1);
  EXPECT_EQ(o.registration.camera.max_focal_change, 0.02);
  EXPECT_EQ(o.registration.camera.max_k1_change, 0.02);
  EXPECT_TRUE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"registration": {"camera_max_change": -1}})", &o).ok());
  EXPECT_FALSE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"registration": {"camera_max_change": 0.05, "min_side": 999}})", &o).ok());
  EXPECT_FALSE(o.Validate().ok());  // Above max_side (480).
  // Arbitration of frames whose SfM and PnP poses disagree is opt-in.
  EXPECT_FALSE(o.registration.arbitrate);
  ASSERT_TRUE(ApplyConfigJson(R"({"registration": {"min_side": 240, "arbitrate": true}})", &o).ok());
  EXPECT_TRUE(o.registration.arbitrate);
  EXPECT_TRUE(o.Validate().ok());
}

TEST(ServerOptionsTest, PoseCheckIsConfigured) {
  ServerOptions o;
  // Every scan is checked; only frames of a scan the service posed itself
  // are dropped unasked.
  EXPECT_EQ(o.pose_check_action, "auto");
  EXPECT_TRUE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"pose_check": {"action": "warn"}})", &o).ok());
  EXPECT_TRUE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"pose_check": {"action": "drop", "min_inliers": 30, "max_disagreement_deg": 60,
                                                   "sequence_neighbours": 2}})", &o).ok());
  EXPECT_EQ(o.pose_check_action, "drop");
  EXPECT_EQ(o.pose_check.min_inliers, 30);
  EXPECT_EQ(o.pose_check.max_disagreement_deg, 60.0f);
  EXPECT_EQ(o.pose_check.sequence_neighbours, 2);
  EXPECT_TRUE(o.Validate().ok());
  ASSERT_TRUE(
      ApplyConfigJson(R"({"pose_check": {"min_chance_ratio": 1.5, "pose_px": 3, "min_explained_fraction": 0.4}})", &o)
          .ok());
  EXPECT_EQ(o.pose_check.min_chance_ratio, 1.5f);
  EXPECT_EQ(o.pose_check.pose_px, 3.0f);
  EXPECT_EQ(o.pose_check.min_explained_fraction, 0.4f);
  EXPECT_TRUE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"pose_check": {"estimator": "ransac"}})", &o).ok());
  EXPECT_EQ(o.pose_check.estimator, "ransac");
  EXPECT_TRUE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"pose_check": {"estimator": "lmeds"}})", &o).ok());
  EXPECT_FALSE(o.Validate().ok());
  o.pose_check.estimator = "usac";
  ASSERT_TRUE(ApplyConfigJson(R"({"pose_check": {"action": "fix"}})", &o).ok());
  EXPECT_FALSE(o.Validate().ok());
  ASSERT_TRUE(ApplyConfigJson(R"({"pose_check": {"action": "off", "sequence_neighbours": 9}})", &o).ok());
  EXPECT_FALSE(o.Validate().ok());
  EXPECT_FALSE(ApplyConfigJson(R"({"pose_check": {"ratio": 0.5}})", &o).ok());
}

TEST(ServerOptionsTest, BadConfigIsRejectedWithTheKey) {
  ServerOptions o;
  absl::Status s = ApplyConfigJson(R"({"max_queu": 3})", &o);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("max_queu"), std::string::npos);
  EXPECT_FALSE(ApplyConfigJson(R"({"max_queue": "three"})", &o).ok());
  EXPECT_FALSE(ApplyConfigJson("not json", &o).ok());
  EXPECT_FALSE(ApplyConfigJson(R"({"gate": {"nope": 1}})", &o).ok());
  EXPECT_EQ(ApplyConfigJson(R"({"init": "cold"})", &o).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ApplyConfigJson(R"({"replay": "1"})", &o).code(), absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(ApplyConfigJson(R"({"init": "reinit", "replay": "online"})", &o).ok());
  EXPECT_EQ(o.update.init, InitMode::kReinit);
  EXPECT_EQ(o.update.replay, ReplayMode::kOnline);
  EXPECT_EQ(ApplyConfigJson(R"({"sampler": "grid"})", &o).code(), absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(ApplyConfigJson(R"({"sampler": "proposal"})", &o).ok());
  EXPECT_EQ(o.update.model.sampler, SamplerKind::kProposal);
  EXPECT_EQ(o.update.depth_fraction, 0.125f);
  ASSERT_TRUE(ApplyConfigJson(R"({"depth_fraction": 0})", &o).ok());
  EXPECT_EQ(o.update.depth_fraction, 0.0f);
  EXPECT_FALSE(o.update.train.view_colour);
  ASSERT_TRUE(ApplyConfigJson(R"({"view_colour": true})", &o).ok());
  EXPECT_TRUE(o.update.train.view_colour);
  EXPECT_EQ(ApplyConfigJson(R"({"view_colour": "yes"})", &o).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ApplyConfigFile("/nonexistent/server.json", &o).code(), absl::StatusCode::kNotFound);
  ServerOptions bad;
  bad.max_queue = 0;
  EXPECT_FALSE(bad.Validate().ok());
  bad = ServerOptions();
  bad.tls_cert = "cert.pem";
  EXPECT_FALSE(bad.Validate().ok());
  bad = ServerOptions();
  bad.update.depth_fraction = 1.5f;
  EXPECT_FALSE(bad.Validate().ok());
  bad = ServerOptions();
  bad.update.method = ContinualMethod::kEWC;
  EXPECT_FALSE(bad.Validate().ok());
}

}  // namespace
}  // namespace clnerf
