// Metrics: image-quality measures used to evaluate novel-view renders, with
// the conventions of NeRF papers and torchmetrics / tf.image.
//
//  * PSNR = -10 log10(MSE) for a data range of 1, where the MSE runs over all
//    pixels and channels. Identical images give +infinity.
//  * SSIM uses an 11x11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03 and
//    a data range of 1. It is computed per channel on the 'valid' region only
//    (window positions that fit entirely inside the image, i.e. the image
//    shrunk by 5 pixels on every side), then averaged over channels and
//    positions. This equals tf.image.ssim and torchmetrics'
//    StructuralSimilarityIndexMeasure (which pads and then crops the border).
//    The filter is separable and evaluated in double precision.
//  * Datasets are summarised by averaging per-image values (MeanMetrics); for
//    PSNR this is the mean of per-image PSNRs, as reported in NeRF papers, not
//    the PSNR of the pooled MSE.
//
// Pixel values are used as given (no clamping); clamp predictions to [0, 1]
// first if the model can overshoot.
//
// Error handling: Psnr/Ssim/Mse are unchecked and have the precondition that
// both images have the same, non-empty size (Ssim: at least 11x11); on a
// violation they return NaN rather than crash. The ComputeImageMetrics*
// functions check their inputs and return INVALID_ARGUMENT instead.
//
// Thread safety: every function is pure and may be called concurrently.
// ComputeImageMetricsBatch parallelises over images with OpenMP when the
// library is built with it.
#ifndef CLNERF_CORE_RENDER_METRICS_H_
#define CLNERF_CORE_RENDER_METRICS_H_

#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/data/image.h"

namespace clnerf {

// Side length of the SSIM window; SSIM needs images at least this large.
inline constexpr int kSsimWindowSize = 11;

struct ImageMetrics {
  double psnr = 0.0;  // dB; +infinity for identical images.
  double ssim = 0.0;  // In [-1, 1]; 1 for identical images.
  double psnr_cc = 0.0;  // Colour-corrected PSNR (ColourCorrectedPsnr).
};

// Mean squared error over all pixels and channels. NaN if sizes differ/empty.
double Mse(const Image& a, const Image& b);

// -10 log10(mse): +infinity for mse == 0, NaN for negative/NaN mse.
double PsnrFromMse(double mse);

// PSNR with data range 1. Precondition: same non-empty size (else NaN).
double Psnr(const Image& a, const Image& b);

// SSIM (see above). Symmetric in its arguments. Precondition: same size, both
// sides >= kSsimWindowSize (else NaN).
double Ssim(const Image& a, const Image& b);

// Colour-corrected PSNR: the PSNR after mapping the prediction's colours
// through the affine map (3x4, least squares over all pixels, in double)
// that best fits them to the target's, clamped to [0, 1]: what multinerf's
// eval reports beside the raw PSNR, so a gap that is only exposure or white
// balance (phone videos change both from frame to frame; a test view has no
// trained per-image embedding) can be told from a gap in geometry or
// texture. It is >= the raw PSNR up to the clamp. Precondition as Psnr (else
// NaN); an ill-conditioned fit (e.g. a constant prediction) falls back to the
// best constant per channel.
double ColourCorrectedPsnr(const Image& prediction, const Image& target);
// The corrected prediction itself.
Image ColourCorrect(const Image& prediction, const Image& target);

// Returns OK if `a` and `b` can be compared: same size, well-formed pixel
// buffers, and at least kSsimWindowSize pixels on each side. INVALID_ARGUMENT
// naming the problem otherwise.
absl::Status CheckComparableImages(const Image& a, const Image& b);

// Checked PSNR + SSIM of one prediction against its ground truth.
absl::StatusOr<ImageMetrics> ComputeImageMetrics(const Image& prediction, const Image& target);

// Checked per-image metrics for parallel lists of predictions and targets
// (same length; pair i is predictions[i] vs targets[i]). Fails on the first
// bad pair, naming its index.
absl::StatusOr<std::vector<ImageMetrics>> ComputeImageMetricsBatch(
    const std::vector<Image>& predictions, const std::vector<Image>& targets);

// Averages per-image values (PSNR averaged in dB, per image). An empty input
// gives NaN for both fields; any +infinity PSNR (an identical pair) makes the
// mean PSNR +infinity.
ImageMetrics MeanMetrics(const std::vector<ImageMetrics>& per_image);

}  // namespace clnerf

#endif  // CLNERF_CORE_RENDER_METRICS_H_
