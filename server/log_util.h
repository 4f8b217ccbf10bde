// Log hygiene for strings that come from clients (scan names, frame names,
// error messages that quote them): EscapeForLog makes them one printable
// line, so a name cannot forge log lines or smuggle terminal escapes into the
// text log. (The JSON log format escapes on its own.)
//
// Thread-safety: a pure function.
#ifndef CLNERF_SERVER_LOG_UTIL_H_
#define CLNERF_SERVER_LOG_UTIL_H_

#include <string>
#include <string_view>

namespace clnerf {

// Control characters and backslashes become C escapes (\n, \x1b, \\);
// everything else, UTF-8 included, is kept. At most `max_bytes` input bytes
// are shown, then "...(N bytes)".
inline std::string EscapeForLog(std::string_view s, size_t max_bytes = 512) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  const size_t n = s.size() < max_bytes ? s.size() : max_bytes;
  out.reserve(n + 16);
  for (size_t i = 0; i < n; ++i) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    switch (c) {
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      case '\\': out += "\\\\"; break;
      default:
        if (c < 0x20 || c == 0x7f) {
          out += "\\x";
          out += kHex[c >> 4];
          out += kHex[c & 15];
        } else {
          out += char(c);
        }
    }
  }
  if (n < s.size()) out += "...(" + std::to_string(s.size()) + " bytes)";
  return out;
}

}  // namespace clnerf

#endif  // CLNERF_SERVER_LOG_UTIL_H_
