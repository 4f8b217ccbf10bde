#include "core/pose/process.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <deque>
#include <fstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

extern char** environ;

namespace clnerf {

std::string TailOfFile(const std::string& path, int max_lines) {
  std::ifstream in(path);
  std::deque<std::string> lines;
  std::string line;
  while (std::getline(in, line)) {
    lines.push_back(line);
    if (int(lines.size()) > max_lines) lines.pop_front();
  }
  return absl::StrJoin(lines, "\n");
}

absl::Status RunProcess(const std::vector<std::string>& argv, const std::string& log_path,
                        const std::atomic<bool>* cancel) {
  if (argv.empty()) return absl::InvalidArgumentError("RunProcess: empty command");
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
  pid_t pid = -1;
  const int rc = posix_spawnp(&pid, args[0], &fa, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  if (rc == ENOENT) return absl::NotFoundError(absl::StrCat("'", argv[0], "' is not installed (not on PATH)"));
  if (rc != 0) return absl::InternalError(absl::StrCat("cannot start '", argv[0], "': ", std::strerror(rc)));
  int status = 0;
  while (true) {
    const pid_t w = waitpid(pid, &status, WNOHANG);
    if (w == pid) break;
    if (w < 0 && errno != EINTR) return absl::InternalError(absl::StrCat("waitpid: ", std::strerror(errno)));
    if (cancel != nullptr && cancel->load()) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      return absl::CancelledError(absl::StrCat(argv[0], " cancelled"));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return absl::OkStatus();
  const std::string how = WIFEXITED(status) ? absl::StrCat("exit status ", WEXITSTATUS(status))
                                            : absl::StrCat("signal ", WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  return absl::InternalError(absl::StrCat(argv.size() > 1 ? argv[0] + " " + argv[1] : argv[0], " failed (", how,
                                          "): ", TailOfFile(log_path, 5)));
}

}  // namespace clnerf
