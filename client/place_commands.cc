// The remote `places` verb: list, create and delete the server's places.
//
//   clnerf places                    (or `places list`) every place
//   clnerf places create NAME        an empty place
//   clnerf places delete NAME --yes  a place and all its files
#include <cstdio>

#include "absl/strings/str_cat.h"
#include "client/proto_json.h"
#include "client/remote_client.h"
#include "client/remote_commands.h"
#include "client/remote_format.h"
#include "client/text_table.h"
#include "client/verb_set.h"

namespace clnerf {

CLI::App* BindPlaces(CLI::App* parent, PlacesArgs* a) {
  CLI::App* c = parent->add_subcommand(
      "places", "List the server's places, or create / delete one: places [list | create NAME | delete NAME --yes]");
  c->add_option("action", a->action, "list, create or delete")
      ->check(CLI::IsMember({"list", "create", "delete"}))
      ->capture_default_str();
  c->add_option("name", a->name, "The place to create or delete");
  c->add_flag("--yes", a->yes, "delete: confirm that the place and every file of it go");
  BindRemoteFlags(c, &a->remote);
  return c;
}

namespace {

nlohmann::json PlaceJson(const clnerf::v1::Place& p) {
  nlohmann::json j = ProtoToJson(p);
  // Proto3 JSON leaves out zero and empty fields; these are always there.
  j["name"] = p.name();
  j["deployed_version"] = p.deployed_version();
  j["time_steps"] = p.time_steps();
  j["queued_jobs"] = p.queued_jobs();
  j["loaded"] = p.loaded();
  j["model_bytes"] = p.model_bytes();
  j["memory_bytes"] = p.memory_bytes();
  return j;
}

int ListPlaces(RemoteClient& client, const PlacesArgs& a) {
  clnerf::v1::ListPlacesResponse response;
  grpc::Status s = client.service().ListPlaces(client.Context(kUnaryTimeoutSeconds).get(),
                                               clnerf::v1::ListPlacesRequest(), &response);
  if (!s.ok()) return FailRemote("places", s, a.remote);
  if (a.remote.json) {
    nlohmann::json list = nlohmann::json::array();
    for (const clnerf::v1::Place& p : response.places()) list.push_back(PlaceJson(p));
    std::printf("%s\n", list.dump(2).c_str());
    return 0;
  }
  TextTable table({"PLACE", "DEPLOYED", "TIME STEPS", "QUEUED", "TRAINING", "LOADED", "MODEL", "MEMORY", "STORE"});
  for (const clnerf::v1::Place& p : response.places()) {
    table.AddRow({p.name(), p.deployed_version() > 0 ? absl::StrCat("v", p.deployed_version()) : "-",
                  absl::StrCat(p.time_steps()), absl::StrCat(p.queued_jobs()),
                  p.running_job().empty() ? "-" : p.running_job(), p.loaded() ? "yes" : "no",
                  p.model_bytes() > 0 ? FormatBytes(p.model_bytes()) : "-",
                  p.memory_bytes() > 0 ? FormatBytes(p.memory_bytes()) : "-",
                  p.store_error().empty() ? "ok" : "READ-ONLY: " + p.store_error()});
  }
  table.Print();
  return 0;
}

}  // namespace

int RunPlaces(const PlacesArgs& a) {
  if (a.action != "list" && a.name.empty()) {
    return FailRemote("places", absl::InvalidArgumentError(absl::StrCat("places ", a.action, " needs a NAME")));
  }
  if (a.action == "delete" && !a.yes) {
    return FailRemote("places", absl::FailedPreconditionError(absl::StrCat(
                                    "deleting place '", a.name,
                                    "' removes its scans, versions and models for good; add --yes to confirm")));
  }
  absl::StatusOr<std::unique_ptr<RemoteClient>> client = RemoteClient::Create(a.remote);
  if (!client.ok()) return FailRemote("places", client.status());
  if (a.action == "list") return ListPlaces(**client, a);
  if (a.action == "create") {
    clnerf::v1::CreatePlaceRequest request;
    request.set_name(a.name);
    clnerf::v1::Place place;
    grpc::Status s =
        (*client)->service().CreatePlace((*client)->Context(kUnaryTimeoutSeconds).get(), request, &place);
    if (!s.ok()) return FailRemote("places create", s, a.remote);
    if (a.remote.json) {
      std::printf("%s\n", PlaceJson(place).dump(2).c_str());
    } else {
      std::printf("created place '%s' (upload to it with --place %s)\n", place.name().c_str(), place.name().c_str());
    }
    return 0;
  }
  clnerf::v1::DeletePlaceRequest request;
  request.set_name(a.name);
  clnerf::v1::DeletePlaceResponse deleted;
  grpc::Status s =
      (*client)->service().DeletePlace((*client)->Context(kUnaryTimeoutSeconds).get(), request, &deleted);
  if (!s.ok()) return FailRemote("places delete", s, a.remote);
  if (a.remote.json) {
    std::printf("%s\n", ProtoToJson(deleted).dump(2).c_str());
  } else {
    std::printf("deleted place '%s'\n", deleted.name().c_str());
  }
  return 0;
}

}  // namespace clnerf
