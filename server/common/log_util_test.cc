#include "server/common/log_util.h"

#include <string>

#include "gtest/gtest.h"

namespace clnerf {
namespace {

TEST(EscapeForLogTest, ControlsBecomeEscapesAndUtf8Stays) {
  EXPECT_EQ(EscapeForLog("a\nb\\c\x1b[31m"), "a\\nb\\\\c\\x1b[31m");
  EXPECT_EQ(EscapeForLog("caf\xc3\xa9 \xe2\x80\x94 \xe6\x97\xa5"), "caf\xc3\xa9 \xe2\x80\x94 \xe6\x97\xa5");
  EXPECT_EQ(EscapeForLog(std::string(10, 'x'), 4), "xxxx...(10 bytes)");
}

TEST(EscapeForLogTest, UnicodeLineBreaksAndBidiControlsAreEscaped) {
  EXPECT_EQ(EscapeForLog("nel\xc2\x85[error] fake"), "nel\\u0085[error] fake");
  EXPECT_EQ(EscapeForLog("a\xe2\x80\xa8" "b\xe2\x80\xa9" "c"), "a\\u2028b\\u2029c");
  EXPECT_EQ(EscapeForLog("x\xe2\x80\xaeyz"), "x\\u202eyz");
  EXPECT_EQ(EscapeForLog("\xe2\x81\xa6\xe2\x81\xa9"), "\\u2066\\u2069");
  EXPECT_EQ(EscapeForLog("\xe2\x80\x8e\xe2\x80\x8f\xd8\x9c"), "\\u200e\\u200f\\u061c");
  EXPECT_EQ(EscapeForLog("\xc2\x9b" "31m"), "\\u009b31m");  // C1 CSI.
  // Neighbours of the escaped ranges are ordinary text.
  EXPECT_EQ(EscapeForLog("\xe2\x80\xa7\xe2\x80\xaf\xc2\xa0"), "\xe2\x80\xa7\xe2\x80\xaf\xc2\xa0");
  // Every escaped form is printable ASCII.
  for (char c : EscapeForLog("\xc2\x85\xe2\x80\xa8\xe2\x80\xae\n")) {
    EXPECT_GE(static_cast<unsigned char>(c), 0x20);
    EXPECT_LT(static_cast<unsigned char>(c), 0x7f);
  }
}

TEST(EscapeForLogTest, InvalidUtf8BecomesHexEscapesSoTheResultIsValid) {
  EXPECT_EQ(EscapeForLog("caf\xc3\xa9"), "caf\xc3\xa9");      // Well-formed: kept.
  EXPECT_EQ(EscapeForLog("caf\xc3"), "caf\\xc3");              // A lone lead byte.
  EXPECT_EQ(EscapeForLog("\xa9x"), "\\xa9x");                  // A stray continuation byte.
  EXPECT_EQ(EscapeForLog("\xc0\xaf"), "\\xc0\\xaf");        // Overlong '/'.
  EXPECT_EQ(EscapeForLog("\xed\xa0\x80"), "\\xed\\xa0\\x80");  // A surrogate.
  EXPECT_EQ(EscapeForLog("\xf0\x9f\x8f\xa0"), "\xf0\x9f\x8f\xa0");  // U+1F3E0 kept.
  // A character cut by the byte limit is escaped, not split.
  EXPECT_EQ(EscapeForLog("ab\xc3\xa9", 3), "ab\\xc3...(4 bytes)");
}

}  // namespace
}  // namespace clnerf
