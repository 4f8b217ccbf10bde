// Durable files: the small set of POSIX file operations that crash-safe
// storage needs (checkpoints, the server's scans, versions and manifest).
//
// AtomicWriteFile writes to a temporary sibling, fsyncs it, renames it over
// the target and fsyncs the directory, so a reader (or a crash) sees either
// the old or the new content, never a mix. WriteFileSynced is for files inside
// a directory that is itself published by a rename. All functions are
// stateless and thread-safe; concurrent writers to one path: last rename wins.
#ifndef CLNERF_CORE_IO_DURABLE_FILE_H_
#define CLNERF_CORE_IO_DURABLE_FILE_H_

#include <string>
#include <string_view>
#include <utility>
#include <vector>

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
// Creates directory `dir` holding `files` (name -> bytes) atomically: they are
// written into the sibling `.tmp-<name of dir>`, each fsync'd, that directory
// is fsync'd and renamed to `dir`, and the parent is fsync'd. A crash leaves
// `dir` complete or absent (plus a temporary that RemoveTempEntries cleans).
// ALREADY_EXISTS if `dir` exists; on failure nothing is left behind.
absl::Status WriteDirectoryAtomically(const std::string& dir,
                                      const std::vector<std::pair<std::string, std::string_view>>& files);
// Removes the entries of `dir` whose names start with ".tmp-": what writes
// interrupted by a crash left behind.
void RemoveTempEntries(const std::string& dir);
// Removes the temporaries AtomicWriteFile(path) leaves when a crash (or a
// kill) interrupts it: siblings named "<file name of path>.tmp.<pid>.<n>".
// Returns how many were removed.
int RemoveAtomicWriteTemps(const std::string& path);
// Reads a whole file. NOT_FOUND names `what` (e.g. "checkpoint").
absl::StatusOr<std::string> ReadFileToString(const std::string& path, absl::string_view what = "file");

}  // namespace clnerf

#endif  // CLNERF_CORE_IO_DURABLE_FILE_H_
