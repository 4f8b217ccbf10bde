// Durable files: the small set of POSIX file operations that crash-safe
// storage needs (checkpoints, the server's scans, versions and manifest).
//
// AtomicWriteFile writes to a temporary sibling, fsyncs it, renames it over
// the target and fsyncs the directory, so a reader (or a crash) sees either
// the old or the new content, never a mix. WriteFileSynced is for files inside
// a directory that is itself published by a rename. All functions are
// stateless and thread-safe; concurrent writers to one path: last rename wins.
#ifndef CLNERF_CORE_DURABLE_FILE_H_
#define CLNERF_CORE_DURABLE_FILE_H_

#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace clnerf {

// Creates/truncates `path`, writes `data`, fsyncs and closes it.
absl::Status WriteFileSynced(const std::string& path, std::string_view data);
// Atomic replace as described above.
absl::Status AtomicWriteFile(const std::string& path, std::string_view data);
// fsync of a directory (so renames and creations in it are durable). File
// systems that cannot sync directories are not an error.
absl::Status SyncDirectory(const std::string& dir);
// The parent directory of `path` ("." if none).
std::string DirectoryOf(const std::string& path);
// Reads a whole file. NOT_FOUND names `what` (e.g. "checkpoint").
absl::StatusOr<std::string> ReadFileToString(const std::string& path, absl::string_view what = "file");

}  // namespace clnerf

#endif  // CLNERF_CORE_DURABLE_FILE_H_
