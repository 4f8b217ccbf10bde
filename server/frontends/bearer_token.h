// BearerTokenMatches: the one check of an `authorization: Bearer <token>`
// value, shared by the gRPC and HTTP front ends. The comparison takes the
// same time wherever the first difference is.
//
// Thread-safety: a pure function.
#ifndef CLNERF_SERVER_BEARER_TOKEN_H_
#define CLNERF_SERVER_BEARER_TOKEN_H_

#include <string>
#include <string_view>

namespace clnerf {

inline bool BearerTokenMatches(std::string_view header_value, const std::string& token) {
  const std::string want = "Bearer " + token;
  unsigned diff = unsigned(header_value.size() ^ want.size());
  for (size_t i = 0; i < want.size(); ++i) {
    diff |= unsigned(i < header_value.size() ? header_value[i] : 0) ^ unsigned(want[i]);
  }
  return diff == 0;
}

}  // namespace clnerf

#endif  // CLNERF_SERVER_BEARER_TOKEN_H_
