// SetUpServerLogging: clnerf-server's logger. spdlog on stderr, as text or
// as JSON (one object per line: time, level, thread, msg).
//
// In JSON mode every line of stderr parses as JSON, whoever writes it:
// protobuf's own log messages go through spdlog (a protobuf log handler, in
// both modes), and anything else written straight to the process's stderr
// (libpng through OpenImageIO, gRPC, a stray fprintf) is captured through a
// pipe and re-logged as a JSON record at warning level ("stderr: ...").
// Message bytes that are not valid UTF-8 become U+FFFD.
//
// Thread-safety: call once, from main(), before any other thread logs.
#ifndef CLNERF_SERVER_LOG_SETUP_H_
#define CLNERF_SERVER_LOG_SETUP_H_

#include <string>

#include "absl/status/status.h"

namespace clnerf {

// `level`: trace|debug|info|warn|error; `format`: text|json.
absl::Status SetUpServerLogging(const std::string& level, const std::string& format);

}  // namespace clnerf

#endif  // CLNERF_SERVER_LOG_SETUP_H_
