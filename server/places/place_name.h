// Place names: a place (a room, a shop, a floor) is the unit of the API, and
// its name becomes a directory of the store, so it is checked before it is
// used anywhere: 1-64 bytes of ASCII letters, digits, '-', '_' and '.',
// starting with a letter or digit. That rules out path separators, "..",
// hidden files, control characters and any non-ASCII look-alike, so a place
// name can never address anything outside its own directory. The empty name
// means the place called "default" (clients from before places existed).
//
// Pure functions; thread-safe.
#ifndef CLNERF_SERVER_PLACE_NAME_H_
#define CLNERF_SERVER_PLACE_NAME_H_

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"

namespace clnerf {

inline constexpr std::string_view kDefaultPlace = "default";
inline constexpr size_t kMaxPlaceNameBytes = 64;

// INVALID_ARGUMENT with the reason (quoting at most the first 40 bytes of the
// name, escaped) unless `name` is a valid place name. The empty name is not
// valid here: resolve it with PlaceOrDefault first.
absl::Status ValidatePlaceName(std::string_view name);

// `name`, or "default" when it is empty.
std::string PlaceOrDefault(std::string_view name);

// NOT_FOUND for a place that does not exist: names up to `max_listed` known
// places (sorted) in the message, or says how many there are.
absl::Status UnknownPlace(std::string_view name, const std::vector<std::string>& known, size_t max_listed = 10);

}  // namespace clnerf

#endif  // CLNERF_SERVER_PLACE_NAME_H_
