// The CLI's verbs: flags land on the core Options fields they name, defaults
// are the core defaults (or the verb's stated own), bad values are refused,
// and remote flags given before the verb reach it.
#include "client/verb_set.h"

#include <string>

#include "client/commands.h"
#include "client/remote_commands.h"
#include "client/verbs.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

// Parses `line` (without the program name) into a fresh app holding one verb.
template <class Args>
Args Parse(CLI::App* (*bind)(CLI::App*, Args*), const std::string& line) {
  CLI::App app;
  Args args;
  bind(&app, &args);
  app.parse(line, false);
  return args;
}

TEST(VerbSetTest, TrainFlagsLandOnFitAndDatasetOptions) {
  const TrainArgs a = Parse(BindTrain,
                            "train --data d --out m.clnerf --iters 7 --seed 3 --lr 0.02 --levels 12 --table-log2 13 "
                            "--cone-angle 0 --distortion 0.5 --no-embed --random-background --downscale 2 "
                            "--test-every 4 --no-eval");
  EXPECT_EQ(a.data, "d");
  EXPECT_EQ(a.out, "m.clnerf");
  EXPECT_FALSE(a.eval_after);
  EXPECT_EQ(a.fit.train.iterations, 7);
  EXPECT_EQ(a.fit.train.seed, 3u);
  EXPECT_FLOAT_EQ(a.fit.train.learning_rate, 0.02f);
  EXPECT_EQ(a.fit.model.grid.levels, 12);
  ASSERT_TRUE(a.fit.overrides.log2_table_size.has_value());
  EXPECT_EQ(*a.fit.overrides.log2_table_size, 13);
  ASSERT_TRUE(a.fit.overrides.cone_angle.has_value());  // A given 0 is a value.
  EXPECT_EQ(*a.fit.overrides.cone_angle, 0.0f);
  EXPECT_FALSE(a.fit.overrides.finest_resolution.has_value());
  EXPECT_FLOAT_EQ(a.fit.train.distortion_reg, 0.5f);
  EXPECT_FALSE(a.fit.model.network.use_embeddings);
  EXPECT_TRUE(a.fit.train.random_background);
  EXPECT_FLOAT_EQ(a.dataset.downscale, 2.0f);
  EXPECT_EQ(a.dataset.test_every, 4);
}

TEST(VerbSetTest, UnsetTrainFlagsKeepTheCoreDefaults) {
  const TrainArgs a = Parse(BindTrain, "train --data d --out m");
  const FitOptions core;
  EXPECT_EQ(a.fit.train.iterations, core.train.iterations);
  EXPECT_EQ(a.fit.train.learning_rate, core.train.learning_rate);
  EXPECT_EQ(a.fit.train.target_samples, core.train.target_samples);
  EXPECT_EQ(a.fit.train.distortion_reg, core.train.distortion_reg);
  EXPECT_EQ(a.fit.train.near_density_distance, core.train.near_density_distance);
  EXPECT_EQ(a.fit.model.grid.levels, core.model.grid.levels);
  EXPECT_EQ(a.fit.model.network.use_embeddings, core.model.network.use_embeddings);
  EXPECT_TRUE(a.fit.overrides.empty());
  EXPECT_TRUE(a.fit.derive_capacity);
  EXPECT_EQ(a.dataset.downscale, DatasetOptions{}.downscale);
  EXPECT_TRUE(a.eval_after);
  EXPECT_TRUE(a.fit.Validate().ok());
}

TEST(VerbSetTest, MissingRequiredAndMalformedFlagsAreRefused) {
  EXPECT_THROW(Parse(BindTrain, "train --data d"), CLI::RequiredError);
  EXPECT_THROW(Parse(BindTrain, "train --data d --out m --iters many"), CLI::ConversionError);
}

TEST(VerbSetTest, ContinualBenchBindsUpdateOptionsAndEnums) {
  const BenchContinualArgs a =
      Parse(BindBenchContinual,
            "continual --data procedural --init reinit --replay online --ub-budget per-step --buffer 3 "
            "--ewc-lambda 5 --new-share 0.3 --copy-embedding --iters 40 --seed 9 --carry-optimizer "
            "--lr-schedule inverse-sqrt-cosine --lr-timescale 500 --paper-protocol");
  EXPECT_TRUE(a.update.carry_optimizer);
  EXPECT_EQ(a.update.train.lr_schedule, LrSchedule::kInverseSqrtCosine);
  EXPECT_EQ(a.update.train.lr_timescale, 500);
  EXPECT_TRUE(a.paper_protocol);
  EXPECT_FALSE(Parse(BindBenchContinual, "continual --data procedural --fresh-optimizer").update.carry_optimizer);
  EXPECT_EQ(a.update.init, InitMode::kReinit);
  EXPECT_EQ(a.update.replay, ReplayMode::kOnline);
  EXPECT_EQ(a.ub_budget, UbBudget::kPerStep);
  EXPECT_EQ(a.update.buffer_size, 3);
  EXPECT_FLOAT_EQ(a.update.ewc_lambda, 5.0f);
  EXPECT_FLOAT_EQ(a.update.new_scan_share, 0.3f);
  EXPECT_TRUE(a.update.copy_embedding);
  EXPECT_EQ(a.update.train.iterations, 40);
  EXPECT_EQ(a.update.train.seed, 9u);

  const BenchContinualArgs d = Parse(BindBenchContinual, "continual --data procedural");
  const UpdateOptions core;
  EXPECT_EQ(d.update.init, core.init);
  EXPECT_EQ(d.update.replay, core.replay);
  EXPECT_EQ(d.update.buffer_size, core.buffer_size);
  EXPECT_EQ(d.update.ewc_lambda, core.ewc_lambda);
  EXPECT_EQ(d.update.new_scan_share, core.new_scan_share);
  EXPECT_EQ(d.update.carry_optimizer, core.carry_optimizer);
  EXPECT_EQ(d.update.train.lr_schedule, core.train.lr_schedule);
  EXPECT_FALSE(d.paper_protocol);
  EXPECT_EQ(d.update.train.iterations, 300);  // The verb's own default.
  EXPECT_EQ(d.ub_budget, UbBudget::kTotal);

  EXPECT_THROW(Parse(BindBenchContinual, "continual --data procedural --init bogus"), CLI::ValidationError);
  EXPECT_THROW(Parse(BindBenchContinual, "continual --data procedural --replay 1"), CLI::ValidationError);
  EXPECT_THROW(Parse(BindBenchContinual, "continual --data procedural --lr-schedule linear"), CLI::ValidationError);
}

TEST(VerbSetTest, DemoSizeAndSeedSetEveryFieldTheyName) {
  const DemoArgs a = Parse(BindDemo, "demo --size 24 --seed 5 --iters 9 --thin");
  EXPECT_EQ(a.scene.width, 24);
  EXPECT_EQ(a.scene.height, 24);
  EXPECT_EQ(a.scene.seed, 5u);
  EXPECT_EQ(a.fit.train.seed, 5u);
  EXPECT_EQ(a.fit.train.iterations, 9);
  EXPECT_TRUE(a.scene.thin_structures);
  const ScansArgs s = Parse(BindScans, "scans --scans 4 --size 16");
  EXPECT_EQ(s.scene.num_time_steps, 4);
  EXPECT_EQ(s.scene.width, 16);
  EXPECT_EQ(s.scene.height, 16);
  EXPECT_TRUE(s.scene.Validate().ok());
}

TEST(VerbSetTest, RenderReadsItsDatasetAsTrainDoes) {
  const RenderArgs a = Parse(BindRender, "render --out o --data d --test-every 4 --images-dir images_2 --downscale 2");
  EXPECT_EQ(a.dataset.test_every, 4);
  EXPECT_EQ(a.dataset.images_dir, "images_2");
  EXPECT_FLOAT_EQ(a.dataset.downscale, 2.0f);
  EXPECT_TRUE(a.model.empty());  // Remote mode.
}

TEST(VerbSetTest, StabilityBenchBindsStabilityOptions) {
  const BenchStabilityArgs a =
      Parse(BindBenchStability, "stability --methods nt,clnerf --stressors none,lr_x10 --scans 2 --size 16 --iters 5");
  EXPECT_EQ(a.methods, (std::vector<std::string>{"nt", "clnerf"}));
  EXPECT_EQ(a.stressors, (std::vector<std::string>{"none", "lr_x10"}));
  EXPECT_EQ(a.stability.scans, 2);
  EXPECT_EQ(a.stability.image_size, 16);
  EXPECT_EQ(a.stability.iterations, 5);
  EXPECT_EQ(a.stability.batch_samples, StabilityOptions{}.batch_samples);
}

// A remote verb that records what it ran with.
struct FakeRemoteArgs {
  RemoteOptions remote;
};
RemoteOptions g_seen;
CLI::App* BindFake(CLI::App* parent, FakeRemoteArgs* a) {
  CLI::App* c = parent->add_subcommand("fake", "test verb");
  BindRemoteFlags(c, &a->remote);
  return c;
}
int RunFake(const FakeRemoteArgs& a) {
  g_seen = a.remote;
  return 7;
}

int RunLine(const std::string& line) {
  CLI::App app;
  VerbSet verbs(&app);
  verbs.Add(BindFake, RunFake);
  app.parse(line, false);
  return verbs.RunChosen();
}

TEST(VerbSetTest, RemoteFlagsBeforeTheVerbReachItAndFlagsAfterItWin) {
  g_seen = {};
  EXPECT_EQ(RunLine("--server a:1 --token t --timeout 2.5 --json fake"), 7);
  EXPECT_EQ(g_seen.server, "a:1");
  EXPECT_EQ(g_seen.token, "t");
  EXPECT_DOUBLE_EQ(g_seen.timeout_seconds, 2.5);
  EXPECT_TRUE(g_seen.json);

  g_seen = {};
  EXPECT_EQ(RunLine("--server a:1 fake --server b:2"), 7);
  EXPECT_EQ(g_seen.server, "b:2");
  EXPECT_FALSE(g_seen.json);

  g_seen = {};
  EXPECT_EQ(RunLine("fake"), 7);
  EXPECT_EQ(g_seen.server, DefaultServer());
}

TEST(VerbSetTest, EveryVerbRegistersWithoutClashingFlags) {
  CLI::App app;
  VerbSet verbs(&app);
  // Duplicate flag names within a verb would throw CLI::OptionAlreadyAdded.
  ASSERT_NO_THROW(RegisterVerbs(&verbs));
  for (const char* name : {"train", "eval", "render", "demo", "scans", "upload", "watch", "jobs", "cancel", "versions",
                           "rollback", "info", "bench"}) {
    EXPECT_NO_THROW(app.get_subcommand(name)) << name;
  }
  CLI::App* bench = app.get_subcommand("bench");
  for (const char* name : {"serve", "places", "render", "continual", "scenes", "stability"}) {
    EXPECT_NO_THROW(bench->get_subcommand(name)) << name;
  }
  // A verb that was not chosen does not run.
  EXPECT_EQ(verbs.RunChosen(), 1);
}

}  // namespace
}  // namespace clnerf
