#include "server/places/place_name.h"

#include <algorithm>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "server/common/log_util.h"

namespace clnerf {
namespace {

bool IsAlnum(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9'); }

// The name as a message may quote it: escaped, and cut to 40 bytes.
std::string Quoted(std::string_view name) {
  constexpr size_t kQuote = 40;
  std::string q = EscapeForLog(name.substr(0, kQuote));
  if (name.size() > kQuote) absl::StrAppend(&q, "...");
  return absl::StrCat("'", q, "'");
}

}  // namespace

absl::Status ValidatePlaceName(std::string_view name) {
  if (name.empty()) return absl::InvalidArgumentError("place name is empty");
  if (name.size() > kMaxPlaceNameBytes) {
    return absl::InvalidArgumentError(absl::StrCat("place name ", Quoted(name), " is ", name.size(),
                                                   " bytes; the limit is ", kMaxPlaceNameBytes));
  }
  if (!IsAlnum(name[0])) {
    return absl::InvalidArgumentError(
        absl::StrCat("place name ", Quoted(name), " must start with a letter or a digit"));
  }
  for (size_t i = 0; i < name.size(); ++i) {
    const char c = name[i];
    if (!IsAlnum(c) && c != '-' && c != '_' && c != '.') {
      const size_t len = std::max<size_t>(1, Utf8SequenceAt(name, i, name.size()));  // A whole character.
      return absl::InvalidArgumentError(absl::StrCat("place name ", Quoted(name), " has '",
                                                     EscapeForLog(name.substr(i, len)), "' at byte ", i,
                                                     "; use letters, digits, '-', '_' and '.'"));
    }
  }
  if (name.find("..") != std::string_view::npos) {
    return absl::InvalidArgumentError(absl::StrCat("place name ", Quoted(name), " contains '..'"));
  }
  return absl::OkStatus();
}

std::string PlaceOrDefault(std::string_view name) {
  return name.empty() ? std::string(kDefaultPlace) : std::string(name);
}

absl::Status UnknownPlace(std::string_view name, const std::vector<std::string>& known, size_t max_listed) {
  std::string msg = absl::StrCat("no place ", Quoted(name));
  if (known.empty()) {
    absl::StrAppend(&msg, "; the store has no places yet");
  } else if (known.size() <= max_listed) {
    std::vector<std::string> sorted = known;
    std::sort(sorted.begin(), sorted.end());
    absl::StrAppend(&msg, "; places: ", absl::StrJoin(sorted, ", "));
  } else {
    absl::StrAppend(&msg, "; the store has ", known.size(), " places (list them with `clnerf places`)");
  }
  return absl::NotFoundError(msg);
}

}  // namespace clnerf
