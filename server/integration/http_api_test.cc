// The HTTP API against the real server in-process (gRPC and HTTP on
// localhost:0), through cpp-httplib's client: the same model as gRPC, the
// status codes of bad requests, the token, and cancellation of stale renders.
#include "server/frontends/http_api.h"

#include <chrono>
#include <future>
#include <map>
#include <regex>
#include <sstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/bake/baked_asset.h"
#include "core/bake/baked_renderer.h"
#include "core/data/image.h"
#include "core/io/durable_file.h"
#include "core/render/metrics.h"
#include "httplib.h"
#include "nlohmann/json.hpp"
#include "server/testing/prometheus_text_test_util.h"
#include "server/testing/server_fixture.h"

namespace clnerf {
namespace {

using json = nlohmann::json;
using testing_util::ServerFixture;
using testing_util::TempDir;
using testing_util::TinyScans;
using testing_util::TinyServerOptions;

class HttpApiTest : public ServerFixture {
 protected:
  json Json(const httplib::Result& r) {
    EXPECT_TRUE(r) << "no HTTP response";
    if (!r) return json();
    EXPECT_EQ(r->get_header_value("Content-Type"), "application/json") << r->body;
    return json::parse(r->body, nullptr, false);
  }
  // A render query for `cam` in the c2w + pixel-intrinsics form.
  static std::string RenderPath(const Camera& cam, const std::string& extra = "") {
    std::vector<std::string> m;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 4; ++j) m.push_back(absl::StrCat(cam.c2w(i, j)));
    }
    const Intrinsics& in = cam.intrinsics;
    return absl::StrCat("/api/render?width=", in.width, "&height=", in.height, "&c2w=", absl::StrJoin(m, ","),
                        "&fx=", in.fx, "&fy=", in.fy, "&cx=", in.cx, "&cy=", in.cy, extra);
  }
  // A server with one render thread and one slot for big renders, with a
  // tiny scan deployed: `scene` is that scan, `big` a 512 x 512 camera whose
  // render takes seconds there.
  void StartWithOneRenderSlot(const std::string& name, Scene* scene, Camera* big) {
    ServerOptions o = TinyServerOptions(TempDir(name));
    o.render_concurrency = 1;
    o.render_threads = 1;
    o.render_pixel_budget = int64_t(512) * 512;
    StartHttp(o);
    *scene = TinyScans(1);
    ASSERT_EQ(UploadAndWait(*scene, 0).phase(), v1::JOB_PHASE_DONE);
    *big = scene->test[0].camera;
    big->intrinsics = big->intrinsics.Scaled(512, 512);
  }
};

double MeanAbsDiff(const Image& a, const Image& b) {
  double d = 0;
  for (size_t i = 0; i < a.rgb.size(); ++i) d += std::abs(a.rgb[i] - b.rgb[i]);
  return d / double(a.rgb.size());
}

TEST_F(HttpApiTest, ServesTheSameModelsVersionsAndJobsAsGrpc) {
  StartHttp(TinyServerOptions(TempDir("srv_http")));
  const Scene scene = TinyScans(2);
  const v1::Job j0 = UploadAndWait(scene, 0);
  ASSERT_EQ(j0.phase(), v1::JOB_PHASE_DONE) << j0.error();
  const v1::Job j1 = UploadAndWait(scene, 1);
  ASSERT_EQ(j1.phase(), v1::JOB_PHASE_DONE) << j1.error();

  json s = Json(http_->Get("/api/scene"));
  EXPECT_EQ(s["version"], 2);
  EXPECT_EQ(s["deployed_version"], 2);
  EXPECT_EQ(s["time_steps"], 2);
  ASSERT_EQ(s["scans"].size(), 2u);
  EXPECT_EQ(s["versions"].size(), 2u);
  EXPECT_EQ(s["default_camera"]["time_step"], 1);
  // The procedural scene's cameras look at its centre from a sphere.
  EXPECT_LT(Eigen::Vector3f(s["focus"][0], s["focus"][1], s["focus"][2]).norm(), 0.2f);
  EXPECT_EQ(Json(http_->Get("/api/scene?version=1"))["time_steps"], 1);

  // The same camera through HTTP (PNG) and gRPC gives the same image.
  const Camera cam = scene.test[0].camera;
  for (int t : {0, 1}) {
    auto r = http_->Get(RenderPath(cam, absl::StrCat("&format=png&time=", t)));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
    EXPECT_EQ(r->get_header_value("X-Clnerf-Version"), "2");
    EXPECT_EQ(r->get_header_value("X-Clnerf-Time-Step"), std::to_string(t));
    absl::StatusOr<Image> via_http = DecodeImage(r->body, "r.png");
    ASSERT_TRUE(via_http.ok()) << via_http.status();
    v1::RenderResponse g;
    ASSERT_TRUE(Render(cam, t, 0, &g).ok());
    absl::StatusOr<Image> via_grpc = DecodeImage(g.image(), "g.png");
    ASSERT_TRUE(via_grpc.ok());
    EXPECT_LT(MeanAbsDiff(*via_http, *via_grpc), 1.0 / 255);
  }
  // JPEG by default; the look-at form of the scan's own camera works too.
  const json& c = s["scans"][0];
  auto jpg = http_->Get(absl::StrCat("/api/render?width=40&height=30&time=0&fov=", c["fov"].get<double>(),
                                     "&eye=", c["eye"][0].get<double>(), ",", c["eye"][1].get<double>(), ",",
                                     c["eye"][2].get<double>(), "&target=", c["target"][0].get<double>(), ",",
                                     c["target"][1].get<double>(), ",", c["target"][2].get<double>(),
                                     "&up=", c["up"][0].get<double>(), ",", c["up"][1].get<double>(), ",",
                                     c["up"][2].get<double>()));
  ASSERT_TRUE(jpg);
  ASSERT_EQ(jpg->status, 200) << jpg->body;
  EXPECT_EQ(jpg->get_header_value("Content-Type"), "image/jpeg");
  absl::StatusOr<Image> small = DecodeImage(jpg->body, "r.jpg");
  ASSERT_TRUE(small.ok());
  EXPECT_EQ(small->width, 40);
  EXPECT_EQ(small->height, 30);

  // Versions and jobs: the same records gRPC has.
  json v = Json(http_->Get("/api/versions"));
  EXPECT_EQ(v["deployed_version"], 2);
  ASSERT_EQ(v["versions"].size(), 2u);
  json jobs = Json(http_->Get("/api/jobs"));
  EXPECT_EQ(jobs["total"], 2);
  ASSERT_EQ(jobs["jobs"].size(), 2u);
  EXPECT_EQ(jobs["jobs"][0]["job_id"], j1.job_id()) << "newest first";
  json oldest = Json(http_->Get("/api/jobs?order=oldest&limit=1"));
  ASSERT_EQ(oldest["jobs"].size(), 1u);
  EXPECT_EQ(oldest["jobs"][0]["job_id"], j0.job_id());
  json second = Json(http_->Get("/api/jobs?limit=1&offset=1"));
  ASSERT_EQ(second["jobs"].size(), 1u);
  EXPECT_EQ(second["jobs"][0]["job_id"], j0.job_id());
  json one = Json(http_->Get("/api/jobs/" + j1.job_id()));
  EXPECT_EQ(one["phase"], "done");
  EXPECT_EQ(one["version"], 2);
  EXPECT_EQ(one["done"], true);
  EXPECT_EQ(Json(http_->Get("/api/info"))["deployed_version"], 2);

  // The page and its files are served.
  auto page = http_->Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->get_header_value("Content-Type").find("text/html"), std::string::npos);
  auto js = http_->Get("/viewer.js");
  ASSERT_TRUE(js);
  EXPECT_EQ(js->status, 200);
}

TEST_F(HttpApiTest, MetricsAreValidPrometheusTextAndHealthEndpointsAnswer) {
  StartHttp(TinyServerOptions(TempDir("srv_metrics")));
  auto live = http_->Get("/healthz");
  ASSERT_TRUE(live);
  EXPECT_EQ(live->status, 200);
  auto ready = http_->Get("/readyz");
  ASSERT_TRUE(ready);
  EXPECT_EQ(ready->status, 200);  // Ready before any version: it takes uploads.
  EXPECT_EQ(Json(ready)["ready"], true);

  const Scene scene = TinyScans(1);
  const v1::Job j0 = UploadAndWait(scene, 0);
  ASSERT_EQ(j0.phase(), v1::JOB_PHASE_DONE) << j0.error();
  const Camera cam = scene.test[0].camera;
  for (int i = 0; i < 3; ++i) {
    auto r = http_->Get(RenderPath(cam, "&format=png"));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << r->body;
  }
  auto bad = http_->Get(RenderPath(cam, "&time=7"));  // No such time step.
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400);

  auto m = http_->Get("/metrics");
  ASSERT_TRUE(m);
  ASSERT_EQ(m->status, 200);
  EXPECT_NE(m->get_header_value("Content-Type").find("text/plain"), std::string::npos);
  std::map<std::string, double> samples;
  const std::string err = testing_util::ParsePrometheusText(m->body, &samples);
  ASSERT_EQ(err, "") << m->body;
  EXPECT_EQ(samples["clnerf_renders_total{code=\"OK\"}"], 3) << m->body;
  EXPECT_EQ(samples["clnerf_renders_total{code=\"INVALID_ARGUMENT\"}"], 1) << m->body;
  EXPECT_EQ(samples["clnerf_render_seconds_count"], 3) << m->body;
  EXPECT_EQ(samples["clnerf_uploads_total{code=\"OK\"}"], 1) << m->body;
  EXPECT_GT(samples["clnerf_upload_bytes_total"], 0) << m->body;
  EXPECT_EQ(samples["clnerf_updates_total{outcome=\"published\"}"], 1) << m->body;
  EXPECT_GT(samples["clnerf_model_bytes"], 0) << m->body;
  // No per-place (or other unbounded) labels.
  EXPECT_EQ(m->body.find("place="), std::string::npos);
  // The reader is strict: a malformed line is caught.
  EXPECT_NE(testing_util::ParsePrometheusText(m->body + "clnerf_x{a=b} 1\n", &samples), "");
}

TEST_F(HttpApiTest, BadRequestsGetTheirStatusAndAMessage) {
  ServerOptions o = TinyServerOptions(TempDir("srv_http_bad"));
  o.token = "s3cret";
  o.render_concurrency = 1;
  o.render_pixel_budget = 256 * 256;
  StartHttp(o);
  const Scene scene = TinyScans(1);
  const Camera cam = scene.test[0].camera;

  // Nothing deployed yet: 409 (FAILED_PRECONDITION), as gRPC.
  auto none = http_->Get(RenderPath(cam));
  ASSERT_TRUE(none);
  EXPECT_EQ(none->status, 409);
  EXPECT_EQ(Json(none)["code"], "FAILED_PRECONDITION");
  EXPECT_EQ(Json(http_->Get("/api/scene"))["code"], "FAILED_PRECONDITION");

  v1::UploadScanResponse ack;
  ASSERT_TRUE(Upload(testing_util::UploadMessages(testing_util::UploadOf(scene, 0)), &ack, "s3cret").ok());
  ASSERT_EQ(Watch(ack.job_id()).phase(), v1::JOB_PHASE_DONE);

  struct Case {
    std::string path;
    int status;
    std::string says;
  };
  const Case cases[] = {
      {RenderPath(cam, "&widht=3"), 400, "unknown parameter 'widht'"},
      {RenderPath(cam, "&time=abc"), 400, "parameter 'time'"},
      {RenderPath(cam, "&time=5"), 400, "out of range"},
      {RenderPath(cam, "&quality=0"), 400, "parameter 'quality'"},
      {"/api/render?width=10", 400, "parameter 'height'"},
      {RenderPath(cam, "&version=99"), 404, "99"},
      {"/api/scene?version=99", 404, "99"},
      {"/api/scene?version=-1", 400, "parameter 'version'"},
      {"/api/jobs/job-999999", 404, "job-999999"},
      {"/api/jobs?limit=0", 400, "parameter 'limit'"},
      {"/api/jobs?order=random", 400, "parameter 'order'"},
      {"/api/no/such/route", 404, "no route"},
  };
  for (const Case& c : cases) {
    auto r = http_->Get(c.path);
    ASSERT_TRUE(r) << c.path;
    EXPECT_EQ(r->status, c.status) << c.path << " -> " << r->body;
    json body = Json(r);
    ASSERT_TRUE(body.contains("error")) << r->body;
    EXPECT_NE(body["error"].get<std::string>().find(c.says), std::string::npos) << c.path << " -> " << r->body;
  }
  // An oversized render is refused before any work: 400 naming the limit.
  Camera big = cam;
  big.intrinsics = cam.intrinsics.Scaled(300, 300);
  auto huge = http_->Get(RenderPath(big));
  ASSERT_TRUE(huge);
  EXPECT_EQ(huge->status, 400);
  EXPECT_NE(Json(huge)["error"].get<std::string>().find("exceeds the per-request limit"), std::string::npos);

  // Mutations need the token; reads do not.
  auto no_token = http_->Post("/api/deploy?version=1");
  ASSERT_TRUE(no_token);
  EXPECT_EQ(no_token->status, 401);
  EXPECT_EQ(Json(no_token)["code"], "UNAUTHENTICATED");
  auto wrong = http_->Post("/api/deploy?version=1", httplib::Headers{{"Authorization", "Bearer nope"}}, "",
                           "text/plain");
  ASSERT_TRUE(wrong);
  EXPECT_EQ(wrong->status, 401);
  auto cancel = http_->Post("/api/jobs/" + ack.job_id() + "/cancel");
  ASSERT_TRUE(cancel);
  EXPECT_EQ(cancel->status, 401);
  const httplib::Headers auth{{"Authorization", "Bearer s3cret"}};
  auto ok = http_->Post("/api/deploy?version=1", auth, "", "text/plain");
  ASSERT_TRUE(ok);
  EXPECT_EQ(ok->status, 200) << ok->body;
  auto unknown = http_->Post("/api/deploy?version=7", auth, "", "text/plain");
  ASSERT_TRUE(unknown);
  EXPECT_EQ(unknown->status, 404) << unknown->body;
  // A body over the cap is refused.
  auto fat = http_->Post("/api/deploy?version=1", auth, std::string(100 << 10, 'x'), "text/plain");
  ASSERT_TRUE(fat);
  EXPECT_EQ(fat->status, 413);
  EXPECT_EQ(Json(http_->Get("/api/info"))["deployed_version"], 1);
}

// Without --token (the default), other web sites must still not drive the
// server through a visitor's browser: a cross-origin POST (a form on
// evil.example) and a request by a rebound name are refused with 403
// before any handler runs; the page's own requests and tools pass.
TEST_F(HttpApiTest, OtherSitesCannotDeployOrReadThroughAVisitorsBrowser) {
  ServerOptions o = TinyServerOptions(TempDir("srv_http_origin"));
  o.http_allowed_hosts = {"nerf.example.org"};
  StartHttp(o);
  const std::string self = absl::StrCat("127.0.0.1:", server_->http_port());
  auto forged = http_->Post("/api/deploy?version=1", httplib::Headers{{"Origin", "http://evil.example"}},
                            "version=1", "application/x-www-form-urlencoded");
  ASSERT_TRUE(forged);
  EXPECT_EQ(forged->status, 403) << forged->body;
  EXPECT_EQ(Json(forged)["code"], "PERMISSION_DENIED");
  auto sandboxed = http_->Post("/api/jobs/job-000001/cancel", httplib::Headers{{"Origin", "null"}}, "", "text/plain");
  ASSERT_TRUE(sandboxed);
  EXPECT_EQ(sandboxed->status, 403);
  // Same origin (the viewer's own fetch) and no Origin (curl) reach the API:
  // nothing is deployed yet, so 404 for version 1.
  for (const httplib::Headers& h : {httplib::Headers{{"Origin", "http://" + self}}, httplib::Headers{}}) {
    auto r = http_->Post("/api/deploy?version=1", h, "", "text/plain");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 404) << r->body;
  }
  // DNS rebinding: the Host header names another site.
  auto rebound = http_->Get("/api/info", httplib::Headers{{"Host", "evil.example"}});
  ASSERT_TRUE(rebound);
  EXPECT_EQ(rebound->status, 403);
  EXPECT_NE(Json(rebound)["error"].get<std::string>().find("--http-allowed-host"), std::string::npos);
  auto named = http_->Get("/api/info", httplib::Headers{{"Host", "nerf.example.org"}});
  ASSERT_TRUE(named);
  EXPECT_EQ(named->status, 200) << named->body;
  EXPECT_EQ(http_->Get("/api/info")->status, 200);
}

// No route takes a parameter twice: a repeat is refused even with the same
// value (cpp-httplib would merge it), and a request line too long to read
// says so.
// A body over a route's cap is answered 413 from its headers, while the
// client is still sending it: the reply must reach a client that reads only
// once it has sent everything (as cpp-httplib's and curl's do), so the
// server drains what follows instead of resetting the connection under it.
// 8 MiB is far more than loopback's socket buffers hold.
TEST_F(HttpApiTest, ABodyOverTheCapGetsItsRefusalWhileTheClientIsStillSending) {
  ServerOptions o = TinyServerOptions(TempDir("srv_http_fat"));
  o.token = "s3cret";
  StartHttp(o);
  const httplib::Headers auth{{"Authorization", "Bearer s3cret"}};
  for (int i = 0; i < 3; ++i) {
    auto fat = http_->Post("/api/deploy?version=1", auth, std::string(8 << 20, 'x'), "text/plain");
    ASSERT_TRUE(fat) << "no reply, try " << i << ": " << httplib::to_string(fat.error());
    EXPECT_EQ(fat->status, 413);
    EXPECT_NE(Json(fat)["error"].get<std::string>().find("request body over"), std::string::npos) << fat->body;
  }
  EXPECT_EQ(http_->Get("/api/info")->status, 200);
}

TEST_F(HttpApiTest, RepeatedParametersAndOverlongRequestLinesAreRefused) {
  StartHttp(TinyServerOptions(TempDir("srv_http_repeat")));
  for (const char* path : {"/api/info?place=a&place=b", "/api/info?place=default&place=default",
                           "/api/render?width=8&width=8&height=8", "/api/jobs?limit=1&li%6Dit=1"}) {
    auto r = http_->Get(path);
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, 400) << path;
    EXPECT_NE(Json(r)["error"].get<std::string>().find("is given more than once"), std::string::npos) << path;
  }
  EXPECT_EQ(http_->Get("/api/info?place=default")->status, 200);
  auto long_line = http_->Get("/api/info?x=" + std::string(9000, 'a'));
  ASSERT_TRUE(long_line);
  EXPECT_EQ(long_line->status, 414);
  EXPECT_NE(Json(long_line)["error"].get<std::string>().find("request line too long"), std::string::npos)
      << long_line->body;
}

TEST_F(HttpApiTest, ANewerRenderOfTheSameViewCancelsTheStaleOneAndDeadlinesHold) {
  Scene scene;
  Camera big;
  ASSERT_NO_FATAL_FAILURE(StartWithOneRenderSlot("srv_http_cancel", &scene, &big));
  const Camera small = scene.test[0].camera;

  // A big render of view "left" that takes seconds on one thread...
  const auto t0 = std::chrono::steady_clock::now();
  auto stale = std::async(std::launch::async, [&] {
    httplib::Client c("127.0.0.1", server_->http_port());
    c.set_read_timeout(std::chrono::seconds(60));
    return c.Get(RenderPath(big, "&view=left&timeout_ms=300000"));
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  // ...is cancelled by a newer render of the same view, which succeeds.
  auto fresh = http_->Get(RenderPath(small, "&view=left"));
  ASSERT_TRUE(fresh);
  EXPECT_EQ(fresh->status, 200) << fresh->body;
  auto old = stale.get();
  const double stale_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_TRUE(old);
  EXPECT_EQ(old->status, 499) << old->body;
  EXPECT_NE(Json(old)["error"].get<std::string>().find("superseded"), std::string::npos);
  // The same render left alone takes far longer than the stale one lived.
  const auto t1 = std::chrono::steady_clock::now();
  auto full = http_->Get(RenderPath(big, "&format=png&timeout_ms=300000"));
  ASSERT_TRUE(full);
  EXPECT_EQ(full->status, 200);
  const double full_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  EXPECT_LT(stale_s, full_s) << "the stale render should stop early";

  // Deadlines: a render that cannot finish in timeout_ms is stopped (504).
  auto late = http_->Get(RenderPath(big, "&timeout_ms=20"));
  ASSERT_TRUE(late);
  EXPECT_EQ(late->status, 504) << late->body;
  EXPECT_EQ(Json(late)["code"], "DEADLINE_EXCEEDED");
  // The metrics count it as what it was.
  auto m = http_->Get("/metrics");
  ASSERT_TRUE(m);
  std::map<std::string, double> samples;
  ASSERT_EQ(testing_util::ParsePrometheusText(m->body, &samples), "") << m->body;
  EXPECT_EQ(samples["clnerf_renders_total{code=\"DEADLINE_EXCEEDED\"}"], 1) << m->body;
}

// A render whose client went away stops and frees its slot: two abandoned
// 512 x 512 renders kept the only slot for their whole run, so the next big
// render waited behind them (small renders never queue for slots). Measured
// against the same big render alone.
TEST_F(HttpApiTest, ARenderWhoseClientLeftStopsAndFreesItsSlot) {
  Scene scene;
  Camera big;
  ASSERT_NO_FATAL_FAILURE(StartWithOneRenderSlot("srv_http_abandoned", &scene, &big));
  auto t0 = std::chrono::steady_clock::now();
  auto full = http_->Get(RenderPath(big, "&timeout_ms=300000"));
  ASSERT_TRUE(full);
  ASSERT_EQ(full->status, 200);
  const double full_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // The same render, asked for and abandoned after 0.2 s (the client closes
  // its connection), twice.
  for (int i = 0; i < 2; ++i) {
    httplib::Client c("127.0.0.1", server_->http_port());
    c.set_read_timeout(std::chrono::milliseconds(200));
    auto gone = c.Get(RenderPath(big, "&timeout_ms=300000"));
    EXPECT_FALSE(gone);  // Timed out on the client's side and closed.
  }
  t0 = std::chrono::steady_clock::now();
  auto next = http_->Get(RenderPath(big, "&timeout_ms=300000"));
  const double next_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_TRUE(next);
  EXPECT_EQ(next->status, 200) << next->body;
  std::printf("512x512 render alone %.2f s; the same after two abandoned ones %.2f s\n", full_s, next_s);
  EXPECT_LT(next_s, 1.5 * full_s) << "the abandoned renders kept the slot";
}

// Health probes answer while every HTTP worker waits for a render slot
// (before, twelve big renders queued on one slot took /healthz down with
// them): the door answers them itself.
TEST_F(HttpApiTest, ProbesAnswerWhileRendersHoldEveryWorker) {
  Scene scene;
  Camera big;
  ASSERT_NO_FATAL_FAILURE(StartWithOneRenderSlot("srv_http_probes", &scene, &big));
  std::vector<std::future<void>> renders;
  // More than cpp-httplib's 8 workers, queued for the slot (up to
  // render_wait_seconds, 30 by default); each client leaves after 3 s.
  for (int i = 0; i < 12; ++i) {
    renders.push_back(std::async(std::launch::async, [&] {
      httplib::Client c("127.0.0.1", server_->http_port());
      c.set_read_timeout(std::chrono::seconds(3));
      (void)c.Get(RenderPath(big, "&timeout_ms=300000"));
    }));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  for (const char* path : {"/healthz", "/readyz"}) {
    httplib::Client c("127.0.0.1", server_->http_port());
    c.set_read_timeout(std::chrono::seconds(2));
    const auto t0 = std::chrono::steady_clock::now();
    auto r = c.Get(path);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_TRUE(r) << path << " did not answer within 2 s";
    EXPECT_EQ(r->status, 200) << path;
    EXPECT_LT(s, 1.0) << path;
    std::printf("%s answered in %.3f s\n", path, s);
  }
  for (auto& f : renders) f.get();
}

// Issue 41: every published version comes with its latest time step baked
// for the browser; other time steps are baked on their first request and
// kept; files carry ETags (304 on a match) and versions are cached as
// immutable. The asset served is a valid one that renders the scene.
TEST_F(HttpApiTest, BakedAssetsAreServedWithEtagsAndOtherTimeStepsBakedOnRequest) {
  const std::string store = TempDir("srv_asset");
  StartHttp(TinyServerOptions(store));
  const Scene scene = TinyScans(2);
  ASSERT_EQ(UploadAndWait(scene, 0).phase(), v1::JOB_PHASE_DONE);
  const v1::Job j1 = UploadAndWait(scene, 1);
  ASSERT_EQ(j1.phase(), v1::JOB_PHASE_DONE) << j1.error();
  EXPECT_GT(Json(http_->Get("/api/jobs/" + j1.job_id()))["metrics"]["bake_seconds"].get<double>(), 0.0);
  auto metric = [&](const std::string& name) {
    auto m = http_->Get("/metrics");
    std::map<std::string, double> samples;
    EXPECT_EQ(testing_util::ParsePrometheusText(m->body, &samples), "");
    return samples[name];
  };

  // The deployed version's latest time step was baked when it was published.
  const std::string dir = TempDir("srv_asset_copy");
  auto manifest = http_->Get("/api/asset");
  ASSERT_TRUE(manifest);
  ASSERT_EQ(manifest->status, 200) << manifest->body;
  std::vector<std::string> names = {"manifest.json"};
  const json files = json::parse(manifest->body)["files"];
  for (auto it = files.begin(); it != files.end(); ++it) names.push_back(it.value().get<std::string>());
  EXPECT_GE(names.size(), 3u);  // index, atlas (and view, format 2).
  for (const std::string& file : names) {
    auto r = http_->Get(absl::StrCat("/api/asset?file=", file));
    ASSERT_TRUE(r);
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(r->get_header_value("X-Clnerf-Version"), "2");
    EXPECT_EQ(r->get_header_value("X-Clnerf-Time-Step"), "1");
    EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache");  // "The deployed one" may change.
    EXPECT_EQ(r->get_header_value("Content-Encoding"), "");  // The page decompresses index and atlas itself.
    ASSERT_TRUE(AtomicWriteFile(dir + "/" + file, r->body).ok());
  }
  EXPECT_EQ(metric("clnerf_asset_bakes_total"), 0);
  absl::StatusOr<BakedAsset> asset = LoadBakedAsset(dir);
  ASSERT_TRUE(asset.ok()) << asset.status();
  EXPECT_EQ(asset->time_step, 1);
  absl::StatusOr<RenderedView> baked = RenderBakedView(*asset, scene.test[0].camera);
  ASSERT_TRUE(baked.ok());
  EXPECT_GT(Psnr(baked->rgb, scene.test[0].image), 12.0);  // The scene, not the background.

  // An explicit version is immutable; its ETag answers 304 with no body.
  auto first = http_->Get("/api/asset?version=2&time=1&file=atlas.bin.gz");
  ASSERT_TRUE(first);
  ASSERT_EQ(first->status, 200);
  EXPECT_EQ(first->get_header_value("Cache-Control"), "public, max-age=31536000, immutable");
  const std::string etag = first->get_header_value("ETag");
  ASSERT_FALSE(etag.empty());
  auto again = http_->Get("/api/asset?version=2&time=1&file=atlas.bin.gz", {{"If-None-Match", etag}});
  ASSERT_TRUE(again);
  EXPECT_EQ(again->status, 304);
  EXPECT_TRUE(again->body.empty());
  // More viewers of the same version cost no more reads: each file was read
  // from disk once (asset_files.h) and is sent from memory.
  const double reads = metric("clnerf_asset_file_reads_total");
  EXPECT_EQ(reads, double(names.size()));
  for (int i = 0; i < 5; ++i) {
    auto r = http_->Get("/api/asset?version=2&time=1&file=atlas.bin.gz");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 200);
    EXPECT_EQ(r->body, first->body);
  }
  EXPECT_EQ(metric("clnerf_asset_file_reads_total"), reads);

  // Time step 0 of version 2 is baked on its first request, once.
  auto past = http_->Get("/api/asset?version=2&time=0");
  ASSERT_TRUE(past);
  ASSERT_EQ(past->status, 200) << past->body;
  EXPECT_EQ(json::parse(past->body)["time_step"], 0);
  EXPECT_EQ(metric("clnerf_asset_bakes_total"), 1);
  auto past_again = http_->Get("/api/asset?version=2&time=0&file=index.bin.gz");
  ASSERT_TRUE(past_again);
  EXPECT_EQ(past_again->status, 200);
  EXPECT_EQ(metric("clnerf_asset_bakes_total"), 1);
  EXPECT_EQ(metric("clnerf_renders_total{code=\"OK\"}"), 0);  // Viewing the asset costs no render.
  EXPECT_GT(metric("clnerf_asset_bytes_total"), double(first->body.size()));

  // Bad requests: their status and a message; nothing is baked for them.
  for (const auto& [path, status] : std::vector<std::pair<std::string, int>>{
           {"/api/asset?file=../version.json", 400}, {"/api/asset?file=model.ckpt", 400},
           {"/api/asset?time=2", 400}, {"/api/asset?time=-2", 400}, {"/api/asset?version=9", 404},
           {"/api/asset?version=x", 400}, {"/api/asset?place=nowhere", 404}}) {
    auto r = http_->Get(path);
    ASSERT_TRUE(r) << path;
    EXPECT_EQ(r->status, status) << path << ": " << r->body;
    EXPECT_TRUE(Json(r).contains("error")) << path;
  }
  EXPECT_EQ(metric("clnerf_asset_bakes_total"), 1);
}

// A version that cannot be baked (a proposal-sampled model has no occupancy
// grid to bake from) is published all the same; its asset request says why,
// so the viewer falls back to server frames.
TEST_F(HttpApiTest, AVersionThatCannotBeBakedIsPublishedAndItsAssetRequestSaysWhy) {
  ServerOptions o = TinyServerOptions(TempDir("srv_asset_fail"));
  o.update.model.sampler = SamplerKind::kProposal;
  StartHttp(o);
  const v1::Job j = UploadAndWait(TinyScans(1), 0);
  ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
  EXPECT_EQ(Json(http_->Get("/api/jobs/" + j.job_id()))["metrics"]["bake_failed"], 1);
  auto r = http_->Get("/api/asset");
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 500);
  EXPECT_NE(Json(r)["error"].get<std::string>().find("proposal"), std::string::npos) << r->body;
  EXPECT_EQ(Json(http_->Get("/api/info"))["deployed_version"], 1);
}

}  // namespace
}  // namespace clnerf
