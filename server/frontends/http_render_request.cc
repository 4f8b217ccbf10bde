#include "server/frontends/http_render_request.h"

#include <cmath>
#include <set>
#include <vector>

#include "Eigen/Geometry"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "server/common/log_util.h"

namespace clnerf {

namespace {

constexpr int kMaxSide = 16384;

const std::set<std::string>& Known() {
  static const std::set<std::string> k = {"width", "height", "eye",  "target",  "up",   "c2w",     "convention",
                                          "fov",   "fx",     "fy",   "cx",      "cy",   "time",    "version",
                                          "format", "quality", "view", "timeout_ms", "place"};
  return k;
}

absl::Status Bad(const std::string& param, const std::string& why) {
  return absl::InvalidArgumentError(absl::StrCat("parameter '", param, "': ", why));
}

std::string Shown(const std::string& v) { return EscapeForLog(v, 64); }

absl::StatusOr<int64_t> ParseInt(const std::string& name, const std::string& v, int64_t lo, int64_t hi) {
  int64_t x = 0;
  if (!absl::SimpleAtoi(v, &x)) return Bad(name, absl::StrCat("'", Shown(v), "' is not an integer"));
  if (x < lo || x > hi) return Bad(name, absl::StrCat(x, " is outside ", lo, "..", hi));
  return x;
}

absl::StatusOr<float> ParseFloat(const std::string& name, const std::string& v) {
  float x = 0;
  if (!absl::SimpleAtof(v, &x) || !std::isfinite(x)) {
    return Bad(name, absl::StrCat("'", Shown(v), "' is not a finite number"));
  }
  return x;
}

absl::StatusOr<std::vector<float>> ParseList(const std::string& name, const std::string& v, size_t n) {
  std::vector<std::string> parts = absl::StrSplit(v, ',');
  if (parts.size() != n) return Bad(name, absl::StrCat("needs ", n, " comma-separated numbers, got ", parts.size()));
  std::vector<float> out;
  for (const std::string& p : parts) {
    absl::StatusOr<float> x = ParseFloat(name, p);
    if (!x.ok()) return x.status();
    out.push_back(*x);
  }
  return out;
}

absl::StatusOr<Eigen::Vector3f> ParseVec3(const std::string& name, const std::string& v) {
  absl::StatusOr<std::vector<float>> l = ParseList(name, v, 3);
  if (!l.ok()) return l.status();
  return Eigen::Vector3f((*l)[0], (*l)[1], (*l)[2]);
}

bool ValidViewId(const std::string& id) {
  if (id.empty() || id.size() > 64) return false;
  for (char c : id) {
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-')) return false;
  }
  return true;
}

}  // namespace

absl::StatusOr<Pose> LookAtPose(const Eigen::Vector3f& eye, const Eigen::Vector3f& target, const Eigen::Vector3f& up) {
  const Eigen::Vector3f f = target - eye;
  if (!(f.norm() > 1e-6f * std::max(1.0f, eye.norm()))) return Bad("target", "must differ from eye");
  const Eigen::Vector3f z = f.normalized();
  if (!(up.norm() > 0)) return Bad("up", "must be a non-zero vector");
  const Eigen::Vector3f r = z.cross(up.normalized());
  if (!(r.norm() > 1e-4f)) return Bad("up", "is parallel to the viewing direction (target - eye)");
  const Eigen::Vector3f x = r.normalized();
  const Eigen::Vector3f y = z.cross(x);  // Down in the image.
  Pose p;
  p.col(0) = x;
  p.col(1) = y;
  p.col(2) = z;
  p.col(3) = eye;
  return p;
}

absl::StatusOr<HttpRenderRequest> ParseRenderQuery(const std::multimap<std::string, std::string>& params) {
  std::map<std::string, std::string> q;
  for (const auto& [k, v] : params) {
    if (!Known().count(k)) {
      return absl::InvalidArgumentError(absl::StrCat("unknown parameter '", Shown(k),
                                                     "'; known: ", absl::StrJoin(Known(), ", ")));
    }
    if (!q.emplace(k, v).second) return Bad(k, "is given more than once");
  }
  auto has = [&](const char* k) { return q.count(k) > 0; };
  HttpRenderRequest r;
  Intrinsics& in = r.camera.intrinsics;
  for (const char* k : {"width", "height"}) {
    if (!has(k)) return Bad(k, "is required");
    absl::StatusOr<int64_t> v = ParseInt(k, q[k], 1, kMaxSide);
    if (!v.ok()) return v.status();
    (std::string(k) == "width" ? in.width : in.height) = int(*v);
  }

  // Pose.
  const bool look_at = has("eye") || has("target") || has("up");
  if (look_at == has("c2w")) return Bad("c2w", "give either eye + target + up or c2w (exactly one camera pose)");
  if (look_at) {
    for (const char* k : {"eye", "target", "up"}) {
      if (!has(k)) return Bad(k, "is required with the look-at form (eye, target, up)");
    }
    if (has("convention")) return Bad("convention", "applies to c2w only");
    absl::StatusOr<Eigen::Vector3f> eye = ParseVec3("eye", q["eye"]);
    if (!eye.ok()) return eye.status();
    absl::StatusOr<Eigen::Vector3f> target = ParseVec3("target", q["target"]);
    if (!target.ok()) return target.status();
    absl::StatusOr<Eigen::Vector3f> up = ParseVec3("up", q["up"]);
    if (!up.ok()) return up.status();
    absl::StatusOr<Pose> p = LookAtPose(*eye, *target, *up);
    if (!p.ok()) return p.status();
    r.camera.c2w = *p;
  } else {
    absl::StatusOr<std::vector<float>> m = ParseList("c2w", q["c2w"], 12);
    if (!m.ok()) return m.status();
    Pose p;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 4; ++j) p(i, j) = (*m)[size_t(i * 4 + j)];
    }
    PoseConvention conv = PoseConvention::kOpenCV;
    if (has("convention")) {
      if (q["convention"] == "opengl") {
        conv = PoseConvention::kOpenGL;
      } else if (q["convention"] != "opencv") {
        return Bad("convention", absl::StrCat("'", Shown(q["convention"]), "' is not opencv or opengl"));
      }
    }
    r.camera.c2w = ConvertPose(p, conv);
  }

  // Intrinsics.
  const bool pixels = has("fx") || has("fy") || has("cx") || has("cy");
  if (pixels && has("fov")) return Bad("fov", "give either fov or fx/fy (with optional cx/cy), not both");
  if (pixels) {
    for (const char* k : {"fx", "fy"}) {
      if (!has(k)) return Bad(k, "is required with pixel intrinsics");
    }
    float* dst[4] = {&in.fx, &in.fy, &in.cx, &in.cy};
    const char* names[4] = {"fx", "fy", "cx", "cy"};
    in.cx = in.width * 0.5f;
    in.cy = in.height * 0.5f;
    for (int i = 0; i < 4; ++i) {
      if (!has(names[i])) continue;
      absl::StatusOr<float> v = ParseFloat(names[i], q[names[i]]);
      if (!v.ok()) return v.status();
      *dst[i] = *v;
    }
    if (!(in.fx > 0) || !(in.fy > 0)) return Bad("fx", "focal lengths must be positive");
  } else {
    float fov = 50;
    if (has("fov")) {
      absl::StatusOr<float> v = ParseFloat("fov", q["fov"]);
      if (!v.ok()) return v.status();
      fov = *v;
    }
    if (!(fov >= 1 && fov <= 170)) return Bad("fov", absl::StrCat(fov, " degrees is outside 1..170"));
    in.fy = in.fx = 0.5f * in.height / std::tan(fov * float(M_PI) / 360.0f);
    in.cx = in.width * 0.5f;
    in.cy = in.height * 0.5f;
  }
  if (absl::Status s = ValidateCamera(r.camera); !s.ok()) return s;

  if (has("time")) {
    absl::StatusOr<int64_t> t = ParseInt("time", q["time"], 0, 1 << 30);
    if (!t.ok()) return t.status();
    r.time_step = int(*t);
  }
  if (has("version")) {
    absl::StatusOr<int64_t> v = ParseInt("version", q["version"], 0, int64_t(1) << 62);
    if (!v.ok()) return v.status();
    r.version = *v;
  }
  if (has("format")) {
    const std::string& f = q["format"];
    if (f == "png") {
      r.format = HttpImageFormat::kPng;
    } else if (f != "jpeg" && f != "jpg") {
      return Bad("format", absl::StrCat("'", Shown(f), "' is not jpeg or png"));
    }
  }
  if (has("quality")) {
    if (r.format != HttpImageFormat::kJpeg) return Bad("quality", "applies to format=jpeg only");
    absl::StatusOr<int64_t> v = ParseInt("quality", q["quality"], 1, 100);
    if (!v.ok()) return v.status();
    r.quality = int(*v);
  }
  if (has("view")) {
    if (!ValidViewId(q["view"])) return Bad("view", "must be 1..64 characters of A-Z a-z 0-9 _ -");
    r.view_id = q["view"];
  }
  if (has("timeout_ms")) {
    absl::StatusOr<int64_t> v = ParseInt("timeout_ms", q["timeout_ms"], 1, 600000);
    if (!v.ok()) return v.status();
    r.timeout_ms = *v;
  }
  return r;
}

}  // namespace clnerf
