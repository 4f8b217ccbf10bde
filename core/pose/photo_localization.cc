#include "core/pose/photo_localization.h"

#include "absl/strings/str_cat.h"
#include "core/data/stopwatch.h"

namespace clnerf {

namespace {

// Focal-length multipliers tried when a photo has no intrinsics.
constexpr float kFocalGuesses[] = {0.7f, 0.85f, 1.0f, 1.18f, 1.4f};

absl::Status CheckQuery(const PhotoQuery& q) {
  if (q.image.empty()) return absl::InvalidArgumentError(absl::StrCat("photo '", q.name, "' is empty"));
  if (!q.intrinsics) return absl::OkStatus();
  const Intrinsics& in = *q.intrinsics;
  if (in.width != q.image.width || in.height != q.image.height) {
    return absl::InvalidArgumentError(absl::StrCat("photo '", q.name, "' is ", q.image.width, "x", q.image.height,
                                                   " but its intrinsics say ", in.width, "x", in.height));
  }
  if (!(in.fx > 0 && in.fy > 0)) {
    return absl::InvalidArgumentError(absl::StrCat("photo '", q.name, "': focal lengths must be > 0"));
  }
  return absl::OkStatus();
}

PhotoLocation LocalizeOne(const FeatureLocalizer& loc, const PhotoQuery& q, const Camera& latest) {
  PhotoLocation out;
  out.name = q.name;
  Camera cam;
  if (q.intrinsics) {
    cam.intrinsics = *q.intrinsics;
    out.found = loc.Localize(q.image, cam);
    out.camera = cam;
  } else {
    out.intrinsics_guessed = true;
    const Intrinsics base = latest.intrinsics.Scaled(q.image.width, q.image.height);
    for (float m : kFocalGuesses) {
      cam.intrinsics = base;
      cam.intrinsics.fx *= m;
      cam.intrinsics.fy *= m;
      FrameLocalization f = loc.Localize(q.image, cam);
      if (f.placed && (!out.found.placed || f.inliers > out.found.inliers)) {
        out.found = f;
        out.camera = cam;
      } else if (!out.found.placed && f.matches > out.found.matches) {
        out.found = f;
        out.camera = cam;
      }
    }
  }
  out.camera.c2w = out.found.c2w;
  return out;
}

}  // namespace

absl::StatusOr<PhotoLocalizationReport> LocalizePhotos(const std::vector<PhotoQuery>& photos, const PlaceMap& map,
                                                       const std::vector<Camera>& place_cameras,
                                                       const RegistrationOptions& options,
                                                       const std::atomic<bool>* cancel) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  if (place_cameras.empty()) return absl::FailedPreconditionError("the place has no cameras to localise against");
  for (const PhotoQuery& q : photos) {
    if (absl::Status s = CheckQuery(q); !s.ok()) return s;
  }
  PhotoLocalizationReport r;
  auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<std::vector<MapView>> renders = RenderPlaceReferences(map, place_cameras, options, cancel);
  if (!renders.ok()) return renders.status();
  absl::StatusOr<std::unique_ptr<FeatureLocalizer>> loc = FeatureLocalizer::Build(*renders, options.localizer);
  if (!loc.ok()) return loc.status();
  r.references = int(renders->size());
  r.map_points = (*loc)->num_points();
  r.render_seconds = SecondsSince(t0);
  t0 = std::chrono::steady_clock::now();
  r.photos.resize(photos.size());
#pragma omp parallel for schedule(dynamic, 1)
  for (int i = 0; i < int(photos.size()); ++i) {
    if (cancel != nullptr && cancel->load()) continue;
    r.photos[i] = LocalizeOne(**loc, photos[i], place_cameras.back());
  }
  if (cancel != nullptr && cancel->load()) return absl::CancelledError("localisation cancelled");
  r.localize_seconds = SecondsSince(t0);
  return r;
}

}  // namespace clnerf
