// proto_convert: where clnerf.v1 protobuf messages and the server's own types
// (jobs, versions, scan headers) meet. Cameras and statuses, which the client
// converts too, are in proto/wire/wire.h; ToGrpcStatus there is the single
// absl::Status -> grpc::Status conversion at the RPC boundary.
//
// Thread-safety: pure functions.
#ifndef CLNERF_SERVER_PROTO_CONVERT_H_
#define CLNERF_SERVER_PROTO_CONVERT_H_

#include "absl/status/statusor.h"
#include "clnerf/v1/clnerf.pb.h"
#include "core/data/camera.h"
#include "proto/wire/wire.h"
#include "grpcpp/support/status.h"
#include "server/jobs/job_tracker.h"
#include "server/places/model_host.h"
#include "server/store/scan_assembler.h"
#include "server/store/scan_store.h"
#include "server/store/version_store.h"

namespace clnerf {

// Cameras and statuses both ways: proto/wire/wire.h (shared with the client).


// The frames of a header with their declared sizes, cameras converted and
// checked; the sizes and names are checked by ScanAssembler::Begin.
absl::StatusOr<ScanHeaderDecl> HeaderFromProto(const v1::ScanHeader& header);

// A photo to localise: decoded, its intrinsics checked when given (unset or
// zero size = to be guessed). INVALID_ARGUMENT naming photo `index`.
absl::StatusOr<PhotoQuery> PhotoFromProto(const v1::Photo& photo, int index);
inline constexpr int kMaxLocalizePhotos = 32;

v1::Job ToProto(const JobStatus& job);
v1::LocalizeResponse ToProto(const LocalizeResult& result);
v1::Version ToProto(const VersionInfo& info, int64_t deployed_version);

}  // namespace clnerf

#endif  // CLNERF_SERVER_PROTO_CONVERT_H_
