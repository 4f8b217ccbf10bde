#include "server/common/metrics.h"

#include <sstream>

#include "absl/status/status.h"
#include "prometheus/counter.h"
#include "prometheus/family.h"
#include "prometheus/gauge.h"
#include "prometheus/histogram.h"
#include "prometheus/registry.h"
#include "prometheus/text_serializer.h"

namespace clnerf {
namespace {

std::string CodeLabel(absl::StatusCode code) { return absl::StatusCodeToString(code); }

}  // namespace

Metrics::Metrics() : registry_(std::make_shared<prometheus::Registry>()) {
  using prometheus::BuildCounter;
  using prometheus::BuildGauge;
  using prometheus::BuildHistogram;
  prometheus::Registry& r = *registry_;
  renders_ = &BuildCounter().Name("clnerf_renders_total").Help("Render requests by status code").Register(r);
  uploads_ = &BuildCounter().Name("clnerf_uploads_total").Help("Scan uploads by status code").Register(r);
  updates_ = &BuildCounter().Name("clnerf_updates_total").Help("Model updates by outcome").Register(r);
  // Renders: a 32x32 preview takes milliseconds, a 2048^2 frame seconds.
  render_seconds_ = &BuildHistogram()
                         .Name("clnerf_render_seconds")
                         .Help("Latency of successful renders")
                         .Register(r)
                         .Add({}, prometheus::Histogram::BucketBoundaries{0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1,
                                                                          2.5, 5, 10, 30});
  update_seconds_ = &BuildHistogram()
                         .Name("clnerf_update_seconds")
                         .Help("Duration of model updates (upload training to outcome)")
                         .Register(r)
                         .Add({}, prometheus::Histogram::BucketBoundaries{10, 30, 60, 120, 300, 600, 1800, 3600});
  load_seconds_ = &BuildHistogram()
                       .Name("clnerf_model_load_seconds")
                       .Help("Latency of loading a model version from the store")
                       .Register(r)
                       .Add({}, prometheus::Histogram::BucketBoundaries{0.01, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5});
  upload_bytes_ = &BuildCounter().Name("clnerf_upload_bytes_total").Help("Bytes of accepted scans").Register(r).Add({});
  assets_ = &BuildCounter()
                 .Name("clnerf_asset_requests_total")
                 .Help("Baked-asset file requests (GET /api/asset) by status code")
                 .Register(r);
  asset_bytes_ = &BuildCounter().Name("clnerf_asset_bytes_total").Help("Bytes of baked-asset files sent").Register(r).Add({});
  asset_bakes_ = &BuildCounter()
                      .Name("clnerf_asset_bakes_total")
                      .Help("Time steps baked on a viewer's request")
                      .Register(r)
                      .Add({});
  asset_bake_seconds_ = &BuildCounter()
                             .Name("clnerf_asset_bake_seconds_total")
                             .Help("Seconds spent baking time steps on request")
                             .Register(r)
                             .Add({});
  asset_file_reads_ = &BuildCounter()
                           .Name("clnerf_asset_file_reads_total")
                           .Help("Baked-asset files read from disk (asset cache misses)")
                           .Register(r)
                           .Add({});
  asset_file_read_bytes_ = &BuildCounter()
                                .Name("clnerf_asset_file_read_bytes_total")
                                .Help("Bytes of baked-asset files read from disk")
                                .Register(r)
                                .Add({});
  gate_refusals_ = &BuildCounter()
                        .Name("clnerf_gate_refusals_total")
                        .Help("Updates the deployment gate refused")
                        .Register(r)
                        .Add({});
  loads_ = &BuildCounter().Name("clnerf_model_loads_total").Help("Model versions loaded").Register(r).Add({});
  load_failures_ =
      &BuildCounter().Name("clnerf_model_load_failures_total").Help("Model loads that failed").Register(r).Add({});
  evictions_ = &BuildCounter()
                    .Name("clnerf_model_evictions_total")
                    .Help("Models evicted from memory under the budget")
                    .Register(r)
                    .Add({});
  fenced_ = &BuildCounter()
                 .Name("clnerf_fenced_commits_total")
                 .Help("Publishes refused because the replica no longer held the place's lease")
                 .Register(r)
                 .Add({});
  lease_changes_ =
      &BuildCounter().Name("clnerf_lease_changes_total").Help("Training leases taken or lost").Register(r).Add({});
  model_bytes_ =
      &BuildGauge().Name("clnerf_model_bytes").Help("Bytes of the model versions held in memory").Register(r).Add({});
}

Metrics::~Metrics() = default;

void Metrics::RenderDone(absl::StatusCode code, double seconds) {
  renders_->Add({{"code", CodeLabel(code)}}).Increment();
  if (code == absl::StatusCode::kOk) render_seconds_->Observe(seconds);
}

void Metrics::UploadDone(absl::StatusCode code, int64_t bytes) {
  uploads_->Add({{"code", CodeLabel(code)}}).Increment();
  if (code == absl::StatusCode::kOk && bytes > 0) upload_bytes_->Increment(double(bytes));
}

void Metrics::AssetServed(absl::StatusCode code, int64_t bytes) {
  assets_->Add({{"code", CodeLabel(code)}}).Increment();
  if (bytes > 0) asset_bytes_->Increment(double(bytes));
}

void Metrics::AssetBaked(double seconds) {
  asset_bakes_->Increment();
  asset_bake_seconds_->Increment(seconds);
}

void Metrics::AssetFileRead(int64_t bytes) {
  asset_file_reads_->Increment();
  asset_file_read_bytes_->Increment(double(bytes));
}

void Metrics::UpdateDone(const std::string& outcome, double seconds) {
  updates_->Add({{"outcome", outcome}}).Increment();
  update_seconds_->Observe(seconds);
  if (outcome == "refused") gate_refusals_->Increment();
}

void Metrics::ModelLoaded(double seconds) {
  loads_->Increment();
  load_seconds_->Observe(seconds);
}
void Metrics::ModelLoadFailed() { load_failures_->Increment(); }
void Metrics::ModelEvicted() { evictions_->Increment(); }
void Metrics::SetModelBytes(int64_t bytes) { model_bytes_->Set(double(bytes)); }
void Metrics::FencedCommit() { fenced_->Increment(); }
void Metrics::LeaseChanged() { lease_changes_->Increment(); }

std::string Metrics::Text() const {
  std::ostringstream out;
  prometheus::TextSerializer().Serialize(out, registry_->Collect());
  return out.str();
}

}  // namespace clnerf
