// ClnerfServiceImpl: the clnerf.v1.ClnerfService RPCs, each a thin shell that
// checks auth, converts the request (proto_convert), looks up the request's
// place (places.h; "" = default), calls that place's ModelHost and converts
// the answer. No model logic lives here.
//
// Auth: when a token is configured, mutating calls (UploadScan, CancelJob,
// SetDeployedVersion, CreatePlace, DeletePlace) need "authorization: Bearer <token>" metadata, else
// UNAUTHENTICATED. Read-only calls are open.
//
// Thread-safety: gRPC calls the handlers from its thread pool concurrently;
// the implementation keeps no mutable state of its own.
#ifndef CLNERF_SERVER_GRPC_SERVICE_H_
#define CLNERF_SERVER_GRPC_SERVICE_H_

#include <string>

#include "clnerf/v1/clnerf.grpc.pb.h"
#include "server/places/model_host.h"
#include "server/places/places.h"

namespace clnerf {

class ClnerfServiceImpl final : public v1::ClnerfService::Service {
 public:
  ClnerfServiceImpl(Places* places, std::string token) : places_(places), token_(std::move(token)) {}

  grpc::Status UploadScan(grpc::ServerContext* ctx, grpc::ServerReader<v1::UploadScanRequest>* reader,
                          v1::UploadScanResponse* response) override;
  grpc::Status GetJob(grpc::ServerContext* ctx, const v1::GetJobRequest* req, v1::Job* resp) override;
  grpc::Status ListJobs(grpc::ServerContext* ctx, const v1::ListJobsRequest* req, v1::ListJobsResponse* resp) override;
  grpc::Status WatchJob(grpc::ServerContext* ctx, const v1::WatchJobRequest* req,
                        grpc::ServerWriter<v1::Job>* writer) override;
  grpc::Status CancelJob(grpc::ServerContext* ctx, const v1::CancelJobRequest* req, v1::Job* resp) override;
  grpc::Status Render(grpc::ServerContext* ctx, const v1::RenderRequest* req, v1::RenderResponse* resp) override;
  grpc::Status RenderStream(grpc::ServerContext* ctx, const v1::RenderStreamRequest* req,
                            grpc::ServerWriter<v1::RenderChunk>* writer) override;
  grpc::Status ListVersions(grpc::ServerContext* ctx, const v1::ListVersionsRequest* req,
                            v1::ListVersionsResponse* resp) override;
  grpc::Status GetVersion(grpc::ServerContext* ctx, const v1::GetVersionRequest* req, v1::Version* resp) override;
  grpc::Status SetDeployedVersion(grpc::ServerContext* ctx, const v1::SetDeployedVersionRequest* req,
                                  v1::Version* resp) override;
  grpc::Status ListCameras(grpc::ServerContext* ctx, const v1::ListCamerasRequest* req,
                           v1::ListCamerasResponse* resp) override;
  grpc::Status Localize(grpc::ServerContext* ctx, const v1::LocalizeRequest* req, v1::LocalizeResponse* resp) override;
  grpc::Status GetServerInfo(grpc::ServerContext* ctx, const v1::GetServerInfoRequest* req,
                             v1::ServerInfo* resp) override;
  grpc::Status ListPlaces(grpc::ServerContext* ctx, const v1::ListPlacesRequest* req,
                          v1::ListPlacesResponse* resp) override;
  grpc::Status CreatePlace(grpc::ServerContext* ctx, const v1::CreatePlaceRequest* req, v1::Place* resp) override;
  grpc::Status DeletePlace(grpc::ServerContext* ctx, const v1::DeletePlaceRequest* req,
                           v1::DeletePlaceResponse* resp) override;

 private:
  grpc::Status CheckAuth(const grpc::ServerContext* ctx) const;
  Places* const places_;
  const std::string token_;
};

}  // namespace clnerf

#endif  // CLNERF_SERVER_GRPC_SERVICE_H_
