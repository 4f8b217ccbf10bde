// Gzip: whole-buffer gzip (RFC 1952) compression and decompression with
// zlib, for files that browsers decode themselves (DecompressionStream
// ("gzip")), such as baked assets.
//
// Stateless functions; thread-safe.
#ifndef CLNERF_CORE_IO_GZIP_H_
#define CLNERF_CORE_IO_GZIP_H_

#include <cstddef>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"

namespace clnerf {

// Gzip stream of `data` at zlib level `level` (1 fastest .. 9 smallest).
absl::StatusOr<std::string> GzipCompress(std::string_view data, int level = 6);

// The bytes of a gzip stream. DATA_LOSS for a corrupt or truncated stream;
// RESOURCE_EXHAUSTED when it would inflate beyond `max_bytes` (a hostile
// file cannot allocate more than that).
absl::StatusOr<std::string> GzipDecompress(std::string_view gz, size_t max_bytes);

}  // namespace clnerf

#endif  // CLNERF_CORE_IO_GZIP_H_
