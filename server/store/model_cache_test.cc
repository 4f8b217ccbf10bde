#include "server/store/model_cache.h"

#include <atomic>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

using Cache = ModelCache<std::string>;

Cache MakeCache(int64_t budget) {
  return Cache(budget, [](const std::string& v) { return int64_t(v.size()); });
}

Cache::Loader Value(const std::string& v, std::atomic<int>* calls = nullptr) {
  return [v, calls]() -> absl::StatusOr<std::shared_ptr<const std::string>> {
    if (calls != nullptr) ++*calls;
    return std::make_shared<const std::string>(v);
  };
}

TEST(ModelCacheTest, EvictsTheLeastRecentlyUsedUnderTheBudget) {
  Cache cache = MakeCache(250);
  const std::string hundred(100, 'x');
  ASSERT_TRUE(cache.GetOrLoad("a@1", Value(hundred)).ok());
  ASSERT_TRUE(cache.GetOrLoad("b@1", Value(hundred)).ok());
  ASSERT_TRUE(cache.GetOrLoad("a@1", Value("unused")).ok());  // A hit: a is now the most recent.
  ASSERT_TRUE(cache.GetOrLoad("c@1", Value(hundred)).ok());   // 300 > 250: b goes.
  EXPECT_EQ(cache.Keys(), (std::vector<std::string>{"c@1", "a@1"}));
  const ModelCacheStats s = cache.stats();
  EXPECT_EQ(s.loads, 3);
  EXPECT_EQ(s.hits, 1);
  EXPECT_EQ(s.evictions, 1);
  EXPECT_EQ(s.bytes, 200);
  EXPECT_EQ(s.entries, 2);
  EXPECT_EQ(cache.Peek("b@1"), nullptr);
  // Six places, room for two: every get succeeds, and the bytes stay within
  // the budget once nobody holds the evicted ones.
  for (int round = 0; round < 3; ++round) {
    for (int p = 0; p < 6; ++p) {
      auto v = cache.GetOrLoad(absl::StrCat("p", p, "@1"), Value(hundred));
      ASSERT_TRUE(v.ok());
      EXPECT_EQ(**v, hundred);
    }
    EXPECT_LE(cache.stats().bytes, 250);
  }
  EXPECT_GE(cache.stats().evictions, 1 + 16);
}

TEST(ModelCacheTest, NeverEvictsAValueARenderStillHolds) {
  Cache cache = MakeCache(150);
  const std::string hundred(100, 'x');
  absl::StatusOr<std::shared_ptr<const std::string>> held = cache.GetOrLoad("a@1", Value(hundred));
  ASSERT_TRUE(held.ok());
  ASSERT_TRUE(cache.GetOrLoad("b@1", Value(hundred)).ok());  // 200 > 150, but a is in use: b stays too.
  EXPECT_EQ(cache.stats().evictions, 0);
  EXPECT_EQ(cache.stats().bytes, 200);
  EXPECT_NE(cache.Peek("a@1"), nullptr);
  ASSERT_TRUE(cache.GetOrLoad("c@1", Value(hundred)).ok());  // Now b (unused) goes; a still held.
  EXPECT_EQ(cache.Peek("b@1"), nullptr);
  EXPECT_NE(cache.Peek("a@1"), nullptr);
  held = absl::InternalError("released");  // The render ends.
  ASSERT_TRUE(cache.GetOrLoad("d@1", Value(hundred)).ok());  // a is free to go now.
  EXPECT_EQ(cache.Peek("a@1"), nullptr);
  EXPECT_LE(cache.stats().bytes, 200);
}

TEST(ModelCacheTest, ConcurrentGetsOfOneKeyLoadItOnce) {
  Cache cache = MakeCache(0);
  std::atomic<int> calls{0};
  const Cache::Loader slow = [&calls]() -> absl::StatusOr<std::shared_ptr<const std::string>> {
    ++calls;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    return std::make_shared<const std::string>("model");
  };
  std::vector<std::shared_ptr<const std::string>> got(8);
  std::vector<std::thread> threads;
  for (int i = 0; i < 8; ++i) {
    threads.emplace_back([&, i] {
      auto v = cache.GetOrLoad("p@1", slow);
      if (v.ok()) got[i] = *v;
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(calls.load(), 1);
  for (const auto& g : got) EXPECT_EQ(g, got[0]);  // The same object for all.
  EXPECT_NE(got[0], nullptr);
}

TEST(ModelCacheTest, AFailedLoadReachesEveryWaiterAndIsRetriedNextTime) {
  Cache cache = MakeCache(0);
  std::atomic<int> calls{0};
  const Cache::Loader failing = [&calls]() -> absl::StatusOr<std::shared_ptr<const std::string>> {
    ++calls;
    std::this_thread::sleep_for(std::chrono::milliseconds(30));
    return absl::DataLossError("checksum mismatch");
  };
  std::vector<absl::StatusCode> codes(4);
  std::vector<std::thread> threads;
  for (int i = 0; i < 4; ++i) {
    threads.emplace_back([&, i] { codes[i] = cache.GetOrLoad("p@2", failing).status().code(); });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(calls.load(), 1);
  for (absl::StatusCode c : codes) EXPECT_EQ(c, absl::StatusCode::kDataLoss);
  EXPECT_EQ(cache.stats().load_failures, 1);
  EXPECT_EQ(cache.stats().entries, 0);
  auto v = cache.GetOrLoad("p@2", Value("fixed"));
  ASSERT_TRUE(v.ok());
  EXPECT_EQ(**v, "fixed");
}

TEST(ModelCacheTest, ErasePrefixDropsOnePlaceOnly) {
  Cache cache = MakeCache(0);
  for (const char* k : {"a@1", "a@2", "ab@1", "b@1"}) ASSERT_TRUE(cache.GetOrLoad(k, Value("v")).ok());
  cache.ErasePrefix("a@");
  EXPECT_EQ(cache.Peek("a@1"), nullptr);
  EXPECT_EQ(cache.Peek("a@2"), nullptr);
  EXPECT_NE(cache.Peek("ab@1"), nullptr);
  EXPECT_NE(cache.Peek("b@1"), nullptr);
  EXPECT_EQ(cache.stats().bytes, 2);
  cache.Erase("b@1");
  EXPECT_EQ(cache.stats().entries, 1);
}

// Put (a version trained here) evicts to fit and replaces a key; Offer (a
// version verified at start-up) joins only if it fits without evicting.
TEST(ModelCacheTest, PutEvictsToFitAndOfferOnlyTakesFreeRoom) {
  int evicted = 0;
  Cache cache(250, [](const std::string& v) { return int64_t(v.size()); }, [&] { ++evicted; });
  const std::string hundred(100, 'x');
  EXPECT_TRUE(cache.Offer("a@1", std::make_shared<const std::string>(hundred)));
  EXPECT_TRUE(cache.Offer("b@1", std::make_shared<const std::string>(hundred)));
  EXPECT_FALSE(cache.Offer("c@1", std::make_shared<const std::string>(hundred)));  // 300 > 250.
  EXPECT_EQ(cache.Peek("c@1"), nullptr);
  EXPECT_EQ(evicted, 0);
  // Replacing a key with a same-sized value fits without evicting.
  EXPECT_TRUE(cache.Offer("b@1", std::make_shared<const std::string>(std::string(100, 'y'))));
  EXPECT_EQ(*cache.Peek("b@1"), std::string(100, 'y'));
  cache.Put("c@1", std::make_shared<const std::string>(hundred));  // Evicts a (least recent).
  EXPECT_EQ(cache.Keys(), (std::vector<std::string>{"c@1", "b@1"}));
  EXPECT_EQ(evicted, 1);
  EXPECT_EQ(cache.stats().evictions, 1);
  EXPECT_EQ(cache.stats().bytes, 200);
  // A put value larger than the budget stays (it is the one just deployed),
  // and everything else that nobody holds goes.
  const std::shared_ptr<const std::string> held = cache.Peek("b@1");
  cache.Put("d@1", std::make_shared<const std::string>(std::string(300, 'z')));
  EXPECT_EQ(cache.Keys(), (std::vector<std::string>{"d@1", "b@1"}));  // b is held by a reader.
  EXPECT_EQ(evicted, 2);
}

}  // namespace
}  // namespace clnerf
