#include "server/server_options.h"

#include <unistd.h>

#include <fstream>
#include <sstream>

#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"

namespace clnerf {

UpdateOptions ServerOptions::DefaultUpdateOptions() {
  UpdateOptions u;
  u.method = ContinualMethod::kCLNeRF;
  u.init = InitMode::kWarm;
  u.replay = ReplayMode::kOffline;
  u.train.iterations = 300;
  return u;
}

int64_t ResolvedModelMemoryBudget(const ServerOptions& options) {
  if (options.model_memory_budget > 0) return options.model_memory_budget;
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page <= 0) return int64_t(4) << 30;  // Unknown: 4 GiB.
  return int64_t(pages) * int64_t(page) / 2;
}

UploadLimits ServerOptions::upload_limits() const {
  UploadLimits l;
  l.max_frames = max_frames;
  l.max_scan_bytes = max_scan_bytes;
  return l;
}

absl::Status ServerOptions::Validate() const {
  if (listen.empty() || listen.find(':') == std::string::npos) {
    return absl::InvalidArgumentError(absl::StrCat("listen address '", listen, "' is not HOST:PORT"));
  }
  if (http_max_head_bytes < 1024) return absl::InvalidArgumentError("http_max_head_bytes must be at least 1024");
  if (!(http_head_timeout_seconds > 0)) return absl::InvalidArgumentError("http_head_timeout_seconds must be > 0");
  if (!http_listen.empty() && http_listen.find(':') == std::string::npos) {
    return absl::InvalidArgumentError(absl::StrCat("http address '", http_listen, "' is not HOST:PORT"));
  }
  if (store_dir.empty()) return absl::InvalidArgumentError("store directory must be set");
  if (tls_cert.empty() != tls_key.empty()) {
    return absl::InvalidArgumentError("TLS needs both a certificate and a key");
  }
  if (max_queue < 1) return absl::InvalidArgumentError("max_queue must be >= 1");
  if (render_concurrency < 1) return absl::InvalidArgumentError("render_concurrency must be >= 1");
  if (render_threads < 0) return absl::InvalidArgumentError("render_threads must be >= 0 (0 = adaptive)");
  if (small_render_pixels < 0) return absl::InvalidArgumentError("small_render_pixels must be >= 0");
  if (!(render_wait_seconds > 0)) return absl::InvalidArgumentError("render_wait_seconds must be > 0");
  if (train_threads < 1) return absl::InvalidArgumentError("train_threads must be >= 1");
  if (max_concurrent_trainings < 1) return absl::InvalidArgumentError("max_concurrent_trainings must be >= 1");
  if (train_nice < 0 || train_nice > 19) return absl::InvalidArgumentError("train_nice must be in [0, 19]");
  if (grpc_threads < 2) return absl::InvalidArgumentError("grpc_threads must be >= 2");
  if (max_message_bytes < (1 << 20) + 4096) {
    return absl::InvalidArgumentError("max_message_bytes must exceed a 1 MiB upload chunk");
  }
  if (max_scan_bytes < 1) return absl::InvalidArgumentError("max_scan_bytes must be >= 1");
  if (max_frames < 1 || max_frames > 65535) return absl::InvalidArgumentError("max_frames must be in [1, 65535]");
  if (max_render_pixels < 1) return absl::InvalidArgumentError("max_render_pixels must be >= 1");
  if (render_pixel_budget < render_concurrency) {
    return absl::InvalidArgumentError("render_pixel_budget must be >= render_concurrency");
  }
  if (max_scan_attempts < 1) return absl::InvalidArgumentError("max_scan_attempts must be >= 1");
  if (!(store_retry_seconds > 0)) return absl::InvalidArgumentError("store_retry_seconds must be > 0");
  if (lease_ttl_seconds < 1 || lease_ttl_seconds > 3600) {
    return absl::InvalidArgumentError("lease_ttl_seconds must be in [1, 3600]");
  }
  if (!(replica_poll_seconds > 0) || replica_poll_seconds > 3600) {
    return absl::InvalidArgumentError("replica_poll_seconds must be in (0, 3600]");
  }
  if (!etcd_prefix.empty() && etcd_prefix[0] != '/') return absl::InvalidArgumentError("etcd_prefix must start with '/'");
  if (model_memory_budget < 0) return absl::InvalidArgumentError("model_memory_budget must be >= 0 (0 = auto)");
  if (asset_memory_budget < 0) return absl::InvalidArgumentError("asset_memory_budget must be >= 0 (0 = no cache)");
  if (keep_versions < 0) return absl::InvalidArgumentError("keep_versions must be >= 0");
  if (!(shutdown_grace_seconds >= 0)) return absl::InvalidArgumentError("shutdown_grace_seconds must be >= 0");
  if (update.method == ContinualMethod::kEWC) {
    // The Fisher penalty is not part of a stored version, so it would not
    // survive a restart.
    return absl::InvalidArgumentError("method ewc is benchmark-only; the server supports nt, er, meil, clnerf, clnerf-noer");
  }
  if (absl::Status s = update.Validate(); !s.ok()) return s;
  if (absl::Status s = registration.Validate(); !s.ok()) return s;
  if (pose_check_action != "auto" && pose_check_action != "warn" && pose_check_action != "drop" &&
      pose_check_action != "off") {
    return absl::InvalidArgumentError("pose_check.action must be auto, warn, drop or off");
  }
  if (absl::Status s = pose_check.Validate(); !s.ok()) return s;
  SfmOptions sfm = posing;
  if (sfm.workspace.empty()) sfm.workspace = "(per job)";
  if (absl::Status s = sfm.Validate(); !s.ok()) return s;
  if (colmap_binary.empty()) return absl::InvalidArgumentError("colmap_binary is empty");
  if (first_scan_iterations < 0) return absl::InvalidArgumentError("first_scan_iterations must be >= 0");
  if (absl::Status s = bake.Validate(); !s.ok()) return s;
  return gate.Validate();
}

namespace {

template <typename T>
absl::Status Get(const nlohmann::json& j, const char* key, T* out) {
  try {
    *out = j.get<T>();
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("config key '", key, "': ", e.what()));
  }
  return absl::OkStatus();
}

absl::Status ApplyGate(const nlohmann::json& g, GateOptions* o) {
  if (!g.is_object()) return absl::InvalidArgumentError("config key 'gate' must be an object");
  for (auto it = g.begin(); it != g.end(); ++it) {
    const std::string& k = it.key();
    absl::Status s;
    if (k == "min_new_psnr") s = Get(*it, "gate.min_new_psnr", &o->min_new_psnr);
    else if (k == "max_replay_drop_db") s = Get(*it, "gate.max_replay_drop_db", &o->max_replay_drop_db);
    else if (k == "min_replay_consistency_psnr") s = Get(*it, "gate.min_replay_consistency_psnr", &o->min_replay_consistency_psnr);
    else if (k == "validation_views") s = Get(*it, "gate.validation_views", &o->validation_views);
    else if (k == "max_new_psnr_drop_db") s = Get(*it, "gate.max_new_psnr_drop_db", &o->max_new_psnr_drop_db);
    else if (k == "replay_memorised_margin_db") {
      s = Get(*it, "gate.replay_memorised_margin_db", &o->replay_memorised_margin_db);
    }
    else return absl::InvalidArgumentError(absl::StrCat("unknown config key 'gate.", k, "'"));
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status ApplyBake(const nlohmann::json& g, ServerOptions* o) {
  if (!g.is_object()) return absl::InvalidArgumentError("config key 'bake' must be an object");
  for (auto it = g.begin(); it != g.end(); ++it) {
    const std::string& k = it.key();
    absl::Status s;
    if (k == "on_publish") s = Get(*it, "bake.on_publish", &o->bake_on_publish);
    else if (k == "resolution") s = Get(*it, "bake.resolution", &o->bake.resolution);
    else if (k == "min_block_weight") s = Get(*it, "bake.min_block_weight", &o->bake.min_block_weight);
    else if (k == "visibility_rays") s = Get(*it, "bake.visibility_rays", &o->bake.visibility_rays);
    else if (k == "in_between_views") s = Get(*it, "bake.in_between_views", &o->bake.in_between_views);
    else if (k == "fit_rays") s = Get(*it, "bake.fit_rays", &o->bake.fit.rays);
    else if (k == "fit_max_entries") s = Get(*it, "bake.fit_max_entries", &o->bake.fit.max_nonzeros);
    else if (k == "fit_max_model_samples") s = Get(*it, "bake.fit_max_model_samples", &o->bake.fit.max_model_samples);
    else if (k == "density_fit_rays") s = Get(*it, "bake.density_fit_rays", &o->bake.density_fit.rays);
    else if (k == "max_asset_bytes") s = Get(*it, "bake.max_asset_bytes", &o->bake.max_asset_bytes);
    else if (k == "max_object_asset_bytes") s = Get(*it, "bake.max_object_asset_bytes", &o->bake.max_object_asset_bytes);
    else return absl::InvalidArgumentError(absl::StrCat("unknown config key 'bake.", k, "'"));
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status ApplyPosing(const nlohmann::json& g, ServerOptions* o) {
  if (!g.is_object()) return absl::InvalidArgumentError("config key 'posing' must be an object");
  for (auto it = g.begin(); it != g.end(); ++it) {
    const std::string& k = it.key();
    absl::Status s;
    if (k == "min_registered_fraction") {
      s = Get(*it, "posing.min_registered_fraction", &o->posing.min_registered_fraction);
    } else if (k == "max_reprojection_px") {
      s = Get(*it, "posing.max_reprojection_px", &o->posing.max_reprojection_px);
    } else if (k == "guided_matching") {
      s = Get(*it, "posing.guided_matching", &o->posing.guided_matching);
    } else if (k == "colmap") {
      s = Get(*it, "posing.colmap", &o->colmap_binary);
    } else {
      return absl::InvalidArgumentError(absl::StrCat("unknown config key 'posing.", k, "'"));
    }
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status ApplyPoseCheck(const nlohmann::json& g, ServerOptions* o) {
  if (!g.is_object()) return absl::InvalidArgumentError("config key 'pose_check' must be an object");
  for (auto it = g.begin(); it != g.end(); ++it) {
    const std::string& k = it.key();
    absl::Status s;
    if (k == "action") s = Get(*it, "pose_check.action", &o->pose_check_action);
    else if (k == "min_inliers") s = Get(*it, "pose_check.min_inliers", &o->pose_check.min_inliers);
    else if (k == "max_disagreement_deg") {
      s = Get(*it, "pose_check.max_disagreement_deg", &o->pose_check.max_disagreement_deg);
    }
    else if (k == "sequence_neighbours") {
      s = Get(*it, "pose_check.sequence_neighbours", &o->pose_check.sequence_neighbours);
    }
    else if (k == "pose_px") s = Get(*it, "pose_check.pose_px", &o->pose_check.pose_px);
    else if (k == "estimator") s = Get(*it, "pose_check.estimator", &o->pose_check.estimator);
    else if (k == "min_chance_ratio") s = Get(*it, "pose_check.min_chance_ratio", &o->pose_check.min_chance_ratio);
    else if (k == "min_explained_fraction") {
      s = Get(*it, "pose_check.min_explained_fraction", &o->pose_check.min_explained_fraction);
    }
    else return absl::InvalidArgumentError(absl::StrCat("unknown config key 'pose_check.", k, "'"));
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status ApplyRegistration(const nlohmann::json& g, RegistrationOptions* o) {
  if (!g.is_object()) return absl::InvalidArgumentError("config key 'registration' must be an object");
  for (auto it = g.begin(); it != g.end(); ++it) {
    const std::string& k = it.key();
    absl::Status s;
    if (k == "max_references") s = Get(*it, "registration.max_references", &o->max_references);
    else if (k == "max_frames") s = Get(*it, "registration.max_frames", &o->max_frames);
    else if (k == "max_side") s = Get(*it, "registration.max_side", &o->localizer.max_side);
    else if (k == "min_side") s = Get(*it, "registration.min_side", &o->localizer.min_side);
    else if (k == "identity_chi_square") s = Get(*it, "registration.identity_chi_square", &o->identity_chi_square);
    else if (k == "min_inliers") s = Get(*it, "registration.min_inliers", &o->localizer.min_inliers);
    else if (k == "weak_min_inliers") s = Get(*it, "registration.weak_min_inliers", &o->localizer.weak_min_inliers);
    else if (k == "min_frames") s = Get(*it, "registration.min_frames", &o->min_frames);
    else if (k == "photometric") s = Get(*it, "registration.photometric", &o->photometric);
    else if (k == "camera_min_rms_gain") s = Get(*it, "registration.camera_min_rms_gain", &o->camera.min_rms_gain);
    else if (k == "camera_max_change") {
      s = Get(*it, "registration.camera_max_change", &o->camera.max_focal_change);
      o->camera.max_k1_change = o->camera.max_focal_change;
    }
    else if (k == "photometric_similarity") {
      s = Get(*it, "registration.photometric_similarity", &o->photometric_similarity);
    }
    else if (k == "arbitrate") s = Get(*it, "registration.arbitrate", &o->arbitrate);
    else return absl::InvalidArgumentError(absl::StrCat("unknown config key 'registration.", k, "'"));
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ApplyConfigJson(const std::string& json_text, ServerOptions* o) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(json_text);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("config is not valid JSON: ", e.what()));
  }
  if (!j.is_object()) return absl::InvalidArgumentError("config must be a JSON object");
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& k = it.key();
    absl::Status s;
    std::string str;
    if (k == "listen") s = Get(*it, "listen", &o->listen);
    else if (k == "http") s = Get(*it, "http", &o->http_listen);
    else if (k == "http_allowed_hosts") s = Get(*it, "http_allowed_hosts", &o->http_allowed_hosts);
    else if (k == "http_max_head_bytes") s = Get(*it, "http_max_head_bytes", &o->http_max_head_bytes);
    else if (k == "http_head_timeout_seconds") s = Get(*it, "http_head_timeout_seconds", &o->http_head_timeout_seconds);
    else if (k == "store") s = Get(*it, "store", &o->store_dir);
    else if (k == "token") s = Get(*it, "token", &o->token);
    else if (k == "tls_cert") s = Get(*it, "tls_cert", &o->tls_cert);
    else if (k == "tls_key") s = Get(*it, "tls_key", &o->tls_key);
    else if (k == "max_queue") s = Get(*it, "max_queue", &o->max_queue);
    else if (k == "render_concurrency") s = Get(*it, "render_concurrency", &o->render_concurrency);
    else if (k == "render_threads") s = Get(*it, "render_threads", &o->render_threads);
    else if (k == "small_render_pixels") s = Get(*it, "small_render_pixels", &o->small_render_pixels);
    else if (k == "render_wait_seconds") s = Get(*it, "render_wait_seconds", &o->render_wait_seconds);
    else if (k == "train_threads") s = Get(*it, "train_threads", &o->train_threads);
    else if (k == "train_nice") s = Get(*it, "train_nice", &o->train_nice);
    else if (k == "max_concurrent_trainings") s = Get(*it, "max_concurrent_trainings", &o->max_concurrent_trainings);
    else if (k == "grpc_threads") s = Get(*it, "grpc_threads", &o->grpc_threads);
    else if (k == "max_message_bytes") s = Get(*it, "max_message_bytes", &o->max_message_bytes);
    else if (k == "max_scan_bytes") s = Get(*it, "max_scan_bytes", &o->max_scan_bytes);
    else if (k == "max_frames") s = Get(*it, "max_frames", &o->max_frames);
    else if (k == "max_render_pixels") s = Get(*it, "max_render_pixels", &o->max_render_pixels);
    else if (k == "render_pixel_budget") s = Get(*it, "render_pixel_budget", &o->render_pixel_budget);
    else if (k == "max_scan_attempts") s = Get(*it, "max_scan_attempts", &o->max_scan_attempts);
    else if (k == "store_retry_seconds") s = Get(*it, "store_retry_seconds", &o->store_retry_seconds);
    else if (k == "etcd") s = Get(*it, "etcd", &o->etcd);
    else if (k == "etcd_prefix") s = Get(*it, "etcd_prefix", &o->etcd_prefix);
    else if (k == "lease_ttl_seconds") s = Get(*it, "lease_ttl_seconds", &o->lease_ttl_seconds);
    else if (k == "replica_poll_seconds") s = Get(*it, "replica_poll_seconds", &o->replica_poll_seconds);
    else if (k == "model_memory_budget") s = Get(*it, "model_memory_budget", &o->model_memory_budget);
    else if (k == "asset_memory_budget") s = Get(*it, "asset_memory_budget", &o->asset_memory_budget);
    else if (k == "keep_versions") s = Get(*it, "keep_versions", &o->keep_versions);
    else if (k == "shutdown_grace_seconds") s = Get(*it, "shutdown_grace_seconds", &o->shutdown_grace_seconds);
    else if (k == "iterations_per_update") s = Get(*it, k.c_str(), &o->update.train.iterations);
    else if (k == "first_scan_iterations") s = Get(*it, k.c_str(), &o->first_scan_iterations);
    else if (k == "buffer_size") s = Get(*it, k.c_str(), &o->update.buffer_size);
    else if (k == "seed") s = Get(*it, k.c_str(), &o->update.train.seed);
    else if (k == "learning_rate") s = Get(*it, k.c_str(), &o->update.train.learning_rate);
    else if (k == "batch_rays") s = Get(*it, k.c_str(), &o->update.train.batch_rays);  // First batch's rays.
    else if (k == "target_samples") s = Get(*it, k.c_str(), &o->update.train.target_samples);  // 0 = fixed batch.
    else if (k == "depth_fraction") s = Get(*it, k.c_str(), &o->update.depth_fraction);  // Sparse depth; 0 = off.
    else if (k == "view_colour") s = Get(*it, k.c_str(), &o->update.train.view_colour);  // Per-photo colour transforms.
    else if (k == "replay_labels_per_draw") s = Get(*it, k.c_str(), &o->update.replay_labels.labels_per_draw);
    else if (k == "carry_optimizer") s = Get(*it, k.c_str(), &o->update.carry_optimizer);
    else if (k == "refine_cameras") s = Get(*it, k.c_str(), &o->update.refine_cameras);  // Pose corrections while training.
    else if (k == "camera_learning_rate") s = Get(*it, k.c_str(), &o->update.camera_refine.learning_rate);
    else if (k == "warm_lr_scale") s = Get(*it, k.c_str(), &o->update.warm_lr_scale);  // Warm updates' learning-rate factor.
    else if (k == "error_share") s = Get(*it, k.c_str(), &o->update.view_error.error_share);  // 0 = uniform.
    else if (k == "error_tiles") s = Get(*it, k.c_str(), &o->update.view_error.tiles);
    else if (k == "replay_seen_weight") s = Get(*it, k.c_str(), &o->update.replay_weights.seen_weight);
    else if (k == "replay_depth_min_opacity") s = Get(*it, k.c_str(), &o->update.replay_labels.depth_min_opacity);
    else if (k == "lr_schedule") {
      s = Get(*it, k.c_str(), &str);
      if (s.ok()) {
        auto m = ParseLrSchedule(str);
        if (!m.ok()) return m.status();
        o->update.train.lr_schedule = *m;
      }
    }
    else if (k == "method") {
      s = Get(*it, k.c_str(), &str);
      if (s.ok()) {
        auto m = ParseContinualMethod(str);
        if (!m.ok()) return m.status();
        o->update.method = *m;
      }
    } else if (k == "init") {
      s = Get(*it, k.c_str(), &str);
      if (s.ok()) {
        auto m = ParseInitMode(str);
        if (!m.ok()) return m.status();
        o->update.init = *m;
      }
    } else if (k == "replay") {
      s = Get(*it, k.c_str(), &str);
      if (s.ok()) {
        auto m = ParseReplayMode(str);
        if (!m.ok()) return m.status();
        o->update.replay = *m;
      }
    } else if (k == "sampler") {  // auto | occupancy | proposal (core/field/ngp_model.h).
      s = Get(*it, k.c_str(), &str);
      if (s.ok()) s = ParseSamplerKind(str, &o->update.model.sampler);
    } else if (k == "gate") {
      s = ApplyGate(*it, &o->gate);
    } else if (k == "registration") {
      s = ApplyRegistration(*it, &o->registration);
    } else if (k == "posing") {
      s = ApplyPosing(*it, o);
    } else if (k == "pose_check") {
      s = ApplyPoseCheck(*it, o);
    } else if (k == "bake") {
      s = ApplyBake(*it, o);
    } else {
      return absl::InvalidArgumentError(absl::StrCat("unknown config key '", k, "'"));
    }
    if (!s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status ApplyConfigFile(const std::string& path, ServerOptions* options) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read config file '", path, "'"));
  std::stringstream ss;
  ss << in.rdbuf();
  absl::Status s = ApplyConfigJson(ss.str(), options);
  if (!s.ok()) return absl::Status(s.code(), absl::StrCat(path, ": ", s.message()));
  return absl::OkStatus();
}

}  // namespace clnerf
