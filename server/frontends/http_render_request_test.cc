#include "server/frontends/http_render_request.h"

#include <cmath>
#include <map>
#include <string>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

using Query = std::multimap<std::string, std::string>;

Query LookAt() {
  return {{"width", "64"}, {"height", "48"}, {"eye", "0,-4,1"}, {"target", "0,0,1"}, {"up", "0,0,1"}};
}

// Pixel coordinates of world point `p` in `cam` (pinhole).
Eigen::Vector2f Project(const Camera& cam, const Eigen::Vector3f& p) {
  const Eigen::Matrix3f r = cam.c2w.leftCols<3>();
  const Eigen::Vector3f c = r.transpose() * (p - cam.c2w.col(3));
  const Intrinsics& in = cam.intrinsics;
  return {in.fx * c.x() / c.z() + in.cx, in.fy * c.y() / c.z() + in.cy};
}

TEST(HttpRenderRequestTest, LookAtPutsTheTargetAtTheCentreWithUpUp) {
  absl::StatusOr<HttpRenderRequest> r = ParseRenderQuery(LookAt());
  ASSERT_TRUE(r.ok()) << r.status();
  const Camera& cam = r->camera;
  EXPECT_EQ(cam.intrinsics.width, 64);
  EXPECT_EQ(cam.intrinsics.height, 48);
  const Eigen::Vector2f centre = Project(cam, {0, 0, 1});
  EXPECT_NEAR(centre.x(), 32, 1e-3);
  EXPECT_NEAR(centre.y(), 24, 1e-3);
  EXPECT_LT(Project(cam, {0, 0, 1.5f}).y(), 24) << "a point above the target is higher in the image";
  EXPECT_GT(Project(cam, {0.5f, 0, 1}).x(), 32) << "+x is to the right, seen from -y";
  // fov 50 (default): fy = h / 2 / tan(25 deg).
  EXPECT_NEAR(cam.intrinsics.fy, 24 / std::tan(25 * M_PI / 180), 1e-3);
  EXPECT_FALSE(r->time_step.has_value());
  EXPECT_EQ(r->version, 0);
  EXPECT_EQ(r->format, HttpImageFormat::kJpeg);
  EXPECT_EQ(r->quality, 85);
}

TEST(HttpRenderRequestTest, MatrixFormInBothConventions) {
  // Looks along world +y from (1,2,3): OpenCV columns x=(1,0,0) y=(0,0,-1) z=(0,1,0).
  Query q = {{"width", "8"}, {"height", "8"}, {"c2w", "1,0,0,1, 0,0,1,2, 0,-1,0,3"}, {"fx", "10"}, {"fy", "11"}};
  absl::StatusOr<HttpRenderRequest> cv = ParseRenderQuery(q);
  ASSERT_TRUE(cv.ok()) << cv.status();
  EXPECT_NEAR(cv->camera.c2w(1, 2), 1, 1e-6);
  EXPECT_NEAR(cv->camera.c2w(2, 3), 3, 1e-6);
  EXPECT_EQ(cv->camera.intrinsics.fx, 10);
  EXPECT_EQ(cv->camera.intrinsics.cx, 4);
  // The same camera in OpenGL: y and z columns negated.
  Query gl = {{"width", "8"},  {"height", "8"}, {"c2w", "1,0,0,1,0,0,-1,2,0,1,0,3"}, {"convention", "opengl"},
              {"fx", "10"},    {"fy", "11"}};
  absl::StatusOr<HttpRenderRequest> g = ParseRenderQuery(gl);
  ASSERT_TRUE(g.ok()) << g.status();
  EXPECT_TRUE(g->camera.c2w.isApprox(cv->camera.c2w, 1e-6f));
}

TEST(HttpRenderRequestTest, OptionsParse) {
  Query q = LookAt();
  q.insert({{"time", "2"}, {"version", "7"}, {"format", "jpeg"}, {"quality", "60"}, {"view", "left-1_a"},
            {"timeout_ms", "500"}, {"fov", "90"}});
  absl::StatusOr<HttpRenderRequest> r = ParseRenderQuery(q);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->time_step, 2);
  EXPECT_EQ(r->version, 7);
  EXPECT_EQ(r->quality, 60);
  EXPECT_EQ(r->view_id, "left-1_a");
  EXPECT_EQ(r->timeout_ms, 500);
  EXPECT_NEAR(r->camera.intrinsics.fy, 24, 1e-3);
  Query png = LookAt();
  png.insert({"format", "png"});
  EXPECT_EQ(ParseRenderQuery(png)->format, HttpImageFormat::kPng);
}

// Each bad query is INVALID_ARGUMENT and the message names the parameter.
TEST(HttpRenderRequestTest, BadQueriesNameTheParameter) {
  struct Case {
    Query q;
    std::string names;
  };
  auto with = [](std::initializer_list<std::pair<const std::string, std::string>> extra) {
    Query q = LookAt();
    q.insert(extra);
    return q;
  };
  auto without = [](const std::string& k) {
    Query q = LookAt();
    q.erase(k);
    return q;
  };
  auto replaced = [](const std::string& k, const std::string& v) {
    Query q = LookAt();
    q.erase(k);
    q.insert({k, v});
    return q;
  };
  const Case cases[] = {
      {without("width"), "width"},
      {replaced("width", "0"), "width"},
      {replaced("height", "abc"), "height"},
      {replaced("width", "99999"), "width"},
      {with({{"wdth", "3"}}), "wdth"},
      {with({{"time", "1"}, {"time", "2"}}), "time"},
      {with({{"c2w", "1,0,0,0,0,1,0,0,0,0,1,0"}}), "c2w"},
      {without("up"), "up"},
      {replaced("eye", "0,0"), "eye"},
      {replaced("eye", "nan,0,0"), "eye"},
      {replaced("target", "0,-4,1"), "target"},
      {replaced("up", "0,1,0"), "up"},
      {with({{"fov", "0"}}), "fov"},
      {with({{"fov", "40"}, {"fx", "10"}, {"fy", "10"}}), "fov"},
      {with({{"fx", "10"}}), "fy"},
      {with({{"time", "-1"}}), "time"},
      {with({{"version", "x"}}), "version"},
      {with({{"format", "gif"}}), "format"},
      {with({{"format", "png"}, {"quality", "50"}}), "quality"},
      {with({{"quality", "101"}}), "quality"},
      {with({{"view", "a b"}}), "view"},
      {with({{"view", std::string(65, 'a')}}), "view"},
      {with({{"timeout_ms", "0"}}), "timeout_ms"},
      {with({{"convention", "opengl"}}), "convention"},
  };
  for (const Case& c : cases) {
    absl::StatusOr<HttpRenderRequest> r = ParseRenderQuery(c.q);
    ASSERT_FALSE(r.ok()) << "expected an error naming " << c.names;
    EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(r.status().message().find(c.names), std::string::npos) << r.status();
  }
}

}  // namespace
}  // namespace clnerf
