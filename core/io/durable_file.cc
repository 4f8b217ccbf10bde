#include "core/io/durable_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <filesystem>

#include "absl/strings/str_cat.h"

namespace clnerf {

namespace {

absl::Status WriteAll(int fd, std::string_view data, const std::string& name) {
  while (!data.empty()) {
    const ssize_t w = ::write(fd, data.data(), data.size());
    if (w < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", name, "'"));
    }
    data.remove_prefix(size_t(w));
  }
  return absl::OkStatus();
}

}  // namespace

std::string DirectoryOf(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

absl::Status SyncDirectory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return absl::ErrnoToStatus(errno, absl::StrCat("cannot open directory '", dir, "'"));
  int rc;
  do {
    rc = ::fsync(fd);
  } while (rc != 0 && errno == EINTR);
  const int err = errno;
  ::close(fd);
  // Some file systems cannot sync directories; that is not a failure.
  if (rc != 0 && err != EINVAL && err != ENOTSUP) {
    return absl::ErrnoToStatus(err, absl::StrCat("cannot fsync directory '", dir, "'"));
  }
  return absl::OkStatus();
}

absl::Status WriteFileSynced(const std::string& path, std::string_view data) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return absl::ErrnoToStatus(errno, absl::StrCat("cannot create '", path, "'"));
  absl::Status status = WriteAll(fd, data, path);
  if (status.ok()) {
    int rc;
    do {
      rc = ::fsync(fd);
    } while (rc != 0 && errno == EINTR);
    if (rc != 0) status = absl::ErrnoToStatus(errno, absl::StrCat("cannot fsync '", path, "'"));
  }
  if (::close(fd) != 0 && status.ok()) {
    status = absl::ErrnoToStatus(errno, absl::StrCat("cannot close '", path, "'"));
  }
  return status;
}

absl::Status AtomicWriteFile(const std::string& path, std::string_view data) {
  static std::atomic<uint64_t> counter{0};
  const std::string tmp = absl::StrCat(path, ".tmp.", ::getpid(), ".", counter.fetch_add(1));
  absl::Status status = WriteFileSynced(tmp, data);
  if (status.ok() && ::rename(tmp.c_str(), path.c_str()) != 0) {
    status = absl::ErrnoToStatus(errno, absl::StrCat("cannot rename '", tmp, "' to '", path, "'"));
  }
  if (!status.ok()) {
    ::unlink(tmp.c_str());
    return status;
  }
  // The new file is in place; an error from here on only means that the
  // rename may not yet be durable.
  return SyncDirectory(DirectoryOf(path));
}

absl::StatusOr<std::string> ReadFileToString(const std::string& path, absl::string_view what) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno == ENOENT) return absl::NotFoundError(absl::StrCat(what, " '", path, "' not found"));
    return absl::ErrnoToStatus(errno, absl::StrCat("cannot open ", what, " '", path, "'"));
  }
  // Read the size fstat reports in one buffer, then keep reading in case the
  // file is longer than reported (or not a regular file).
  std::string out;
  struct stat st;
  if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) out.resize(size_t(st.st_size));
  size_t filled = 0;
  std::string chunk;
  while (true) {
    char* dst;
    size_t room;
    if (filled < out.size()) {
      dst = out.data() + filled;
      room = out.size() - filled;
    } else {
      chunk.resize(size_t(1) << 20);
      dst = chunk.data();
      room = chunk.size();
    }
    const ssize_t r = ::read(fd, dst, room);
    if (r < 0) {
      if (errno == EINTR) continue;
      const int err = errno;
      ::close(fd);
      return absl::ErrnoToStatus(err, absl::StrCat("cannot read ", what, " '", path, "'"));
    }
    if (r == 0) break;
    if (dst == chunk.data()) {
      out.append(chunk.data(), size_t(r));
    }
    filled += size_t(r);
  }
  out.resize(filled);
  ::close(fd);
  return out;
}

absl::Status WriteDirectoryAtomically(const std::string& dir,
                                      const std::vector<std::pair<std::string, std::string_view>>& files) {
  namespace fs = std::filesystem;
  const fs::path final_dir(dir);
  const fs::path parent = final_dir.parent_path().empty() ? fs::path(".") : final_dir.parent_path();
  const fs::path tmp = parent / (".tmp-" + final_dir.filename().string());
  std::error_code ec;
  if (fs::exists(final_dir, ec)) return absl::AlreadyExistsError(absl::StrCat("'", dir, "' exists"));
  fs::remove_all(tmp, ec);
  fs::create_directories(tmp, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create '", tmp.string(), "': ", ec.message()));
  absl::Status s;
  for (const auto& [name, bytes] : files) {
    s = WriteFileSynced((tmp / name).string(), bytes);
    if (!s.ok()) break;
  }
  if (s.ok()) s = SyncDirectory(tmp.string());
  if (s.ok()) {
    fs::rename(tmp, final_dir, ec);
    if (ec) s = absl::InternalError(absl::StrCat("cannot rename '", tmp.string(), "' to '", dir, "': ", ec.message()));
  }
  if (!s.ok()) {
    fs::remove_all(tmp, ec);
    return s;
  }
  return SyncDirectory(parent.string());
}

void RemoveTempEntries(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    if (e.path().filename().string().rfind(".tmp-", 0) == 0) fs::remove_all(e.path(), ec);
  }
}

int RemoveAtomicWriteTemps(const std::string& path) {
  namespace fs = std::filesystem;
  const fs::path p(path);
  const std::string prefix = p.filename().string() + ".tmp.";
  std::error_code ec;
  int removed = 0;
  for (const auto& e : fs::directory_iterator(p.has_parent_path() ? p.parent_path() : fs::path("."), ec)) {
    const std::string name = e.path().filename().string();
    if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) continue;
    // Only "<pid>.<n>" suffixes: never a user's file that merely looks alike.
    const std::string rest = name.substr(prefix.size());
    const size_t dot = rest.find('.');
    const auto digits = [](std::string_view s) {
      return !s.empty() && s.find_first_not_of("0123456789") == std::string_view::npos;
    };
    if (dot == std::string::npos || !digits(std::string_view(rest).substr(0, dot)) ||
        !digits(std::string_view(rest).substr(dot + 1))) {
      continue;
    }
    std::error_code rm;
    if (fs::remove(e.path(), rm)) ++removed;
  }
  return removed;
}

}  // namespace clnerf
