// Places end to end through gRPC (in-process server on localhost:0): create,
// upload and render per place, list, delete durably, restart; and bad place
// names or unknown places get a clear status and leave the store unchanged.
#include "server/places/places.h"

#include <filesystem>
#include <set>
#include <string>
#include <thread>

#include "server/testing/server_fixture.h"

namespace clnerf {
namespace {

namespace fs = std::filesystem;
using testing_util::ServerFixture;
using testing_util::TempDir;
using testing_util::TinyScans;
using testing_util::TinyServerOptions;
using testing_util::UploadMessages;
using testing_util::UploadOf;

// Every path under `dir` with its size (a snapshot to compare).
std::set<std::string> Snapshot(const std::string& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    out.insert(e.path().string() + (e.is_regular_file() ? ":" + std::to_string(e.file_size()) : "/"));
  }
  return out;
}

class PlacesTest : public ServerFixture {
 protected:
  grpc::Status CreatePlace(const std::string& name, v1::Place* out = nullptr) {
    grpc::ClientContext ctx;
    v1::CreatePlaceRequest req;
    req.set_name(name);
    v1::Place p;
    grpc::Status s = stub_->CreatePlace(&ctx, req, &p);
    if (out != nullptr) *out = p;
    return s;
  }
  grpc::Status DeletePlace(const std::string& name) {
    grpc::ClientContext ctx;
    v1::DeletePlaceRequest req;
    req.set_name(name);
    v1::DeletePlaceResponse r;
    return stub_->DeletePlace(&ctx, req, &r);
  }
  std::vector<v1::Place> ListPlaces() {
    grpc::ClientContext ctx;
    v1::ListPlacesResponse r;
    EXPECT_TRUE(stub_->ListPlaces(&ctx, v1::ListPlacesRequest(), &r).ok());
    return {r.places().begin(), r.places().end()};
  }
  // Uploads step t of `scene` to `place` and waits for its job.
  v1::Job UploadTo(const std::string& place, const Scene& scene, int t, grpc::Status* status = nullptr) {
    std::vector<v1::UploadScanRequest> msgs = UploadMessages(UploadOf(scene, t));
    msgs[0].mutable_header()->set_place(place);
    v1::UploadScanResponse ack;
    grpc::Status s = Upload(msgs, &ack);
    if (status != nullptr) *status = s;
    if (!s.ok()) return v1::Job();
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(600));
    v1::WatchJobRequest req;
    req.set_job_id(ack.job_id());
    req.set_place(place);
    auto reader = stub_->WatchJob(&ctx, req);
    v1::Job job, last;
    while (reader->Read(&job)) last = job;
    EXPECT_TRUE(reader->Finish().ok());
    return last;
  }
  grpc::Status RenderAt(const std::string& place, const Camera& cam, v1::RenderResponse* resp) {
    grpc::ClientContext ctx;
    v1::RenderRequest req;
    testing_util::FillCamera(cam, req.mutable_camera());
    req.set_place(place);
    return stub_->Render(&ctx, req, resp);
  }
};

TEST_F(PlacesTest, EachPlaceHasItsOwnScansVersionsAndModel) {
  const std::string store = TempDir("srv_places");
  StartServer(TinyServerOptions(store));
  ASSERT_EQ(ListPlaces().size(), 1u);
  EXPECT_EQ(ListPlaces()[0].name(), "default");
  v1::Place created;
  ASSERT_TRUE(CreatePlace("shop-a", &created).ok());
  EXPECT_EQ(created.name(), "shop-a");
  EXPECT_EQ(created.deployed_version(), 0);
  EXPECT_EQ(CreatePlace("shop-a").error_code(), grpc::StatusCode::ALREADY_EXISTS);

  const Scene scene = TinyScans(2);
  const v1::Job a0 = UploadTo("shop-a", scene, 0);
  ASSERT_EQ(a0.phase(), v1::JOB_PHASE_DONE) << a0.error();
  EXPECT_EQ(a0.version(), 1);
  // The default place is untouched: nothing to render there yet.
  v1::RenderResponse r;
  EXPECT_EQ(RenderAt("", scene.test[0].camera, &r).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  ASSERT_TRUE(RenderAt("shop-a", scene.test[0].camera, &r).ok());
  EXPECT_EQ(r.version(), 1);
  // An upload without a place goes to "default", with its own version 1.
  const v1::Job d0 = UploadTo("", scene, 0);
  ASSERT_EQ(d0.phase(), v1::JOB_PHASE_DONE) << d0.error();
  EXPECT_EQ(d0.version(), 1);
  const v1::Job a1 = UploadTo("shop-a", scene, 1);
  ASSERT_EQ(a1.phase(), v1::JOB_PHASE_DONE) << a1.error();
  EXPECT_EQ(a1.version(), 2);
  std::vector<v1::Place> places = ListPlaces();
  ASSERT_EQ(places.size(), 2u);
  EXPECT_EQ(places[0].name(), "default");
  EXPECT_EQ(places[0].deployed_version(), 1);
  EXPECT_EQ(places[1].name(), "shop-a");
  EXPECT_EQ(places[1].deployed_version(), 2);
  EXPECT_EQ(places[1].time_steps(), 2);
  EXPECT_TRUE(places[1].loaded());
  EXPECT_GT(places[1].model_bytes(), 0);
  EXPECT_TRUE(fs::exists(store + "/places/shop-a/versions"));

  // After a restart both places come back with their versions.
  StopServer();
  StartServer(TinyServerOptions(store));
  places = ListPlaces();
  ASSERT_EQ(places.size(), 2u);
  EXPECT_EQ(places[1].deployed_version(), 2);
  ASSERT_TRUE(RenderAt("shop-a", scene.test[0].camera, &r).ok());
  EXPECT_EQ(r.version(), 2);

  // Deleting removes the place and its files for good; "default" cannot go.
  EXPECT_EQ(DeletePlace("default").error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  ASSERT_TRUE(DeletePlace("shop-a").ok());
  EXPECT_FALSE(fs::exists(store + "/places/shop-a"));
  EXPECT_EQ(RenderAt("shop-a", scene.test[0].camera, &r).error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(DeletePlace("shop-a").error_code(), grpc::StatusCode::NOT_FOUND);
  StopServer();
  StartServer(TinyServerOptions(store));
  ASSERT_EQ(ListPlaces().size(), 1u);
  ASSERT_TRUE(RenderAt("", scene.test[0].camera, &r).ok());  // default kept its version.
}

TEST_F(PlacesTest, BadOrUnknownPlacesGetAClearStatusAndChangeNothing) {
  const std::string store = TempDir("srv_places_bad");
  StartServer(TinyServerOptions(store));
  ASSERT_TRUE(CreatePlace("flat-1").ok());
  const std::set<std::string> before = Snapshot(store);
  const Scene scene = TinyScans(1);
  grpc::Status s;
  UploadTo("nowhere", scene, 0, &s);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(s.error_message().find("places: default, flat-1"), std::string::npos) << s.error_message();
  UploadTo("../flat-1", scene, 0, &s);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << s.error_message();
  EXPECT_EQ(CreatePlace("../../etc").error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(CreatePlace(".hidden").error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(DeletePlace("../flat-1").error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // Names that differ only by case collide on case-insensitive volumes.
  for (const char* twin : {"Default", "FLAT-1"}) {
    grpc::Status cs = CreatePlace(twin);
    EXPECT_EQ(cs.error_code(), grpc::StatusCode::ALREADY_EXISTS) << twin;
    EXPECT_NE(cs.error_message().find("only by case"), std::string::npos) << cs.error_message();
  }
  // A non-ASCII name: refused, with a message that is valid UTF-8 (gRPC
  // sends it as a header) naming the whole character.
  grpc::Status cafe = CreatePlace("caf\xc3\xa9");
  EXPECT_EQ(cafe.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(cafe.error_message().find("'\xc3\xa9' at byte 3"), std::string::npos) << cafe.error_message();
  // A 3 MB name (under gRPC's 4 MiB message limit, so it reaches the server).
  const std::string huge(3 << 20, 'x');
  grpc::Status hs = CreatePlace(huge);
  EXPECT_EQ(hs.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_LT(hs.error_message().size(), 200u);
  v1::RenderResponse r;
  EXPECT_EQ(RenderAt(huge, scene.test[0].camera, &r).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // A 10 MB name is refused by gRPC's own message limit.
  EXPECT_FALSE(CreatePlace(std::string(10 << 20, 'y')).ok());
  grpc::ClientContext ctx;
  v1::ListVersionsRequest lv;
  lv.set_place("nowhere");
  v1::ListVersionsResponse lr;
  EXPECT_EQ(stub_->ListVersions(&ctx, lv, &lr).error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(Snapshot(store), before);
}

// Places share max_concurrent_trainings (1): uploads to two places train
// one after the other, never at once, and both finish.
TEST_F(PlacesTest, PlacesTakeTurnsForTheTrainingSlot) {
  ServerOptions o = TinyServerOptions(TempDir("srv_places_turns"));
  o.max_concurrent_trainings = 1;
  StartServer(o);
  ASSERT_TRUE(CreatePlace("a").ok());
  ASSERT_TRUE(CreatePlace("b").ok());
  const Scene scene = TinyScans(1);
  std::vector<std::string> jobs;
  for (const char* place : {"a", "b"}) {
    std::vector<v1::UploadScanRequest> msgs = UploadMessages(UploadOf(scene, 0));
    msgs[0].mutable_header()->set_place(place);
    v1::UploadScanResponse ack;
    ASSERT_TRUE(Upload(msgs, &ack).ok());
    jobs.push_back(ack.job_id());
  }
  int both = 0, one = 0, waited = 0;
  for (int i = 0; i < 3000; ++i) {
    const std::vector<v1::Place> places = ListPlaces();
    int training = 0, queued = 0, deployed = 0;
    for (const v1::Place& p : places) {
      training += !p.running_job().empty();
      queued += p.queued_jobs();
      deployed += p.deployed_version() > 0;
    }
    both += training > 1;
    one += training == 1;
    waited += training == 1 && queued == 1;  // The other place's scan waits, queued.
    if (deployed == 2) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(both, 0);
  EXPECT_GT(one, 0);
  EXPECT_GT(waited, 0);
  for (const v1::Place& p : ListPlaces()) {
    if (p.name() != "default") {
      EXPECT_EQ(p.deployed_version(), 1) << p.name();
    }
  }
}

// A request that holds a place's host while the place is deleted (a render
// or upload racing DeletePlace) gets NOT_FOUND, not the UNAVAILABLE of a
// server that is stopping (on which clients retry).
TEST_F(PlacesTest, ARequestIntoADeletedPlaceIsNotFoundNotUnavailable) {
  const Scene scene = TinyScans(1);
  for (const bool deleted : {true, false}) {
    absl::StatusOr<std::unique_ptr<ModelHost>> host =
        ModelHost::Open(TinyServerOptions(TempDir("srv_places_gone")), {}, "shop");
    ASSERT_TRUE(host.ok()) << host.status();
    if (deleted) (*host)->MarkDeleted();
    (*host)->Shutdown();
    const absl::Status s = (*host)->AcceptScan(UploadOf(scene, 0)).status();
    if (deleted) {
      EXPECT_TRUE(absl::IsNotFound(s)) << s;
      EXPECT_NE(s.message().find("place 'shop' was deleted"), std::string::npos) << s;
    } else {
      EXPECT_TRUE(absl::IsUnavailable(s)) << s;
    }
    EXPECT_EQ((*host)->StoppedStatus().code(), s.code());
  }
}

// A place deleted while its update trains: the job says so, not that the
// server shut down (the reason is read when the job stops, not when it
// started).
TEST_F(PlacesTest, AJobStoppedByItsPlacesDeletionSaysSo) {
  const Scene scene = TinyScans(1);
  absl::StatusOr<std::unique_ptr<ModelHost>> host =
      ModelHost::Open(TinyServerOptions(TempDir("srv_places_deleted_job"), 100000), {}, "shop");
  ASSERT_TRUE(host.ok()) << host.status();
  absl::StatusOr<UploadAck> ack = (*host)->AcceptScan(UploadOf(scene, 0));
  ASSERT_TRUE(ack.ok()) << ack.status();
  bool training = false;
  for (int i = 0; i < 1200 && !training; ++i) {
    absl::StatusOr<JobStatus> j = (*host)->GetJob(ack->job_id);
    ASSERT_TRUE(j.ok()) << j.status();
    training = j->phase == JobPhase::kTraining && j->iteration > 0;
    if (!training) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_TRUE(training);
  (*host)->MarkDeleted();
  (*host)->Shutdown();
  absl::StatusOr<JobStatus> j = (*host)->GetJob(ack->job_id);
  ASSERT_TRUE(j.ok()) << j.status();
  EXPECT_EQ(j->phase, JobPhase::kCancelled);
  EXPECT_NE(j->error.find("the place was deleted"), std::string::npos) << j->error;
}

// A store the single-place server wrote (its files at the root) opens as the
// place "default", as it is.
TEST_F(PlacesTest, AStoreFromBeforePlacesOpensAsDefault) {
  const std::string store = TempDir("srv_places_legacy");
  {
    ServerOptions o = TinyServerOptions(store);
    absl::StatusOr<std::unique_ptr<ModelHost>> host = ModelHost::Open(o);  // The single-place server's core.
    ASSERT_TRUE(host.ok()) << host.status();
    const Scene scene = TinyScans(1);
    absl::StatusOr<UploadAck> ack = (*host)->AcceptScan(UploadOf(scene, 0));
    ASSERT_TRUE(ack.ok()) << ack.status();
    for (int i = 0; i < 600 && (*host)->deployed_version() == 0; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    ASSERT_EQ((*host)->deployed_version(), 1);
    (*host)->Shutdown();
  }
  StartServer(TinyServerOptions(store));
  std::vector<v1::Place> places = ListPlaces();
  ASSERT_EQ(places.size(), 1u);
  EXPECT_EQ(places[0].name(), "default");
  EXPECT_EQ(places[0].deployed_version(), 1);
}

// Six places under a memory budget for two models: at start-up only what fits
// stays loaded, every render succeeds (evicted models reload on use), the
// resident bytes stay within the budget between requests, and the evictions
// are counted in the cache and in /metrics' counter.
TEST_F(PlacesTest, SixPlacesUnderABudgetForTwoAllRenderAndEvictionsAreCounted) {
  const std::string store = TempDir("srv_places_budget");
  const Scene scene = TinyScans(1);
  StartServer(TinyServerOptions(store));
  const std::vector<std::string> names = {"p0", "p1", "p2", "p3", "p4", "p5"};
  for (const std::string& n : names) {
    ASSERT_TRUE(CreatePlace(n).ok());
    const v1::Job j = UploadTo(n, scene, 0);
    ASSERT_EQ(j.phase(), v1::JOB_PHASE_DONE) << j.error();
  }
  int64_t one = 0;  // The bytes one loaded model holds.
  {
    auto h = server_->places().Get("p0");
    ASSERT_TRUE(h.ok());
    auto s = (*h)->publisher_for_testing().registry().Get(0);
    ASSERT_TRUE(s.ok());
    one = ServableBytes(**s);
  }
  StopServer();

  ServerOptions o = TinyServerOptions(store);
  o.model_memory_budget = one * 5 / 2;  // Two fit, three do not.
  StartServer(o);
  // The warm-up after start-up loads each model and keeps those that fit.
  int loaded = 0;
  for (int i = 0; i < 200 && loaded < 2; ++i) {
    loaded = 0;
    for (const v1::Place& p : ListPlaces()) loaded += p.loaded() ? 1 : 0;
    if (loaded < 2) std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  EXPECT_EQ(loaded, 2) << "at start-up the checked models stay loaded only while they fit";
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // Let the warm-up finish the other four.
  loaded = 0;
  for (const v1::Place& p : ListPlaces()) loaded += p.loaded() ? 1 : 0;
  EXPECT_EQ(loaded, 2);
  EXPECT_EQ(server_->places().models().stats().evictions, 0) << "the warm-up never evicts";
  for (int round = 0; round < 2; ++round) {
    for (const std::string& n : names) {
      v1::RenderResponse r;
      const grpc::Status s = RenderAt(n, scene.test[0].camera, &r);
      ASSERT_TRUE(s.ok()) << n << ": " << s.error_message();
      EXPECT_EQ(r.version(), 1);
      const ModelCacheStats st = server_->places().models().stats();
      EXPECT_LE(st.bytes, o.model_memory_budget) << "after rendering " << n;
      EXPECT_LE(st.entries, 2);
    }
  }
  const ModelCacheStats st = server_->places().models().stats();
  // Round robin over 6 places with room for 2: every render after the first
  // two loads evicts one.
  EXPECT_GE(st.evictions, 8);
  EXPECT_GE(st.loads, 10);
  const std::string text = server_->places().metrics().Text();
  const std::string line = "clnerf_model_evictions_total " + std::to_string(st.evictions);
  EXPECT_NE(text.find(line), std::string::npos) << text;
  loaded = 0;
  for (const v1::Place& p : ListPlaces()) loaded += p.loaded() ? 1 : 0;
  EXPECT_EQ(loaded, 2);
}

// Two servers over one store (replicas): a place created through one is
// opened by the other on first use and listed by both; deleted through one,
// the other drops it and answers NOT_FOUND.
TEST(PlacesSharedStoreTest, PlacesCreatedOrDeletedByAnotherServerAreSeen) {
  const std::string store = TempDir("srv_places_shared");
  auto a = Places::Open(TinyServerOptions(store));
  auto b = Places::Open(TinyServerOptions(store));
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE((*a)->Create("shop").ok());
  auto seen = (*b)->Get("shop");
  ASSERT_TRUE(seen.ok()) << seen.status();
  EXPECT_EQ((*b)->Names(), (std::vector<std::string>{"default", "shop"}));
  ASSERT_TRUE((*a)->Create("flat").ok());
  EXPECT_EQ((*b)->Names(), (std::vector<std::string>{"default", "flat", "shop"}));
  ASSERT_TRUE((*a)->Delete("shop").ok());
  EXPECT_EQ((*b)->Get("shop").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ((*b)->Names(), (std::vector<std::string>{"default", "flat"}));
  // And the other way round.
  ASSERT_TRUE((*b)->Delete("flat").ok());
  EXPECT_EQ((*a)->Names(), (std::vector<std::string>{"default"}));
}

}  // namespace
}  // namespace clnerf
