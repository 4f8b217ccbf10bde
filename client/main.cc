// clnerf: command-line entry point. Flags are parsed here and only here.
#include <cstdio>
#include <utility>
#include <vector>

#include "CLI/CLI.hpp"
#include "client/commands.h"
#include "spdlog/sinks/stdout_color_sinks.h"
#include "spdlog/spdlog.h"

int main(int argc, char** argv) {
  using namespace clnerf;
  CLI::App app{"clnerf: continual NeRF on CPU (CLNeRF with an Instant-NGP backbone)"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "clnerf 0.1.0");
  std::string log_level = "info";
  app.add_option("--log-level", log_level, "trace|debug|info|warn|error|off")->capture_default_str();

  auto add_model_flags = [](CLI::App* c, ModelArgs* m) {
    c->add_option("--levels", m->levels, "Hash-grid levels (default 16)");
    c->add_option("--table-log2", m->log2_table_size, "log2 entries per level (default: derived from the scene)");
    c->add_option("--finest-res", m->finest_resolution, "Finest grid resolution (default: derived)");
    c->add_option("--steps-per-diagonal", m->steps_per_diagonal, "March steps across the box diagonal (default: derived)");
    c->add_option("--occupancy-res", m->occupancy_resolution, "Occupancy grid resolution (default: derived)");
    c->add_option("--cone-angle", m->cone_angle, "March cone angle (exponential steps; default: derived)");
    c->add_option("--near", m->near, "Near plane in model units (default: derived)");
    c->add_option("--occupancy-threshold", m->occupancy_threshold,
                  "Occupancy density threshold (default: 0.01 / minimum step)");
    c->add_option("--distortion", m->distortion,
                  "Distortion-loss weight (default: 0.01 for real captures, 0 for objects)");
    c->add_option("--near-density", m->near_density,
                  "Occlusion-penalty weight on density near the cameras (default: 0.01 for real captures, 0 for objects)");
    c->add_option("--near-density-distance", m->near_density_distance,
                  "Distance from the camera, in model units, within which density is penalised (default 0.2)");
    c->add_option("--near-density-fade", m->near_density_fade,
                  "Fade the occlusion penalty to 0 over this fraction of training (0 = constant)");
    c->add_flag("--random-background", m->random_background,
                "Real captures: train on random background colours");
    c->add_flag("--no-embed", m->no_embed, "Disable per-time-step embeddings");
  };
  // Flags of every verb that talks to a server. They are also accepted before
  // the verb (`clnerf --server H:P upload DIR`); a flag given after the verb
  // wins.
  std::vector<std::pair<CLI::App*, RemoteOptions*>> remote_verbs;
  auto add_remote_flags = [&remote_verbs](CLI::App* c, RemoteOptions* o) {
    remote_verbs.emplace_back(c, o);
    o->server = DefaultServer();
    o->token = DefaultToken();
    c->add_option("--server", o->server, "Server HOST:PORT (env CLNERF_SERVER)")->capture_default_str();
    c->add_option("--token", o->token, "Bearer token for uploads, cancels and rollbacks (env CLNERF_TOKEN)");
    c->add_option("--timeout", o->timeout_seconds,
                  "Deadline per RPC in seconds (default: 30 for calls, 600 for a render, none for streams)");
    c->add_option("--tls-ca", o->tls_ca, "PEM root certificate: connect with TLS");
    c->add_flag("--json", o->json, "Machine-readable JSON on stdout");
  };

  TrainArgs train;
  CLI::App* t = app.add_subcommand("train", "Train a model on a dataset (Blender, transforms.json, COLMAP or LLFF)");
  t->add_option("--data", train.data, "Dataset directory")->required();
  t->add_option("--out", train.out, "Output model file")->required();
  t->add_option("--iters", train.iterations, "Training steps")->capture_default_str();
  t->add_option("--seed", train.seed, "Random seed")->capture_default_str();
  t->add_option("--threads", train.threads, "Threads (0 = all cores)")->capture_default_str();
  t->add_option("--downscale", train.downscale, "Shrink images by this factor")->capture_default_str();
  t->add_option("--lr", train.learning_rate, "Initial learning rate")->capture_default_str();
  t->add_option("--batch-samples", train.target_samples, "Samples per batch (rays adapt)")->capture_default_str();
  t->add_option("--curve-every", train.curve_every, "Evaluate held-out views every N steps (PSNR-vs-time curve)");
  t->add_option("--curve-views", train.curve_views, "Held-out views per curve point")->capture_default_str();
  t->add_option("--json", train.json, "Write results as JSON to this file ('-' = stdout)");
  t->add_flag("!--no-eval", train.eval_after, "Skip the final test-split evaluation");
  t->add_flag("--fp16", train.fp16, "Save the parameters as fp16 (about half the file; relative error <= 2^-11)");
  add_model_flags(t, &train.model);

  EvalArgs eval;
  CLI::App* e = app.add_subcommand("eval", "Render a split and report PSNR/SSIM");
  e->add_option("--model", eval.model, "Model file")->required();
  e->add_option("--data", eval.data, "Dataset directory")->required();
  e->add_option("--split", eval.split, "train|val|test")->capture_default_str();
  e->add_option("--json", eval.json, "Write results as JSON to this file ('-' = stdout)");
  e->add_option("--save-dir", eval.save_dir, "Also write the renders here");
  e->add_option("--max-views", eval.max_views, "Evaluate an evenly spaced subset (0 = all)");
  e->add_option("--threads", eval.threads, "Threads (0 = all cores)");
  e->add_option("--downscale", eval.downscale, "Shrink images by this factor")->capture_default_str();

  RenderArgs render;
  CLI::App* r = app.add_subcommand(
      "render", "Render views to PNG: locally with --model, else on the server (remote flags apply)");
  r->add_option("--model", render.model, "Model file (omit to render on the server)");
  r->add_option("--out", render.out, "PNG file (one view) or directory")->required();
  r->add_option("--data,--views-from", render.data,
                "Take cameras from this dataset's split (remote: and score the renders against its images)");
  r->add_option("--camera-path", render.camera_path, "nerfstudio camera_path.json");
  r->add_option("--split", render.split, "train|val|test")->capture_default_str();
  r->add_option("--index", render.index, "Only this view of the split (-1 = all)")->capture_default_str();
  r->add_option("--pose", render.pose, "Camera-to-world matrix, OpenGL convention, 12 or 16 numbers row-major");
  r->add_option("--width", render.width, "Image width for --pose")->capture_default_str();
  r->add_option("--height", render.height, "Image height for --pose")->capture_default_str();
  r->add_option("--focal", render.focal, "Focal length in pixels for --pose (0 = NeRF-synthetic FOV)");
  r->add_option("--time-step", render.time_step, "Time step to render (-1 = latest)")->capture_default_str();
  r->add_option("--threads", render.threads, "Threads (0 = all cores)");
  r->add_option("--version", render.version, "Remote: model version (0 = the deployed one)")->capture_default_str();
  add_remote_flags(r, &render.remote);

  UploadArgs upload;
  CLI::App* up = app.add_subcommand("upload", "Upload a scan folder (Blender, transforms.json, COLMAP or LLFF) to the server");
  up->add_option("dir", upload.dir, "Dataset directory")->required();
  up->add_option("--name", upload.name, "Scan name (default: the folder's name)");
  up->add_option("--test-split", upload.test_split, "Held-out frames: test (falls back to val), val or none")
      ->capture_default_str();
  up->add_flag("--watch", upload.watch, "Then follow the update job until it ends");
  add_remote_flags(up, &upload.remote);

  JobArgs watch;
  CLI::App* w = app.add_subcommand("watch", "Follow an update job until it is done, failed or cancelled");
  w->add_option("job", watch.job_id, "Job id")->required();
  add_remote_flags(w, &watch.remote);

  ListArgs jobs;
  CLI::App* js = app.add_subcommand("jobs", "List the server's update jobs");
  add_remote_flags(js, &jobs.remote);

  JobArgs cancel;
  CLI::App* cj = app.add_subcommand("cancel", "Cancel a queued or running update job");
  cj->add_option("job", cancel.job_id, "Job id")->required();
  add_remote_flags(cj, &cancel.remote);

  ListArgs versions;
  CLI::App* vs = app.add_subcommand("versions", "List the server's model versions");
  add_remote_flags(vs, &versions.remote);

  RollbackArgs rollback;
  CLI::App* rb = app.add_subcommand("rollback", "Deploy an existing model version");
  rb->add_option("version", rollback.version, "Version to deploy")->required();
  add_remote_flags(rb, &rollback.remote);

  ListArgs info;
  CLI::App* in = app.add_subcommand("info", "Show the server's state and health");
  add_remote_flags(in, &info.remote);

  DemoArgs demo;
  CLI::App* d = app.add_subcommand("demo", "Engine-only demo: procedural scene -> train -> render -> PSNR in-process (no data needed)");
  d->add_option("--out", demo.out, "Output directory")->capture_default_str();
  d->add_option("--iters", demo.iterations, "Training steps")->capture_default_str();
  d->add_option("--size", demo.size, "Image size (pixels)")->capture_default_str();
  d->add_option("--seed", demo.seed, "Random seed")->capture_default_str();
  d->add_option("--threads", demo.threads, "Threads (0 = all cores)");
  d->add_flag("--thin", demo.thin, "Add thin rods (about a pixel wide) to the scene");
  d->add_flag("--backdrop", demo.backdrop,
              "Unbounded scene: ground plane, pillars and a far backdrop, trained in contracted space "
              "(the scene folder written is Blender format, which loads back as a bounded scene)");

  ScansArgs scans;
  CLI::App* sc = app.add_subcommand("scans", "Write scans of the procedural changing scene (one folder per scan, for upload)");
  sc->add_option("--out", scans.out, "Output directory")->capture_default_str();
  sc->add_option("--scans", scans.scans, "Number of scans (time steps)")->capture_default_str();
  sc->add_option("--size", scans.size, "Image size (pixels)")->capture_default_str();
  sc->add_option("--train-views", scans.train_views, "Training views per scan")->capture_default_str();
  sc->add_option("--test-views", scans.test_views, "Held-out views per scan")->capture_default_str();
  sc->add_option("--seed", scans.seed, "Random seed")->capture_default_str();
  sc->add_flag("--thin", scans.thin, "Add thin rods (about a pixel wide) to the scene");

  CLI::App* bench = app.add_subcommand("bench", "Benchmarks (print figures and JSON)");
  bench->require_subcommand(1);
  BenchServeArgs bench_serve;
  CLI::App* bs = bench->add_subcommand("serve", "Render latency (idle / during an update), upload throughput and "
                                                 "upload-to-served time against a running server");
  bs->add_option("--data", bench_serve.data, "Dataset cut into tasks (scans 0 and 1 are uploaded) or 'procedural'")
      ->capture_default_str();
  bs->add_option("--tasks", bench_serve.tasks, "Tasks to cut a static dataset into")->capture_default_str();
  bs->add_option("--sizes", bench_serve.sizes, "Comma-separated square render sizes")->capture_default_str();
  bs->add_option("--clients", bench_serve.clients, "Comma-separated concurrent client counts")->capture_default_str();
  bs->add_option("--renders", bench_serve.renders_per_client, "Requests per client per configuration")
      ->capture_default_str();
  bs->add_option("--store", bench_serve.store,
                 "The server's store directory: also time the same renders in-process (the 100x100 target)");
  bs->add_option("--json-out", bench_serve.json, "Write JSON here ('-' = stdout)");
  add_remote_flags(bs, &bench_serve.remote);

  BenchRenderArgs bench_render;
  CLI::App* br = bench->add_subcommand("render", "Time renders of test views at several sizes");
  br->add_option("--model", bench_render.model, "Model file")->required();
  br->add_option("--data", bench_render.data, "Dataset (cameras of its test split)")->required();
  br->add_option("--sizes", bench_render.sizes, "Comma-separated square sizes")->capture_default_str();
  br->add_option("--views", bench_render.views, "Views per size")->capture_default_str();
  br->add_option("--repeats", bench_render.repeats, "Renders per view (median kept)")->capture_default_str();
  br->add_option("--threads", bench_render.threads, "Threads (0 = all cores)");
  br->add_option("--json", bench_render.json, "Write JSON here");

  BenchContinualArgs bc;
  CLI::App* bcc = bench->add_subcommand("continual", "Run one continual method through every step of a scan sequence");
  bcc->add_option("--method", bc.method, "nt|ewc|er|meil|clnerf|clnerf-noer|ub")->capture_default_str();
  bcc->add_option("--data", bc.data,
                  "Static dataset (cut into --tasks), dataset with time steps, directory of scan folders, or "
                  "'procedural'")
      ->required();
  bcc->add_option("--tasks", bc.tasks, "Tasks for a static dataset / scans for 'procedural' (0 = 10 / 5)")
      ->capture_default_str();
  bcc->add_option("--iters", bc.iterations, "Training steps per update")->capture_default_str();
  bcc->add_option("--ub-budget", bc.ub_budget,
                  "ub's iterations: total (tasks x --iters, equal compute) | per-step (--iters, the paper's protocol)")
      ->capture_default_str();
  bcc->add_option("--init", bc.init, "reinit|warm: start each update from scratch or from the previous model")
      ->capture_default_str();
  bcc->add_option("--replay", bc.replay, "offline|online generative replay")->capture_default_str();
  bcc->add_option("--buffer", bc.buffer, "Real images kept for experience replay (clnerf, er)")->capture_default_str();
  bcc->add_flag("--prioritized", bc.prioritized, "Buffer keeps the lowest-PSNR images instead of a reservoir");
  bcc->add_flag("--no-embed", bc.no_embed, "Ablation: no per-time-step embeddings");
  bcc->add_option("--ewc-lambda", bc.ewc_lambda, "EWC strength")->capture_default_str();
  bcc->add_option("--warm-lr-scale", bc.warm_lr_scale, "Learning-rate factor for warm-started updates")
      ->capture_default_str();
  bcc->add_option("--new-share", bc.new_share,
                  "clnerf/clnerf-noer/er: fraction of each batch from the new scan (0 = uniform over all views)")
      ->capture_default_str();
  bcc->add_flag("--copy-embedding", bc.copy_embedding,
                "Warm start: the new time step's embeddings start as a copy of the last step's");
  bcc->add_option("--downscale", bc.downscale, "Shrink images by this factor")->capture_default_str();
  bcc->add_option("--procedural-size", bc.procedural_size, "Image size of the procedural scans")->capture_default_str();
  bcc->add_option("--seed", bc.seed, "Random seed")->capture_default_str();
  bcc->add_option("--threads", bc.threads, "Threads (0 = all cores)");
  bcc->add_option("--json", bc.json, "Write JSON here ('-' = stdout)");

  BenchScenesArgs bsc;
  CLI::App* bss = bench->add_subcommand(
      "scenes", "Scene suite: train (default flags) and evaluate each dataset; table, CSV and charts");
  bss->add_option("dirs", bsc.dirs, "Dataset directories")->required();
  bss->add_option("--out", bsc.out, "Output directory (models, JSON, CSV, markdown, PNG charts)")
      ->capture_default_str();
  bss->add_option("--iters", bsc.iterations, "Training steps per run (as `train`)")->capture_default_str();
  bss->add_flag("--capacity-sweep", bsc.capacity_sweep,
                "Also train with log2 tables derived-2..derived+1 (PSNR vs bytes chart)");
  bss->add_option("--threads", bsc.threads, "Threads (0 = all cores)");
  bss->add_option("--curve-every", bsc.curve_every, "PSNR-vs-time curve every N steps (default: iters / 10)");
  bss->add_option("--curve-views", bsc.curve_views, "Held-out views per curve point")->capture_default_str();
  bss->add_option("--train-views", bsc.train_views, "Training views for the train-view PSNR")->capture_default_str();
  bss->add_flag("--force", bsc.force, "Re-run configurations whose results are already in --out");

  BenchStabilityArgs bst;
  CLI::App* bstab = bench->add_subcommand(
      "stability", "Stability matrix: every continual method (and ub) against every stressor, through the deployment gate");
  bstab->add_option("--methods", bst.methods, "Methods (nt ewc er meil clnerf-noer clnerf ub)")->delimiter(',');
  bstab->add_option("--stressors", bst.stressors,
                    "Stressors (default all: none iters_x5 lr_x3 lr_x10 chain_20 blank_scan single_view far_cameras "
                    "nan_gradient stale_memory)")
      ->delimiter(',');
  bstab->add_option("--scans", bst.scans, "Scans of the procedural sequence (chain_20: 20)")->capture_default_str();
  bstab->add_option("--size", bst.size, "Image size of the procedural scans")->capture_default_str();
  bstab->add_option("--iters", bst.iterations, "Training steps per update (ub: scans x this)")->capture_default_str();
  bstab->add_option("--batch-samples", bst.batch_samples, "Samples per training batch (rays adapt)")
      ->capture_default_str();
  bstab->add_option("--seed", bst.seed, "Random seed")->capture_default_str();
  bstab->add_option("--threads", bst.threads, "Threads (0 = all cores)");
  bstab->add_option("--json", bst.json, "Write JSON here ('-' = stdout)");
  bstab->add_option("--markdown", bst.markdown, "Also write the markdown table here");

  RemoteOptions global_remote;
  add_remote_flags(&app, &global_remote);
  remote_verbs.pop_back();  // The app itself is not a verb.

  CLI11_PARSE(app, argc, argv);
  for (auto& [verb, opts] : remote_verbs) {
    if (!*verb) continue;
    const auto given = [&](const char* flag) { return app.count(flag) > 0 && verb->count(flag) == 0; };
    if (given("--server")) opts->server = global_remote.server;
    if (given("--token")) opts->token = global_remote.token;
    if (given("--timeout")) opts->timeout_seconds = global_remote.timeout_seconds;
    if (given("--tls-ca")) opts->tls_ca = global_remote.tls_ca;
    if (given("--json")) opts->json = true;
  }
  // Logs go to stderr so stdout carries only results (lines and JSON).
  spdlog::set_default_logger(spdlog::stderr_color_mt("clnerf"));
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");
  if (*t) return RunTrain(train);
  if (*e) return RunEval(eval);
  if (*r) return RunRender(render);
  if (*d) return RunDemo(demo);
  if (*sc) return RunScans(scans);
  if (*br) return RunBenchRender(bench_render);
  if (*bs) return RunBenchServe(bench_serve);
  if (*bcc) return RunBenchContinual(bc);
  if (*bss) return RunBenchScenes(bsc);
  if (*bstab) return RunBenchStability(bst);
  if (*up) return RunUpload(upload);
  if (*w) return RunWatch(watch);
  if (*js) return RunJobs(jobs);
  if (*cj) return RunCancel(cancel);
  if (*vs) return RunVersions(versions);
  if (*rb) return RunRollback(rollback);
  if (*in) return RunInfo(info);
  return 1;
}
