#include "core/pose/pose_arbitration.h"

#include <chrono>
#include <cmath>
#include <set>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/data/stopwatch.h"
#include "core/pose/similarity.h"

namespace clnerf {

absl::Status ArbitrationOptions::Validate() const {
  if (!(rotation_deg > 0) || !(centre > 0)) {
    return absl::InvalidArgumentError("arbitration rotation_deg and centre must be > 0");
  }
  if (max_side < 16) return absl::InvalidArgumentError("arbitration max_side must be at least 16");
  if (!(margin >= 0 && margin < 2)) return absl::InvalidArgumentError("arbitration margin must be in [0, 2)");
  return absl::OkStatus();
}

std::string ArbitrationReport::Summary() const {
  std::string s = absl::StrFormat("%d of %d disputed frames moved to their PnP pose", taken, disputed);
  for (const FrameArbitration& f : frames) {
    absl::StrAppendFormat(&s, "%s frame %d%s (%.1f deg, %.1f%% apart; correlation %.2f registered, %.2f PnP%s)",
                          &f == &frames.front() ? ":" : ",", f.frame, f.suspect ? (f.weak ? " (suspect, weak PnP)" : " (suspect)") : "", f.rotation_deg,
                          100 * f.centre, f.ncc_registered, f.ncc_localized, f.took_localized ? ", moved" : "");
  }
  if (confirmed > 0 || !dropped.empty()) {
    absl::StrAppendFormat(&s, "; of the frames the pose check disputed, %d confirmed by PnP, %d dropped", confirmed,
                          int(dropped.size()));
  }
  return s;
}

namespace {

std::vector<double> GreyValues(const Image& im) {
  std::vector<double> g(im.num_pixels());
  for (size_t i = 0; i < g.size(); ++i) g[i] = Luma(im.rgb.data() + 3 * i);
  return g;
}

}  // namespace

absl::StatusOr<double> MapCorrelation(const PlaceMap& map, const Image& photo, const Camera& camera, int max_side) {
  const Intrinsics& in = camera.intrinsics;
  if (photo.width != in.width || photo.height != in.height) {
    return absl::InvalidArgumentError(absl::StrFormat("the photo is %dx%d, its camera %dx%d", photo.width,
                                                      photo.height, in.width, in.height));
  }
  const Camera small = CameraWithSideIn(camera, 1, max_side);
  absl::StatusOr<MapView> view = map.Render(small);
  if (!view.ok()) return view.status();
  const Image shrunk = ResizeImage(photo, small.intrinsics.width, small.intrinsics.height);
  const std::vector<double> a = GreyValues(shrunk), b = GreyValues(view->rgb);
  if (a.size() != b.size() || a.empty()) return absl::InternalError("the map's render does not match its camera");
  double ma = 0, mb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ma += a[i];
    mb += b[i];
  }
  ma /= double(a.size());
  mb /= double(b.size());
  double ab = 0, aa = 0, bb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ab += (a[i] - ma) * (b[i] - mb);
    aa += (a[i] - ma) * (a[i] - ma);
    bb += (b[i] - mb) * (b[i] - mb);
  }
  const double flat = 1e-8 * double(a.size());
  if (!(aa > flat) || !(bb > flat)) return absl::InvalidArgumentError("the photo or the map's render is flat");
  return ab / std::sqrt(aa * bb);
}

namespace {

// The disputed frame `f` (scene view `v`, PnP pose `pnp`) arbitrated: true
// when its PnP pose won (and `v` moved there); errors are the map's own.
absl::StatusOr<bool> ArbitrateOne(const PlaceMap& map, const Pose& pnp, const ArbitrationOptions& options, View* v,
                                  FrameArbitration* f) {
  Camera at_pnp = v->camera;
  at_pnp.c2w = pnp;
  absl::StatusOr<double> registered = MapCorrelation(map, v->image, v->camera, options.max_side);
  absl::StatusOr<double> localized = MapCorrelation(map, v->image, at_pnp, options.max_side);
  for (const absl::StatusOr<double>* c : {&registered, &localized}) {
    if (!c->ok() && !absl::IsInvalidArgument(c->status())) return c->status();  // The map failed.
  }
  if (!localized.ok()) return false;  // No case for moving it.
  // A registered pose whose render cannot be compared (flat: empty space)
  // loses to any localised pose that can.
  f->ncc_registered = registered.ok() ? *registered : -1.0;
  f->ncc_localized = *localized;
  f->took_localized = f->ncc_localized >= f->ncc_registered + options.margin;
  if (f->took_localized) v->camera.c2w = pnp;
  return f->took_localized;
}

}  // namespace

absl::StatusOr<ArbitrationReport> ArbitrateDisputedFrames(const std::vector<FrameLocalization>& localized,
                                                          const std::vector<int>& tried, const PlaceMap& map,
                                                          double extent, Scene* scene,
                                                          const ArbitrationOptions& options,
                                                          const std::vector<int>& suspect) {
  if (absl::Status s = options.Validate(); !s.ok()) return s;
  const auto t0 = std::chrono::steady_clock::now();
  const std::set<int> distrusted(suspect.begin(), suspect.end());
  std::set<int> vouched;  // Suspect frames the map vouched for.
  ArbitrationReport out;
  for (size_t k = 0; k < tried.size() && k < localized.size(); ++k) {
    const FrameLocalization& l = localized[k];
    const size_t i = size_t(tried[k]);
    const bool suspect = distrusted.count(int(i)) > 0;
    // A weak PnP pose is a candidate for a suspect frame only.
    if (!(l.placed || (suspect && l.weak)) || i >= scene->train.size() || !l.c2w.allFinite()) continue;
    View& v = scene->train[i];
    FrameArbitration f;
    f.frame = int(i);
    f.suspect = suspect;
    f.weak = !l.placed;
    f.rotation_deg = RotationAngleDegrees(v.camera.c2w.leftCols<3>().cast<double>(), l.c2w.leftCols<3>().cast<double>());
    f.centre = extent > 0 ? double((v.camera.position() - l.c2w.col(3)).norm()) / extent : 0.0;
    if (f.rotation_deg <= options.rotation_deg && f.centre <= options.centre) {
      if (f.suspect) {
        ++out.confirmed;
        vouched.insert(f.frame);
      }
      continue;
    }
    ++out.disputed;
    absl::StatusOr<bool> moved = ArbitrateOne(map, l.c2w, options, &v, &f);
    if (!moved.ok()) return moved.status();
    if (*moved) {
      ++out.taken;
      vouched.insert(f.frame);
    }
    out.frames.push_back(f);
  }
  for (int i : distrusted) {
    if (!vouched.count(i)) out.dropped.push_back(i);
  }
  out.seconds = SecondsSince(t0);
  return out;
}

}  // namespace clnerf
