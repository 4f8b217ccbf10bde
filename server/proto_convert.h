// proto_convert: the one place where clnerf.v1 protobuf messages and core /
// host types meet, plus ToGrpcStatus, the single absl::Status -> grpc::Status
// conversion at the RPC boundary (as TF Serving's ToGRPCStatus).
//
// Thread-safety: pure functions.
#ifndef CLNERF_SERVER_PROTO_CONVERT_H_
#define CLNERF_SERVER_PROTO_CONVERT_H_

#include "absl/status/statusor.h"
#include "clnerf/v1/clnerf.pb.h"
#include "core/camera.h"
#include "grpcpp/support/status.h"
#include "server/job_tracker.h"
#include "server/model_host.h"
#include "server/scan_assembler.h"
#include "server/scan_store.h"
#include "server/version_store.h"

namespace clnerf {

grpc::Status ToGrpcStatus(const absl::Status& status);

// Checks the pose (16 finite numbers, bottom row 0 0 0 1), the convention
// and the intrinsics; returns the camera in the internal OpenCV convention.
// `what` prefixes error messages (e.g. "frame 3").
absl::StatusOr<Camera> CameraFromProto(const v1::CameraSpec& spec, const std::string& what);

// The frames of a header with their declared sizes, cameras converted and
// checked; the sizes and names are checked by ScanAssembler::Begin.
absl::StatusOr<ScanHeaderDecl> HeaderFromProto(const v1::ScanHeader& header);

v1::Job ToProto(const JobStatus& job);
v1::Version ToProto(const VersionInfo& info, int64_t deployed_version);

}  // namespace clnerf

#endif  // CLNERF_SERVER_PROTO_CONVERT_H_
