// Remote verbs on update jobs: watch, jobs, cancel.
#include <cstdio>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/job_watch.h"
#include "client/verb_set.h"
#include "client/progress_bar.h"
#include "client/proto_json.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/remote_format.h"
#include "client/text_table.h"

namespace clnerf {

CLI::App* BindWatch(CLI::App* parent, JobArgs* a) {
  CLI::App* c = parent->add_subcommand("watch", "Follow an update job until it is done, failed or cancelled");
  c->add_option("job", a->job_id, "Job id")->required();
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunWatch(const JobArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("watch", client.status());
  return ReportJob("watch", FollowJob(**client, a.job_id, a.remote.place), a.remote);
}

CLI::App* BindJobs(CLI::App* parent, ListArgs* a) {
  CLI::App* c = parent->add_subcommand("jobs", "List the server's update jobs");
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunJobs(const ListArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("jobs", client.status());
  // Every page, so the list is complete however long the history is.
  clnerf::v1::ListJobsResponse response;
  clnerf::v1::ListJobsRequest request;
  request.set_page_size(1000);
  request.set_place(a.remote.place);
  while (true) {
    clnerf::v1::ListJobsResponse page;
    grpc::Status s = (*client)->service().ListJobs((*client)->Context(kUnaryTimeoutSeconds).get(), request, &page);
    if (!s.ok()) return FailRemote("jobs", s, a.remote);
    for (clnerf::v1::Job& j : *page.mutable_jobs()) *response.add_jobs() = std::move(j);
    response.set_total_jobs(page.total_jobs());
    if (page.next_page_token().empty()) break;
    request.set_page_token(page.next_page_token());
  }
  if (a.remote.json) {
    std::printf("%s\n", ProtoToJson(response).dump(2).c_str());
    return 0;
  }
  if (response.jobs().empty()) {
    std::printf("no jobs\n");
    return 0;
  }
  TextTable table({"JOB", "SCAN", "NAME", "PHASE", "STEP", "PROGRESS", "VERSION", "CREATED", "RESULT"});
  for (const clnerf::v1::Job& j : response.jobs()) {
    const std::string progress =
        j.total_iterations() > 0 ? absl::StrFormat("%d/%d", j.iteration(), j.total_iterations()) : "-";
    std::string result = "-";
    if (j.phase() == clnerf::v1::JOB_PHASE_FAILED || j.phase() == clnerf::v1::JOB_PHASE_CANCELLED) {
      result = j.error().empty() ? "-" : j.error();
    } else if (!j.metrics().empty()) {
      result = FormatMetrics(j.metrics());
    } else if (j.phase() == clnerf::v1::JOB_PHASE_TRAINING) {
      result = absl::StrFormat("loss %.5f psnr %.2f eta %s", j.loss(), j.psnr(), FormatDuration(j.eta_seconds()));
    }
    table.AddRow({j.job_id(), j.scan_id(), j.scan_name().empty() ? "-" : j.scan_name(), PhaseName(j.phase()),
                  absl::StrCat(j.time_step()), progress, j.version() > 0 ? absl::StrCat(j.version()) : "-",
                  FormatUnixMs(j.created_unix_ms()), result});
  }
  table.Print();
  return 0;
}

CLI::App* BindCancel(CLI::App* parent, JobArgs* a) {
  CLI::App* c = parent->add_subcommand("cancel", "Cancel a queued or running update job");
  c->add_option("job", a->job_id, "Job id")->required();
  BindRemoteFlags(c, &a->remote);
  return c;
}

int RunCancel(const JobArgs& a) {
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("cancel", client.status());
  clnerf::v1::CancelJobRequest request;
  request.set_job_id(a.job_id);
  request.set_place(a.remote.place);
  clnerf::v1::Job job;
  grpc::Status s = (*client)->service().CancelJob((*client)->Context(kUnaryTimeoutSeconds).get(), request, &job);
  if (!s.ok()) return FailRemote("cancel", s, a.remote);
  if (a.remote.json) std::printf("%s\n", ProtoToJson(job).dump(2).c_str());
  else if (IsTerminal(job.phase())) std::printf("job %s: %s\n", job.job_id().c_str(), PhaseName(job.phase()).c_str());
  else std::printf("job %s: cancel requested (now %s)\n", job.job_id().c_str(), PhaseName(job.phase()).c_str());
  return 0;
}

}  // namespace clnerf
