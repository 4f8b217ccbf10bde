// `check-poses`: are a capture's poses right? Each frame's pose against its
// own photos (core/pose/pose_check.h), before anything trains on them.
#include <cstdio>
#include <set>

#include "client/commands.h"
#include "client/core_flags.h"
#include "core/data/dataset.h"
#include "core/pose/pose_check.h"
#include "core/pose/run_repair.h"
#include "nlohmann/json.hpp"
#include "spdlog/spdlog.h"

namespace clnerf {

nlohmann::json PoseCheckJson(const PoseCheckReport& r, const std::vector<View>& views) {
  nlohmann::json pairs = nlohmann::json::array();
  for (const PairCheck& p : r.pairs) {
    pairs.push_back({{"a", views[p.a].name},
                     {"b", views[p.b].name},
                     {"matches", p.matches},
                     {"inliers", p.inliers},
                     {"chance", p.chance_inliers},
                     {"disagreement_deg", p.disagreement_deg},
                     {"explained", p.explained},
                     {"disagrees", p.disagrees}});
  }
  nlohmann::json disputed = nlohmann::json::array();
  for (int i : r.disputed) disputed.push_back(views[i].name);
  return {{"frames", r.frames},
          {"pairs_tried", r.pairs_tried},
          {"pairs_matched", r.pairs.size()},
          {"disagreeing_pairs", r.disagreeing_pairs},
          {"explained_pairs", r.explained_pairs},
          {"pairs_below_chance", r.pairs_below_chance},
          {"conflicts", r.conflicts},
          {"continuity_links", r.continuity_links},
          {"inconclusive", r.inconclusive},
          {"median_agreeing_deg", r.median_agreeing_deg},
          {"disputed", disputed},
          {"unchecked", r.unchecked.size()},
          {"seconds", r.seconds},
          {"pairs", pairs}};
}

CLI::App* BindCheckPoses(CLI::App* parent, CheckPosesArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "check-poses", "Check a capture's poses against its own photos (frames posed turned against the rest)");
  c->add_option("--data", a->data, "Dataset directory")->required();
  c->add_option("--split", a->split, "all (train and test together, in name order), train or test")
      ->check(CLI::IsMember({"train", "test", "all"}))
      ->capture_default_str();
  c->add_option("--json", a->json, "Write the report as JSON to this file ('-' = stdout)");
  BindPoseCheckFlags(c, &a->check);
  BindThreadsFlag(c, &a->threads);
  BindDatasetFlags(c, &a->dataset);
  return c;
}

int RunCheckPoses(const CheckPosesArgs& a) {
  SetThreads(a.threads);
  absl::StatusOr<Scene> scene = LoadScene(a.data, a.dataset);
  if (!scene.ok()) return Fail(scene.status());
  const std::vector<View> views = a.split == "all" ? CaptureInOrder(*scene) : a.split == "train" ? scene->train : scene->test;
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, a.check, a.threads);
  if (!r.ok()) return Fail(r.status());
  std::printf("%s (%.1f s)\n", r->Summary(views).c_str(), r->seconds);
  if (absl::Status s = WriteJson(a.json, PoseCheckJson(*r, views)); !s.ok()) return Fail(s);
  return 0;
}

namespace {

// `--pose-check repair`: the disputed frames moved into the others' frame
// (core/pose/run_repair.h), then the capture checked again; kept only when
// that check disputes nothing. False (and nothing moved) otherwise.
bool RepairDisputed(const TrainArgs& a, const PoseCheckReport& r, const std::vector<View>& views,
                    const std::set<std::string>& disputed, Scene* scene, nlohmann::json* j) {
  absl::StatusOr<RunRepair> repair = SolveRunRepair(r, views);
  if (!repair.ok()) {
    spdlog::warn("pose check: cannot repair the disputed frames ({}); training with them as they came",
                 std::string(repair.status().message()));
    (*j)["repair"] = {{"repaired", false}, {"why", std::string(repair.status().message())}};
    return false;
  }
  ApplyRunRepair(*repair, disputed, scene);
  // Kept only if the capture then checks clean.
  absl::StatusOr<PoseCheckReport> again = CheckPoses(CaptureInOrder(*scene), a.check, a.fit.train.threads);
  const std::string after = again.ok() ? again->Summary() : std::string(again.status().message());
  const bool clean = again.ok() && again->disputed.empty() && !again->inconclusive;
  if (!clean) {
    RunRepair back = *repair;
    back.transform = repair->transform.Inverse();
    ApplyRunRepair(back, disputed, scene);
  }
  spdlog::warn("pose check: the {} disputed frames moved into the others' frame: {}; checked again: {}; {}",
               disputed.size(), repair->Summary(), after,
               clean ? "repair kept" : "repair undone, training with them as they came");
  (*j)["repair"] = {{"repaired", clean},
                    {"turn_deg", repair->turn_deg},
                    {"scale", repair->transform.scale},
                    {"pairs_used", repair->pairs_used},
                    {"crossing_pairs", repair->crossing_pairs},
                    {"rotation_spread_deg", repair->rotation_spread_deg},
                    {"centre_residual", repair->centre_residual},
                    {"check_after", after},
                    {"disputed_after", again.ok() ? int(again->disputed.size()) : -1}};
  return clean;
}

}  // namespace

absl::StatusOr<nlohmann::json> CheckTrainingPoses(const TrainArgs& a, Scene* scene,
                                                  std::set<std::string>* disputed_test,
                                                  std::vector<View>* given_test) {
  if (a.pose_check == "off" || scene->train.empty() || scene->train[0].image.width == 0) return nlohmann::json();
  const std::vector<View> views = CaptureInOrder(*scene);
  absl::StatusOr<PoseCheckReport> r = CheckPoses(views, a.check, a.fit.train.threads);
  if (!r.ok()) return r.status();
  const std::string summary = r->Summary(views);
  nlohmann::json j = PoseCheckJson(*r, views);
  j["action"] = a.pose_check;
  const std::set<std::string> disputed = DisputedNames(*r, views);
  for (const View& v : scene->test) {
    if (disputed.count(v.name)) disputed_test->insert(v.name);
  }
  if (disputed.empty()) {
    spdlog::info("pose check: {} ({:.1f} s)", summary, r->seconds);
    return j;
  }
  spdlog::warn("pose check: {} ({:.1f} s). These frames' poses disagree with their photos and with the rest of the "
               "capture (often a run that structure from motion turned about a scene that looks alike from opposite "
               "sides); {}", summary, r->seconds,
               a.pose_check == "drop"     ? "training without them"
               : a.pose_check == "repair" ? "moving them into the others' frame"
                                          : "training with them anyway (--pose-check repair or drop)");
  if (a.pose_check == "repair" && !r->inconclusive) {
    const std::vector<View> test = scene->test;
    if (RepairDisputed(a, *r, views, disputed, scene, &j)) {
      *given_test = test;
      disputed_test->clear();
    }
  }
  if (a.pose_check == "drop") j["dropped_train_views"] = DropViewsNamed(disputed, &scene->train);
  return j;
}

}  // namespace clnerf
