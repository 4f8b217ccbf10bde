// Log hygiene for strings that come from clients (scan names, frame names,
// HTTP paths, error messages that quote them): EscapeForLog makes them one
// printable line, so a name cannot forge log lines or smuggle terminal
// escapes into the text log. That covers the Unicode line breaks that
// Unicode-aware viewers honour (U+0085 NEL and the other C1 controls,
// U+2028, U+2029) and the bidirectional controls that reorder what a reader
// sees (U+061C, U+200E, U+200F, U+202A..U+202E, U+2066..U+2069).
// (The JSON log format escapes on its own.)
//
// Thread-safety: a pure function.
#ifndef CLNERF_SERVER_LOG_UTIL_H_
#define CLNERF_SERVER_LOG_UTIL_H_

#include <string>
#include <string_view>

namespace clnerf {

// If `s` holds, at byte i, the UTF-8 encoding of a C1 control, a Unicode
// line or paragraph separator or a bidirectional control, returns its
// length in bytes and stores the code point; else returns 0.
inline size_t LineBreakOrBidiAt(std::string_view s, size_t i, unsigned* code_point) {
  auto byte = [&](size_t k) { return i + k < s.size() ? static_cast<unsigned char>(s[i + k]) : 0u; };
  const unsigned b0 = byte(0), b1 = byte(1), b2 = byte(2);
  if (b0 == 0xc2 && b1 >= 0x80 && b1 <= 0x9f) {  // U+0080..U+009F (C1, NEL).
    *code_point = b1;
    return 2;
  }
  if (b0 == 0xd8 && b1 == 0x9c) {  // U+061C ARABIC LETTER MARK.
    *code_point = 0x61c;
    return 2;
  }
  if (b0 == 0xe2 && b1 == 0x80 && ((b2 >= 0xa8 && b2 <= 0xae) || b2 == 0x8e || b2 == 0x8f)) {
    *code_point = 0x2000 + (b2 - 0x80);  // U+2028/9, U+202A..E, U+200E/F.
    return 3;
  }
  if (b0 == 0xe2 && b1 == 0x81 && b2 >= 0xa6 && b2 <= 0xa9) {  // U+2066..U+2069 isolates.
    *code_point = 0x2040 + (b2 - 0x80);
    return 3;
  }
  return 0;
}

// The length of the well-formed UTF-8 sequence (2 to 4 bytes) that starts
// at byte i and ends before byte `end`, or 0 (a lone or stray byte, an
// overlong form, a surrogate, past U+10FFFF, or one cut at `end`).
inline size_t Utf8SequenceAt(std::string_view s, size_t i, size_t end) {
  auto byte = [&](size_t k) { return i + k < end ? static_cast<unsigned char>(s[i + k]) : 0u; };
  const unsigned b0 = byte(0), b1 = byte(1);
  auto cont = [&](size_t k) { return (byte(k) & 0xc0) == 0x80; };
  if (b0 >= 0xc2 && b0 <= 0xdf) return cont(1) ? 2 : 0;
  if (b0 >= 0xe0 && b0 <= 0xef) {
    if ((b0 == 0xe0 && b1 < 0xa0) || (b0 == 0xed && b1 >= 0xa0)) return 0;  // Overlong; surrogates.
    return cont(1) && cont(2) ? 3 : 0;
  }
  if (b0 >= 0xf0 && b0 <= 0xf4) {
    if ((b0 == 0xf0 && b1 < 0x90) || (b0 == 0xf4 && b1 >= 0x90)) return 0;  // Overlong; past U+10FFFF.
    return cont(1) && cont(2) && cont(3) ? 4 : 0;
  }
  return 0;
}

// Control characters and backslashes become C escapes (\n, \x1b, \\), and
// the code points LineBreakOrBidiAt finds become \u escapes (\u2028);
// well-formed UTF-8 is kept, and any other byte of 0x80 or more (invalid
// UTF-8, or a character cut by the limit) becomes \xNN, so the result is
// always valid UTF-8 (a gRPC status message must be). At most `max_bytes`
// input bytes are shown, then "...(N bytes)".
inline std::string EscapeForLog(std::string_view s, size_t max_bytes = 512) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  const size_t n = s.size() < max_bytes ? s.size() : max_bytes;
  out.reserve(n + 16);
  for (size_t i = 0; i < n; ++i) {
    unsigned cp = 0;
    if (const size_t len = LineBreakOrBidiAt(s, i, &cp); len > 0) {
      out += "\\u";
      for (int shift = 12; shift >= 0; shift -= 4) out += kHex[(cp >> shift) & 15];
      i += len - 1;
      continue;
    }
    const unsigned char c = static_cast<unsigned char>(s[i]);
    if (c >= 0x80) {
      if (const size_t len = Utf8SequenceAt(s, i, n); len > 0) {
        out.append(s.substr(i, len));
        i += len - 1;
      } else {
        out += "\\x";
        out += kHex[c >> 4];
        out += kHex[c & 15];
      }
      continue;
    }
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
