#include "server/frontends/http_origin_guard.h"

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(HttpOriginGuardTest, HostNameDropsPortCaseAndTrailingDot) {
  EXPECT_EQ(HostName("Example.COM:8080"), "example.com");
  EXPECT_EQ(HostName("example.com."), "example.com");
  EXPECT_EQ(HostName("[::1]:8080"), "::1");
  EXPECT_EQ(HostName("::1"), "::1");  // Bare IPv6: not a port.
  EXPECT_EQ(HostName("127.0.0.1:80"), "127.0.0.1");
}

TEST(HttpOriginGuardTest, HostMustNameThisServer) {
  const std::vector<std::string> none;
  for (const char* host : {"127.0.0.1:8080", "[::1]:8080", "10.1.2.3", "localhost:8080", "viewer.localhost", ""}) {
    EXPECT_TRUE(CheckRequestOrigin({"GET", host, "", ""}, none).ok()) << host;
  }
  // DNS rebinding: a page on evil.example re-pointed at this machine.
  absl::Status s = CheckRequestOrigin({"GET", "evil.example:8080", "", ""}, none);
  EXPECT_TRUE(absl::IsPermissionDenied(s)) << s;
  EXPECT_NE(s.message().find("--http-allowed-host"), std::string::npos) << s;
  EXPECT_FALSE(CheckRequestOrigin({"GET", "localhost.evil.example", "", ""}, none).ok());
  // The operator's own names, or any.
  EXPECT_TRUE(CheckRequestOrigin({"GET", "NeRF.example.org:443", "", ""}, {"nerf.example.org"}).ok());
  EXPECT_FALSE(CheckRequestOrigin({"GET", "other.example.org", "", ""}, {"nerf.example.org"}).ok());
  EXPECT_TRUE(CheckRequestOrigin({"GET", "anything.example", "", ""}, {"*"}).ok());
}

TEST(HttpOriginGuardTest, CrossOriginMutatingRequestsAreRefused) {
  const std::vector<std::string> none;
  // A form on another site posting to the viewer's port.
  EXPECT_TRUE(absl::IsPermissionDenied(
      CheckRequestOrigin({"POST", "127.0.0.1:8080", "http://evil.example", ""}, none)));
  EXPECT_FALSE(CheckRequestOrigin({"POST", "127.0.0.1:8080", "null", ""}, none).ok());  // Sandboxed page.
  EXPECT_FALSE(CheckRequestOrigin({"POST", "127.0.0.1:8080", "http://127.0.0.1:3000", ""}, none).ok());
  EXPECT_FALSE(CheckRequestOrigin({"DELETE", "127.0.0.1:8080", "", "cross-site"}, none).ok());
  // The viewer itself (same origin), and tools that send no Origin.
  EXPECT_TRUE(CheckRequestOrigin({"POST", "127.0.0.1:8080", "http://127.0.0.1:8080", "same-origin"}, none).ok());
  EXPECT_TRUE(CheckRequestOrigin({"POST", "LOCALHOST:8080", "http://localhost:8080", ""}, none).ok());
  EXPECT_TRUE(CheckRequestOrigin({"POST", "127.0.0.1:8080", "", ""}, none).ok());
  // Reads are not refused for their Origin (a cross-origin page cannot read
  // the answer without CORS headers, which the server never sends).
  EXPECT_TRUE(CheckRequestOrigin({"GET", "127.0.0.1:8080", "http://evil.example", "cross-site"}, none).ok());
}

}  // namespace
}  // namespace clnerf
