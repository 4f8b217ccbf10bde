#include "client/core_flags.h"

#include "client/verb_set.h"

namespace clnerf {

void BindRegulariserFlags(CLI::App* c, TrainOptions* to) {
  TrainOptions& t = *to;
  c->add_option("--lr", t.learning_rate, "Initial learning rate")->capture_default_str();
  // Regularisers (< 0: automatic, see core/train/trainer.h).
  c->add_option("--distortion", t.distortion_reg,
                "Distortion-loss weight (< 0: 0.01 for real captures, 0 for objects)")
      ->capture_default_str();
  c->add_option("--distortion-warmup", t.distortion_warmup,
                "Raise the distortion weight linearly from 0 over this fraction of training (0 = constant)")
      ->capture_default_str();
  c->add_option("--near-density", t.near_density_reg,
                "Occlusion-penalty weight on density near the cameras (< 0: 0.01 for real captures, 0 for objects)")
      ->capture_default_str();
  c->add_option("--near-density-distance", t.near_density_distance,
                "Distance from the camera, in model units, within which density is penalised")
      ->capture_default_str();
  c->add_option("--near-density-fade", t.near_density_fade,
                "Fade the occlusion penalty to 0 over this fraction of training (0 = constant)")
      ->capture_default_str();
  c->add_option("--grid-decay", t.grid_decay,
                "Normalised weight decay on the hash grid's features (Zip-NeRF uses 0.1; 0 = off; docs/clean_fields.md)")
      ->capture_default_str();
  c->add_option("--coarse-to-fine", t.coarse_to_fine,
                "Switch the hash levels on coarse to fine over this fraction of training (0 = off)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  c->add_flag("--random-background", t.random_background, "Real captures: train on random background colours");
  c->add_option("--opacity-reg", t.opacity_reg, "Weight of the ray-opacity entropy prior mean(-o log o)")
      ->capture_default_str();
}

void BindFitFlags(CLI::App* c, FitOptions* fo) {
  TrainOptions& t = fo->train;
  c->add_option("--iters", t.iterations, "Training steps")->capture_default_str();
  c->add_option("--seed", t.seed, "Random seed")->capture_default_str();
  BindThreadsFlag(c, &t.threads);
  c->add_option("--batch-samples", t.target_samples, "Samples per batch (rays adapt)")->capture_default_str();
  c->add_option("--curve-every", fo->curve_every, "Evaluate held-out views every N steps (PSNR-vs-time curve)")
      ->capture_default_str();
  c->add_option("--curve-views", fo->curve_views, "Held-out views per curve point")->capture_default_str();
  // Capacity: derived from the scene unless given (core/field/capacity.h).
  CapacityOverrides& o = fo->overrides;
  c->add_option("--levels", fo->model.grid.levels, "Hash-grid levels")->capture_default_str();
  c->add_option("--table-log2", o.log2_table_size, "log2 entries per level (default: derived from the scene)");
  c->add_option("--finest-res", o.finest_resolution, "Finest grid resolution (default: derived)");
  c->add_option("--steps-per-diagonal", o.steps_per_diagonal, "March steps across the box diagonal (default: derived)");
  c->add_option("--occupancy-res", o.occupancy_resolution, "Occupancy grid resolution (default: derived)");
  c->add_option("--cone-angle", o.cone_angle, "March cone angle (exponential steps; default: derived)");
  c->add_option("--near", o.near, "Near plane in model units (default: derived)");
  c->add_option("--occupancy-threshold", o.occupancy_threshold,
                "Occupancy density threshold (default: derived from the minimum step)");
  c->add_option("--occupancy-decay", fo->model.occupancy.decay,
                 "Occupancy grid: each refreshed cell's density EMA keeps max(decay * old, new) (docs/render_cost.md)")
      ->capture_default_str();
  BindRegulariserFlags(c, &t);
  BindEnumFlag(c, "--sampler", &fo->model.sampler, {SamplerKind::kAuto, SamplerKind::kOccupancy, SamplerKind::kProposal},
               SamplerKindName,
               "How samples are placed: occupancy-grid marching, proposal fields, or auto (occupancy marching; "
               "see docs/proposal_sampling.md)");
  ProposalOptions& po = fo->model.proposal;
  c->add_option("--proposal-samples", po.samples0, "Proposal sampling: first-stage samples per ray")->capture_default_str();
  c->add_option("--proposal-samples2", po.samples1, "Proposal sampling: second-stage samples per ray (0 = one stage)")
      ->capture_default_str();
  c->add_option("--nerf-samples", po.nerf_samples, "Proposal sampling: full-field samples per ray")->capture_default_str();
  c->add_option("--interlevel", t.interlevel_weight, "Proposal sampling: interlevel-loss weight")->capture_default_str();
  c->add_option("--depth-weight", t.depth_weight,
                "Sparse-depth loss weight (captures with points: COLMAP points3D, ply_file_path)")
      ->capture_default_str();
  c->add_option("--depth-sigma", t.depth_sigma, "Sparse-depth loss: Gaussian width in model units")
      ->capture_default_str();
  c->add_option("--depth-fraction", fo->depth_fraction,
                "Share of each batch drawn from pixels with a known depth: sparse-depth supervision from the "
                "capture's points, e.g. 0.125 (0 = off; docs/sparse_depth.md)")
      ->capture_default_str();
  c->add_flag("--view-colour,!--no-view-colour", t.view_colour,
              "Per-photo affine colour transforms learned in training (exposure / white balance; test views use "
              "the identity; docs/appearance.md)")
      ->capture_default_str();
  c->add_option("--view-colour-prior", t.view_colour_prior, "Weight of the per-photo colour transforms' identity prior")
      ->capture_default_str();
  c->add_option("--view-colour-lr", t.view_colour_lr_scale,
                "Learning-rate scale of the per-photo colour transforms")
      ->capture_default_str();
  c->add_option("--error-share", fo->view_error.error_share,
                "Share of training rays drawn where the model is still wrong (views or tiles in proportion to "
                "their error, as a place's first scan trains in the service; 0 = uniform)")
      ->capture_default_str();
  c->add_option("--error-tiles", fo->view_error.tiles, "Error sampling: tiles per view side")->capture_default_str();
  c->add_option("--error-decay", fo->view_error.decay, "Error sampling: per-step decay of the error estimates")
      ->capture_default_str();
  c->add_flag("--prune", fo->prune,
              "After training, drop occupancy cells no training pixel needs (faster renders; docs/render_cost.md)");
  c->add_option("--prune-max-drop", fo->prune_options.max_psnr_drop,
                "Pruning: PSNR (dB) it may cost on training pixels")
      ->capture_default_str();
  c->add_flag("!--no-embed", fo->model.network.use_embeddings, "Disable per-time-step embeddings");
}

void BindDatasetFlags(CLI::App* c, DatasetOptions* d) {
  c->add_option("--downscale", d->downscale, "Shrink images by this factor")->capture_default_str();
  c->add_option("--images-dir", d->images_dir,
                "COLMAP/LLFF: image folder, absolute or relative to the dataset (default: images_N/ or images/)");
  c->add_option("--test-every", d->test_every,
                "transforms.json without a split, COLMAP, LLFF: every N-th view is a test view (0 = none)")
      ->capture_default_str();
  c->add_option("--max-images", d->max_images_per_split, "Keep at most this many views per split (0 = all)")
      ->capture_default_str();
  c->add_flag("--ngp-bounded", d->ngp_bounded, "transforms.json: a bounded object scene (white background)");
  c->add_flag("--depth-from-images", d->sparse_depth_from_images,
              "Real captures without points: sparse depth from the images' own plane-sweep matches");
  c->add_flag("!--no-sparse-depth", d->sparse_depth,
              "Do not attach depth targets from the capture's points (COLMAP points3D, ply_file_path)");
}

void BindSquareSizeFlag(CLI::App* c, ProceduralSceneOptions* scene) {
  c->add_option_function<int>(
       "--size", [scene](int size) { scene->width = scene->height = size; }, "Image size (pixels)")
      ->default_str(std::to_string(scene->width));
}

void BindPoseCheckFlags(CLI::App* c, PoseCheckOptions* o) {
  c->add_option("--check-max-side", o->max_side, "Pose check: photos matched at most this many pixels on their long side")
      ->capture_default_str();
  c->add_option("--check-features", o->max_features, "Pose check: SIFT keypoints per photo")->capture_default_str();
  c->add_option("--check-ratio", o->ratio, "Pose check: Lowe's ratio test")->capture_default_str();
  c->add_option("--check-sequence-neighbours", o->sequence_neighbours,
                "Pose check: each frame is checked against the next N frames in the capture's order")
      ->capture_default_str();
  c->add_option("--check-min-inliers", o->min_inliers, "Pose check: essential-matrix inliers a pair needs to count")
      ->capture_default_str();
  c->add_option("--check-max-disagreement", o->max_disagreement_deg,
                "Pose check: degrees between the photos' and the poses' rotation above which a pair disagrees")
      ->capture_default_str();
  c->add_option("--check-estimator", o->estimator, "Pose check: essential-matrix estimator, usac or ransac")
      ->capture_default_str();
  c->add_option("--check-chance-ratio", o->min_chance_ratio,
                "Pose check: a pair counts with this many times the inliers of its matches shuffled (0 = off)")
      ->capture_default_str();
  c->add_option("--check-pose-px", o->pose_px,
                "Pose check: a match is explained by the poses within this many pixels of their epipolar line")
      ->capture_default_str();
  c->add_option("--check-explained", o->min_explained_fraction,
                "Pose check: a turned pair still agrees when the poses explain this fraction of its inliers (0 = off)")
      ->capture_default_str();
}

}  // namespace clnerf
