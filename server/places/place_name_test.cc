#include "server/places/place_name.h"

#include <string>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(PlaceNameTest, AcceptsOrdinaryNames) {
  for (const char* n : {"default", "shop-042", "Floor_3", "flat.12b", "a", "0"}) {
    EXPECT_TRUE(ValidatePlaceName(n).ok()) << n << ": " << ValidatePlaceName(n);
  }
  EXPECT_TRUE(ValidatePlaceName(std::string(kMaxPlaceNameBytes, 'x')).ok());
}

TEST(PlaceNameTest, RefusesAnythingThatCouldLeaveItsDirectory) {
  for (const char* n : {"", "..", ".", "../etc", "a/b", "a\\b", "/abs", ".hidden", "-flag", "a..b", "a b",
                        "caf\xc3\xa9", "tab\there", "nl\nx", "nul\x01", "x\x7f", "semi;colon", "q\"uote"}) {
    const absl::Status s = ValidatePlaceName(n);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << "'" << n << "'";
  }
  // A hostile 10 MB name: refused with its size, and the message quotes only
  // its first bytes.
  const std::string huge(10 << 20, 'a');
  const absl::Status s = ValidatePlaceName(huge);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("10485760 bytes"), std::string::npos) << s;
  EXPECT_LT(s.message().size(), 200u);
}

TEST(PlaceNameTest, MessagesEscapeControlCharacters) {
  const absl::Status s = ValidatePlaceName("ok\nFAKE LOG LINE");
  EXPECT_EQ(s.message().find('\n'), std::string::npos) << s;
}

// "café": the message names the whole character and stays valid UTF-8 (a
// gRPC status message must be).
TEST(PlaceNameTest, MessagesQuoteWholeCharacters) {
  const absl::Status s = ValidatePlaceName("caf\xc3\xa9");
  EXPECT_TRUE(absl::IsInvalidArgument(s));
  EXPECT_NE(s.message().find("has '\xc3\xa9' at byte 3"), std::string::npos) << s;
  const absl::Status lone = ValidatePlaceName("caf\xc3");
  EXPECT_NE(lone.message().find("has '\\xc3' at byte 3"), std::string::npos) << lone;
}

TEST(PlaceNameTest, EmptyMeansDefault) {
  EXPECT_EQ(PlaceOrDefault(""), "default");
  EXPECT_EQ(PlaceOrDefault("shop"), "shop");
  EXPECT_TRUE(ValidatePlaceName(PlaceOrDefault("")).ok());
}

TEST(PlaceNameTest, UnknownPlaceListsShortListsAndCountsLongOnes) {
  absl::Status s = UnknownPlace("nope", {"b", "a"});
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(s.message().find("places: a, b"), std::string::npos) << s;
  std::vector<std::string> many;
  for (int i = 0; i < 50; ++i) many.push_back(absl::StrCat("p", i));
  s = UnknownPlace("nope", many);
  EXPECT_NE(s.message().find("50 places"), std::string::npos) << s;
  s = UnknownPlace("nope", {});
  EXPECT_NE(s.message().find("no places"), std::string::npos) << s;
}

}  // namespace
}  // namespace clnerf
