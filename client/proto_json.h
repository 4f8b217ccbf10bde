// ProtoToJson: a protobuf message as nlohmann::json for the CLI's --json
// output. Unlike protobuf's canonical JSON mapping it keeps the .proto field
// names, prints 64-bit integers as JSON numbers (not strings) so that scripts
// can compare versions and sizes directly, prints every field including
// defaults (proto3 `optional` scalars only when set, unset sub-messages as
// null), writes enums by name ("JOB_PHASE_DONE") and bytes fields as their
// length ("<name>_bytes"), since --json never carries image data. Pure
// function; thread-safe.
#ifndef CLNERF_CLIENT_PROTO_JSON_H_
#define CLNERF_CLIENT_PROTO_JSON_H_

#include "google/protobuf/message.h"
#include "nlohmann/json.hpp"

namespace clnerf {

nlohmann::json ProtoToJson(const google::protobuf::Message& message);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_PROTO_JSON_H_
