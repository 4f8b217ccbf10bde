#include "server/frontends/http_origin_guard.h"

#include <arpa/inet.h>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "server/common/log_util.h"

namespace clnerf {

namespace {

bool IsIpLiteral(const std::string& host) {
  unsigned char buf[16];
  return inet_pton(AF_INET, host.c_str(), buf) == 1 || inet_pton(AF_INET6, host.c_str(), buf) == 1;
}

bool HostAllowed(const std::string& host, const std::vector<std::string>& allowed) {
  if (IsIpLiteral(host) || host == "localhost" || absl::EndsWith(host, ".localhost")) return true;
  for (const std::string& a : allowed) {
    if (a == "*" || HostName(a) == host) return true;
  }
  return false;
}

bool Mutating(const std::string& method) { return method != "GET" && method != "HEAD" && method != "OPTIONS"; }

// "http://Host:8080" -> "host:8080" (scheme and path dropped, lower case).
std::string Authority(const std::string& origin) {
  std::string s = origin;
  const size_t scheme = s.find("://");
  if (scheme != std::string::npos) s = s.substr(scheme + 3);
  const size_t path = s.find('/');
  if (path != std::string::npos) s = s.substr(0, path);
  return absl::AsciiStrToLower(s);
}

}  // namespace

std::string HostName(const std::string& authority) {
  std::string h = absl::AsciiStrToLower(authority);
  if (!h.empty() && h.front() == '[') {
    const size_t close = h.find(']');
    h = close == std::string::npos ? h.substr(1) : h.substr(1, close - 1);
  } else if (const size_t colon = h.find(':'); colon != std::string::npos && h.find(':', colon + 1) == std::string::npos) {
    h = h.substr(0, colon);
  }
  while (!h.empty() && h.back() == '.') h.pop_back();
  return h;
}

absl::Status CheckRequestOrigin(const RequestOrigin& r, const std::vector<std::string>& allowed_hosts) {
  if (!r.host.empty() && !HostAllowed(HostName(r.host), allowed_hosts)) {
    return absl::PermissionDeniedError(absl::StrCat(
        "Host '", EscapeForLog(r.host, 64),
        "' is not this server's name (IP addresses and localhost are; start clnerf-server with "
        "--http-allowed-host NAME to serve it by that name)"));
  }
  if (!Mutating(r.method)) return absl::OkStatus();
  if (!r.origin.empty()) {
    if (r.origin == "null" || Authority(r.origin) != absl::AsciiStrToLower(r.host)) {
      return absl::PermissionDeniedError(absl::StrCat("cross-origin ", r.method, " refused (Origin '",
                                                      EscapeForLog(r.origin, 64), "', Host '",
                                                      EscapeForLog(r.host, 64), "')"));
    }
    return absl::OkStatus();
  }
  if (r.sec_fetch_site == "cross-site" || r.sec_fetch_site == "same-site") {
    return absl::PermissionDeniedError(absl::StrCat("cross-origin ", r.method, " refused (Sec-Fetch-Site ",
                                                    EscapeForLog(r.sec_fetch_site, 32), ")"));
  }
  return absl::OkStatus();
}

}  // namespace clnerf
