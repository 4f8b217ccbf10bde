#include "client/job_watch.h"

#include <algorithm>
#include <cstdio>
#include <memory>

#include "absl/strings/str_format.h"
#include "client/progress_bar.h"
#include "client/proto_json.h"
#include "client/remote_format.h"
#include "spdlog/spdlog.h"

namespace clnerf {
namespace {

using clnerf::v1::Job;

std::string TrainMetrics(const Job& job) { return absl::StrFormat("loss %.5f | psnr %.2f", job.loss(), job.psnr()); }

// The log line for entering the job's current phase.
void LogPhase(const Job& job) {
  std::string detail;
  switch (job.phase()) {
    case clnerf::v1::JOB_PHASE_QUEUED:
      detail = absl::StrFormat(" (scan %s '%s', time step %d)", job.scan_id(), job.scan_name(), job.time_step());
      break;
    case clnerf::v1::JOB_PHASE_TRAINING:
      detail = absl::StrFormat(" (%d iterations)", job.total_iterations());
      break;
    case clnerf::v1::JOB_PHASE_FAILED:
      detail = ": " + job.error();
      break;
    default:
      break;
  }
  spdlog::info("job {}: {}{}", job.job_id(), PhaseName(job.phase()), detail);
}

}  // namespace

WatchOutcome FollowJob(RemoteClient& client, const std::string& job_id, const std::string& place) {
  WatchOutcome out;
  std::unique_ptr<grpc::ClientContext> ctx = client.Context(kNoDeadline);
  clnerf::v1::WatchJobRequest request;
  request.set_job_id(job_id);
  request.set_place(place);
  std::unique_ptr<grpc::ClientReader<Job>> reader = client.service().WatchJob(ctx.get(), request);
  std::unique_ptr<ProgressBar> bar;
  bool first = true;
  Job job;
  while (reader->Read(&job)) {
    const bool phase_changed = first || job.phase() != out.job.phase();
    first = false;
    if (phase_changed) {
      if (bar) {
        if (job.phase() == clnerf::v1::JOB_PHASE_FAILED || job.phase() == clnerf::v1::JOB_PHASE_CANCELLED) bar->Abort();
        else if (out.job.phase() == clnerf::v1::JOB_PHASE_REGISTERING) bar->Finish("frames localised");
        else if (out.job.phase() == clnerf::v1::JOB_PHASE_POSING) bar->Finish("posed");
        else bar->Finish(TrainMetrics(out.job));
        bar.reset();
      }
      LogPhase(job);
    }
    out.job = job;
    if (job.phase() == clnerf::v1::JOB_PHASE_POSING && job.total_iterations() > 0) {
      static const char* kStages[] = {"finding features", "matching photos", "building the model"};
      if (!bar) bar = std::make_unique<ProgressBar>("pose", job.total_iterations());
      bar->SetTiming(job.elapsed_seconds(), job.eta_seconds());
      bar->Update(job.iteration(), std::string("COLMAP: ") + kStages[std::clamp(job.iteration(), 0, 2)]);
    }
    if (job.phase() == clnerf::v1::JOB_PHASE_REGISTERING && job.total_iterations() > 0) {
      if (!bar) bar = std::make_unique<ProgressBar>("register", job.total_iterations());
      bar->SetTiming(job.elapsed_seconds(), job.eta_seconds());
      bar->Update(job.iteration(), "frames localised against the place's model");
    }
    if (job.phase() == clnerf::v1::JOB_PHASE_TRAINING && job.total_iterations() > 0) {
      if (!bar) bar = std::make_unique<ProgressBar>("train", job.total_iterations());
      bar->SetTiming(job.elapsed_seconds(), job.eta_seconds());
      bar->Update(job.iteration(), TrainMetrics(job));
    }
    if (IsTerminal(job.phase())) {
      out.ended = true;
      break;
    }
  }
  if (bar) bar->Abort();
  if (out.ended) {
    // The server closes the stream after a terminal state; do not wait for it.
    ctx->TryCancel();
    reader->Finish();
    out.status = grpc::Status::OK;
  } else {
    out.status = reader->Finish();
    if (out.status.ok()) {
      out.status = grpc::Status(grpc::StatusCode::ABORTED,
                                absl::StrFormat("the server closed the watch of job %s before it finished (last "
                                                "phase %s)",
                                                job_id, first ? "none" : PhaseName(out.job.phase())));
    }
  }
  return out;
}

int ReportJob(const std::string& verb, const WatchOutcome& outcome, const RemoteOptions& options,
              nlohmann::json extra) {
  if (!outcome.ended) return FailRemote(verb, outcome.status, options);
  const Job& job = outcome.job;
  if (options.json) {
    nlohmann::json j = ProtoToJson(job);
    if (extra.is_object()) {
      extra["job"] = j;
      j = extra;
    }
    std::printf("%s\n", j.dump(2).c_str());
  }
  switch (job.phase()) {
    case clnerf::v1::JOB_PHASE_DONE: {
      if (!options.json) {
        const double secs = job.finished_unix_ms() > job.created_unix_ms()
                                ? (job.finished_unix_ms() - job.created_unix_ms()) / 1e3
                                : job.elapsed_seconds();
        std::printf("job %s done: version %lld (time step %d, %s) | gate %s\n", job.job_id().c_str(),
                    (long long)job.version(), job.time_step(), FormatDuration(secs).c_str(),
                    FormatMetrics(job.metrics()).c_str());
      }
      return 0;
    }
    case clnerf::v1::JOB_PHASE_FAILED:
      std::fprintf(stderr, "clnerf %s: job %s FAILED: %s\n", verb.c_str(), job.job_id().c_str(),
                   job.error().empty() ? "(no reason given)" : job.error().c_str());
      return kExitJobFailed;
    default:
      std::fprintf(stderr, "clnerf %s: job %s CANCELLED%s\n", verb.c_str(), job.job_id().c_str(),
                   job.error().empty() ? "" : (": " + job.error()).c_str());
      return kExitJobCancelled;
  }
}

}  // namespace clnerf
