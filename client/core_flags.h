// Flags bound straight onto core Options structs, shared by the verbs that
// take them (`train`, `bench scenes`, `bench continual`, ...). Each binds to
// the struct's own field, so the help text shows the core default and there
// is no second copy of it. Not thread-safe (CLI set-up).
#ifndef CLNERF_CLIENT_CORE_FLAGS_H_
#define CLNERF_CLIENT_CORE_FLAGS_H_

#include "CLI/CLI.hpp"
#include "core/data/dataset_options.h"
#include "core/data/procedural_scene.h"
#include "core/pose/pose_check.h"
#include "core/train/fit.h"

namespace clnerf {

// The learning rate and the training priors: distortion, near density,
// grid decay, coarse-to-fine levels, random background, opacity entropy.
void BindRegulariserFlags(CLI::App* command, TrainOptions* train);

// What `clnerf train` trains with: steps, seed, threads, learning rate,
// batch, PSNR-vs-time curve, the capacity overrides and the regularisers.
void BindFitFlags(CLI::App* command, FitOptions* fit);

// The dataset loader's options: downscale, image folder, test split,
// per-split cap, bounded instant-ngp scenes.
void BindDatasetFlags(CLI::App* command, DatasetOptions* dataset);

// The pose check's pairs and thresholds (core/pose/pose_check.h).
void BindPoseCheckFlags(CLI::App* command, PoseCheckOptions* check);

// --size N: square images of a procedural scene (width and height).
void BindSquareSizeFlag(CLI::App* command, ProceduralSceneOptions* scene);

}  // namespace clnerf

#endif  // CLNERF_CLIENT_CORE_FLAGS_H_
