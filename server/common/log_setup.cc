#include "server/common/log_setup.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "absl/strings/str_cat.h"
#include "google/protobuf/stubs/logging.h"
#include "server/common/log_util.h"
#include "spdlog/pattern_formatter.h"
#include "spdlog/sinks/base_sink.h"
#include "spdlog/sinks/stdout_color_sinks.h"
#include "spdlog/spdlog.h"

namespace clnerf {

namespace {

// Length of the valid UTF-8 sequence at s[i], or 0.
size_t Utf8SequenceAt(std::string_view s, size_t i) {
  const unsigned char c = static_cast<unsigned char>(s[i]);
  size_t n = 0;
  unsigned cp = 0;
  if (c < 0x80) return 1;
  if (c >= 0xc2 && c <= 0xdf) n = 2, cp = c & 0x1f;
  else if (c >= 0xe0 && c <= 0xef) n = 3, cp = c & 0x0f;
  else if (c >= 0xf0 && c <= 0xf4) n = 4, cp = c & 0x07;
  else return 0;
  if (i + n > s.size()) return 0;
  for (size_t k = 1; k < n; ++k) {
    const unsigned char d = static_cast<unsigned char>(s[i + k]);
    if ((d & 0xc0) != 0x80) return 0;
    cp = (cp << 6) | (d & 0x3f);
  }
  // Overlong forms, surrogates and values past U+10FFFF are invalid.
  if ((n == 3 && cp < 0x800) || (n == 4 && (cp < 0x10000 || cp > 0x10ffff)) || (cp >= 0xd800 && cp <= 0xdfff)) {
    return 0;
  }
  return n;
}

// %j: the log message as the body of a JSON string.
class JsonMessageFlag : public spdlog::custom_flag_formatter {
 public:
  void format(const spdlog::details::log_msg& msg, const std::tm&, spdlog::memory_buf_t& dest) override {
    const std::string_view s(msg.payload.data(), msg.payload.size());
    for (size_t i = 0; i < s.size();) {
      const char c = s[i];
      switch (c) {
        case '"': dest.append(std::string_view("\\\"")); ++i; continue;
        case '\\': dest.append(std::string_view("\\\\")); ++i; continue;
        case '\n': dest.append(std::string_view("\\n")); ++i; continue;
        case '\t': dest.append(std::string_view("\\t")); ++i; continue;
        default: break;
      }
      if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) {
        char buf[8];
        std::snprintf(buf, sizeof(buf), "\\u%04x", unsigned(static_cast<unsigned char>(c)));
        dest.append(std::string_view(buf));
        ++i;
        continue;
      }
      const size_t n = Utf8SequenceAt(s, i);
      if (n == 0) {
        dest.append(std::string_view("\\ufffd"));
        ++i;
      } else {
        dest.append(s.substr(i, n));
        i += n;
      }
    }
  }
  std::unique_ptr<custom_flag_formatter> clone() const override { return std::make_unique<JsonMessageFlag>(); }
};

// Writes formatted records to a file descriptor (the real stderr, saved
// before fd 2 is redirected into the capture pipe).
class FdSink : public spdlog::sinks::base_sink<std::mutex> {
 public:
  explicit FdSink(int fd) : fd_(fd) {}

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    spdlog::memory_buf_t buf;
    formatter_->format(msg, buf);
    const char* p = buf.data();
    size_t n = buf.size();
    while (n > 0) {
      const ssize_t w = ::write(fd_, p, n);
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) return;
      p += w;
      n -= size_t(w);
    }
  }
  void flush_() override {}

 private:
  const int fd_;
};

// Re-logs each line written to `fd` (the read end of the stderr pipe).
void RelogLines(int fd) {
  std::string pending;
  char buf[4096];
  while (true) {
    const ssize_t n = ::read(fd, buf, sizeof(buf));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    pending.append(buf, size_t(n));
    size_t start = 0;
    for (size_t nl; (nl = pending.find('\n', start)) != std::string::npos; start = nl + 1) {
      if (nl > start) spdlog::warn("stderr: {}", std::string_view(pending).substr(start, nl - start));
    }
    pending.erase(0, start);
    if (pending.size() > 8192) {  // A very long line without a newline.
      spdlog::warn("stderr: {}", pending);
      pending.clear();
    }
  }
}

void ProtobufLogHandler(google::protobuf::LogLevel level, const char* file, int line, const std::string& message) {
  const std::string text = absl::StrCat("protobuf (", file, ":", line, "): ", EscapeForLog(message));
  switch (level) {
    case google::protobuf::LOGLEVEL_INFO: spdlog::info("{}", text); break;
    case google::protobuf::LOGLEVEL_WARNING: spdlog::warn("{}", text); break;
    default: spdlog::error("{}", text); break;
  }
}

}  // namespace

absl::Status SetUpServerLogging(const std::string& level, const std::string& format) {
  const spdlog::level::level_enum lvl = spdlog::level::from_str(level);
  if (lvl == spdlog::level::off && level != "off") {
    return absl::InvalidArgumentError(absl::StrCat("--log-level '", level, "' is not trace|debug|info|warn|error"));
  }
  if (format == "text") {
    auto logger = spdlog::stderr_color_mt("clnerf-server");
    spdlog::set_default_logger(logger);
    spdlog::set_pattern("[%Y-%m-%d %H:%M:%S.%e] [%^%l%$] %v");
  } else if (format == "json") {
    // Keep the real stderr for the logger; fd 2 becomes a pipe whose lines
    // are re-logged as JSON records.
    const int real = ::fcntl(2, F_DUPFD_CLOEXEC, 3);
    int pipe_fds[2];
    if (real < 0 || ::pipe2(pipe_fds, O_CLOEXEC) != 0) {
      return absl::InternalError(absl::StrCat("cannot capture stderr: errno ", errno));
    }
    auto logger = std::make_shared<spdlog::logger>("clnerf-server", std::make_shared<FdSink>(real));
    spdlog::set_default_logger(logger);
    auto f = std::make_unique<spdlog::pattern_formatter>();
    f->add_flag<JsonMessageFlag>('j').set_pattern(
        R"({"time":"%Y-%m-%dT%H:%M:%S.%e%z","level":"%l","thread":%t,"msg":"%j"})");
    spdlog::set_formatter(std::move(f));
    std::fflush(stderr);
    ::dup2(pipe_fds[1], 2);
    ::close(pipe_fds[1]);
    std::setvbuf(stderr, nullptr, _IOLBF, 0);
    std::thread(RelogLines, pipe_fds[0]).detach();
  } else {
    return absl::InvalidArgumentError("--log-format must be text or json");
  }
  spdlog::set_level(lvl);
  google::protobuf::SetLogHandler(&ProtobufLogHandler);
  return absl::OkStatus();
}

}  // namespace clnerf
