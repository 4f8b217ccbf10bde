// Speckle: how much fine detail a render has that its photo does not (the
// black-and-white speckle of a hash grid in rarely seen regions, floaters'
// sharp edges, aliasing sparkle), and its counterpart, how much of the
// photo's fine detail the render lacks (blur). PSNR mixes both with every
// other error; these two say which a person would see.
//
// Per image: grey values g (Rec. 601 luma), a 3x3 high-pass h = g - box3(g),
// and its local energy e = sqrt(box7(h^2)) (RMS over a 7x7 window, so a
// detail shifted by a pixel or two still counts as present). Over the pixels
// whose windows fit inside the image:
//   speckle = mean(max(0, e_render - e_photo))
//   blur    = mean(max(0, e_photo - e_render))
// in grey levels of a [0, 1] image (0 for identical images; a render that is
// a flat photo plus grey noise uniform in [-a, a] scores 0.54 a).
//
// Thread safety: pure functions.
#ifndef CLNERF_CORE_RENDER_SPECKLE_H_
#define CLNERF_CORE_RENDER_SPECKLE_H_

#include "absl/status/statusor.h"
#include "core/data/image.h"

namespace clnerf {

struct DetailScore {
  double speckle = 0;  // Fine detail in the render the photo lacks.
  double blur = 0;     // Fine detail in the photo the render lacks.
};

// Window sizes: the high-pass's and the energy's (odd).
inline constexpr int kSpeckleHighPass = 3;
inline constexpr int kSpeckleWindow = 7;

// INVALID_ARGUMENT when the sizes differ or an image is smaller than
// kSpeckleHighPass + kSpeckleWindow - 1 on a side.
absl::StatusOr<DetailScore> ScoreDetail(const Image& render, const Image& photo);

}  // namespace clnerf

#endif  // CLNERF_CORE_RENDER_SPECKLE_H_
