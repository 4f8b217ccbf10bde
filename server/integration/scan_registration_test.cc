// The update worker registers each later scan into its place's frame, with
// the place's deployed model as the map: a scan moved into its own frame by
// a random similarity trains in the place's frame; a scan of another place
// is refused, parked, and nothing is published.
#include <cmath>
#include <filesystem>
#include <random>

#include "core/data/procedural_scene.h"
#include "core/pose/similarity.h"
#include "Eigen/Geometry"
#include "gtest/gtest.h"
#include "server/testing/server_fixture.h"

namespace clnerf {
namespace {

using testing_util::ServerFixture;
using testing_util::TempDir;
using testing_util::TinyServerOptions;
using testing_util::UploadMessages;
using testing_util::UploadOf;

// Textured objects before a backdrop seen by a forward-facing rig; at step
// 1 objects are removed, added and recoloured.
Scene ChangingScans(ProceduralLayout layout, uint64_t seed) {
  ProceduralSceneOptions o;
  o.layout = layout;
  o.textured = true;
  o.seed = seed;
  o.width = 160;
  o.height = 120;
  o.num_train_views = 20;
  o.num_test_views = 2;
  o.num_time_steps = 2;
  o.change_lighting = false;
  absl::StatusOr<Scene> s = GenerateProceduralScene(o);
  EXPECT_TRUE(s.ok()) << s.status();
  return *s;
}

TEST_F(ServerFixture, LaterScansAreRegisteredIntoThePlacesFrame) {
  const std::string store = TempDir("srv_registration");
  // θ_0 trains 800 small-batch iterations (the map), the update 100: this
  // test checks the worker's path (phase, refusal, parking, metrics, the
  // transform applied before training). The registration's accuracy is
  // checked against an exact map in core/pose/registration_test.cc and on
  // real captures by `clnerf bench register`; a map this blurry places the
  // frames within a few percent.
  ServerOptions o = TinyServerOptions(store, 100);
  o.first_scan_iterations = 800;
  o.update.model.grid.levels = 12;
  o.update.capacity.max_log2_table_size = 16;
  o.gate.min_new_psnr = 12.0f;
  StartServer(o);
  const Scene scene = ChangingScans(ProceduralLayout::kForwardFacing, 3);
  ScanUpload first = UploadOf(scene, 0);
  first.scene_kind = "unbounded";
  v1::UploadScanResponse ack;
  ASSERT_TRUE(Upload(UploadMessages(first), &ack).ok());
  v1::Job j = Watch(ack.job_id());
  ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();

  // A scan of another place (the procedural room) in its own frame: refused
  // with the registration's diagnostics, parked, nothing published.
  const Scene room = ChangingScans(ProceduralLayout::kRoom, 9);
  ScanUpload other = UploadOf(room, 0);
  other.pose_frame = "own";
  ASSERT_TRUE(Upload(UploadMessages(other), &ack).ok());
  j = Watch(ack.job_id());
  EXPECT_EQ(j.phase(), v1::JOB_PHASE_FAILED);
  EXPECT_NE(j.error().find("FAILED_PRECONDITION: the scan could not be placed"), std::string::npos) << j.error();
  EXPECT_NE(j.error().find("frames localised"), std::string::npos) << j.error();
  EXPECT_EQ(Versions().size(), 1u);
  EXPECT_TRUE(std::filesystem::exists(store + "/parked/" + ack.scan_id())) << ack.scan_id();

  // The next visit (objects moved) in its own frame: a rotation, scale and
  // shift away from the place's.
  Similarity moved;
  moved.rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.2, -0.5, 1).normalized()).toRotationMatrix();
  moved.scale = 1.7;
  moved.translation = Eigen::Vector3d(2, -1, 0.5);
  ScanUpload second = UploadOf(scene, 1);
  second.pose_frame = "own";
  for (ScanFrame& f : second.frames) f.camera.c2w = moved.ApplyToPose(f.camera.c2w);
  ASSERT_TRUE(Upload(UploadMessages(second), &ack).ok());
  j = Watch(ack.job_id());
  ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
  ASSERT_TRUE(j.metrics().count("registration_scale"));
  // Its poses were checked against its photos first (a similarity moves no
  // frame against another: nothing disputed).
  ASSERT_TRUE(j.metrics().count("pose_check_pairs"));
  EXPECT_EQ(j.metrics().at("pose_check_disputed"), 0.0);
  // The registration found (roughly) the inverse of `moved`.
  EXPECT_NEAR(j.metrics().at("registration_scale"), 1.0 / moved.scale, 0.1 / moved.scale);
  EXPECT_NEAR(j.metrics().at("registration_rotation_deg"), moved.RotationDegrees(), 3.0);
  EXPECT_EQ(j.metrics().at("registration_identity"), 0.0);
  EXPECT_GE(j.metrics().at("registration_frames_agreeing"), 3.0);
  // Then its whole similarity was refined against the map's renders (taken
  // or refused: this map is blurry; PhotometricSimilarityTest checks it).
  ASSERT_TRUE(j.metrics().count("registration_similarity_refined"));
  EXPECT_LT(j.metrics().at("registration_similarity_refine_deg"), 2.0);
  EXPECT_EQ(Versions().size(), 2u);
}

}  // namespace
}  // namespace clnerf
