// The HTTP front end's defence against other web sites: which requests a
// browser may make on a visitor's behalf.
//
//  * DNS rebinding: a page on evil.example whose name is re-pointed at
//    127.0.0.1 reaches this server with "Host: evil.example" and, being
//    same-origin to itself, can read the answers. So the Host header must
//    name this server: an IP literal, "localhost" (or *.localhost), or one of
//    the names the operator allows (--http-allowed-host; "*" = any).
//  * Cross-site request forgery: any page can make a visitor's browser POST
//    a form or a text/plain body to http://127.0.0.1:8080/api/deploy; the
//    answer is unreadable but the deploy happens. So a mutating request
//    (anything but GET, HEAD and OPTIONS) that a browser marks as coming from
//    another origin (its Origin header, or Sec-Fetch-Site) is refused. Tools
//    (curl, the CLI) send neither and are not affected; a --token still
//    guards them.
//
// Thread-safety: pure functions.
#ifndef CLNERF_SERVER_HTTP_ORIGIN_GUARD_H_
#define CLNERF_SERVER_HTTP_ORIGIN_GUARD_H_

#include <string>
#include <vector>

#include "absl/status/status.h"

namespace clnerf {

struct RequestOrigin {
  std::string method;
  std::string host;            // The Host header ("" when absent).
  std::string origin;          // The Origin header ("" when absent).
  std::string sec_fetch_site;  // The Sec-Fetch-Site header ("" when absent).
};

// OK, or PERMISSION_DENIED saying why (the names in it are escaped).
absl::Status CheckRequestOrigin(const RequestOrigin& request, const std::vector<std::string>& allowed_hosts);

// "Example.COM:8080" -> "example.com", "[::1]:80" -> "::1": the host part of
// a Host header or of an authority, lower case, without a trailing dot.
std::string HostName(const std::string& authority);

}  // namespace clnerf

#endif  // CLNERF_SERVER_HTTP_ORIGIN_GUARD_H_
