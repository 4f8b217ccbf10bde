// How the remote verbs translate between core values and clnerf.v1 messages,
// and how message fields read to a person: camera specs, job phase names,
// timestamps, sizes and metric maps. Pure functions; thread-safe.
#ifndef CLNERF_CLIENT_REMOTE_FORMAT_H_
#define CLNERF_CLIENT_REMOTE_FORMAT_H_

#include <cstdint>
#include <string>

#include "clnerf/v1/clnerf.pb.h"
#include "core/data/camera.h"

namespace clnerf {


// "QUEUED", "TRAINING", ..., "DONE" (the enum name without its prefix).
std::string PhaseName(clnerf::v1::JobPhase phase);
// DONE, FAILED or CANCELLED.
bool IsTerminal(clnerf::v1::JobPhase phase);

// "2024-11-22 15:36:01" in local time; "-" for 0.
std::string FormatUnixMs(int64_t unix_ms);
// "812 B", "45.2 KB", "1.23 MB", "2.05 GB" (decimal units).
std::string FormatBytes(int64_t bytes);
// "psnr=27.31 ssim=0.9412" sorted by key; "-" when empty.
std::string FormatMetrics(const google::protobuf::Map<std::string, double>& metrics);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_REMOTE_FORMAT_H_
