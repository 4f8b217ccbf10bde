#include "client/verbs.h"

#include "client/commands.h"
#include "client/remote_commands.h"

namespace clnerf {

void RegisterVerbs(VerbSet* verbs) {
  // Local: the engine in-process.
  verbs->Add(BindTrain, RunTrain);
  verbs->Add(BindEval, RunEval);
  verbs->Add(BindBake, RunBake);
  verbs->Add(BindCheckPoses, RunCheckPoses);
  verbs->Add(BindRender, RunRender);  // Remote without --model.
  verbs->Add(BindDemo, RunDemo);
  verbs->Add(BindScans, RunScans);
  // Remote: a clnerf server.
  verbs->Add(BindUpload, RunUpload);
  verbs->Add(BindWatch, RunWatch);
  verbs->Add(BindJobs, RunJobs);
  verbs->Add(BindCancel, RunCancel);
  verbs->Add(BindVersions, RunVersions);
  verbs->Add(BindRollback, RunRollback);
  verbs->Add(BindInfo, RunInfo);
  verbs->Add(BindPlaces, RunPlaces);
  verbs->Add(BindCameras, RunCameras);
  verbs->Add(BindLocalize, RunLocalize);
  // Benchmarks.
  CLI::App* bench = verbs->app()->add_subcommand("bench", "Benchmarks (print figures and JSON)");
  bench->require_subcommand(1);
  verbs->Add(BindBenchServe, RunBenchServe, bench);
  verbs->Add(BindBenchPlaces, RunBenchPlaces, bench);
  verbs->Add(BindBenchRender, RunBenchRender, bench);
  verbs->Add(BindBenchContinual, RunBenchContinual, bench);
  verbs->Add(BindBenchScenes, RunBenchScenes, bench);
  verbs->Add(BindBenchStability, RunBenchStability, bench);
  verbs->Add(BindBenchRegister, RunBenchRegister, bench);
  verbs->Add(BindBenchRescan, RunBenchRescan, bench);
}

}  // namespace clnerf
