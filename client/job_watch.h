// Following a server-side update job (clnerf.v1 WatchJob) from the CLI, shared
// by `clnerf watch` and `clnerf upload --watch`: a training progress bar
// (iteration / total, the server's elapsed time and ETA, loss, PSNR) and one
// log line per phase change on stderr, then the job's outcome as a result line
// (or JSON) on stdout and an exit code. Not thread-safe (CLI entry points).
#ifndef CLNERF_CLIENT_JOB_WATCH_H_
#define CLNERF_CLIENT_JOB_WATCH_H_

#include <string>

#include "client/remote_client.h"
#include "nlohmann/json.hpp"

namespace clnerf {

struct WatchOutcome {
  grpc::Status status;      // The stream's status (OK when the job ended).
  clnerf::v1::Job job;      // The last state received.
  bool ended = false;       // `job` is DONE, FAILED or CANCELLED.
};

// Streams the job's states until it reaches a terminal phase or the stream
// ends (no deadline unless --timeout was given).
WatchOutcome FollowJob(RemoteClient& client, const std::string& job_id, const std::string& place = "");

// Prints the outcome and returns the exit code: 0 for DONE ("job <id> done:
// version <v> ..."), kExitJobFailed / kExitJobCancelled with a one-line
// reason on stderr, 1 when the stream broke. With --json the final Job goes
// to stdout (as `extra["job"]` next to `extra`'s other keys when `extra` is
// an object, e.g. the upload's response).
int ReportJob(const std::string& verb, const WatchOutcome& outcome, const RemoteOptions& options,
              nlohmann::json extra = nullptr);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_JOB_WATCH_H_
