#include "core/data/npy_reader.h"

#include <bit>
#include <cctype>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>

#include "absl/strings/str_cat.h"

namespace clnerf {
namespace {

static_assert(std::endian::native == std::endian::little, "npy reader assumes little-endian");

constexpr char kMagic[] = "\x93NUMPY";
constexpr size_t kMagicLen = 6;

absl::Status Invalid(const std::string& name, const std::string& what) {
  return absl::InvalidArgumentError(absl::StrCat(name, ": ", what));
}

// A minimal parser for the header's Python dict literal, e.g.
//   {'descr': '<f8', 'fortran_order': False, 'shape': (71, 17), }
class HeaderParser {
 public:
  explicit HeaderParser(const std::string& text) : s_(text) {}

  // Fills the three keys numpy writes; false on any syntax error, unknown or
  // missing key.
  bool Parse(std::string* descr, bool* fortran_order, std::vector<int64_t>* shape) {
    bool have_descr = false, have_order = false, have_shape = false;
    if (!Eat('{')) return false;
    while (true) {
      SkipSpace();
      if (Eat('}')) break;
      std::string key;
      if (!String(&key) || !Eat(':')) return false;
      if (key == "descr" && !have_descr) {
        have_descr = String(descr);
        if (!have_descr) return false;
      } else if (key == "fortran_order" && !have_order) {
        have_order = Bool(fortran_order);
        if (!have_order) return false;
      } else if (key == "shape" && !have_shape) {
        have_shape = Tuple(shape);
        if (!have_shape) return false;
      } else {
        return false;
      }
      if (!Eat(',')) {
        if (!Eat('}')) return false;
        break;
      }
    }
    SkipSpace();
    return pos_ == s_.size() && have_descr && have_order && have_shape;
  }

 private:
  void SkipSpace() {
    while (pos_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
  }
  bool Eat(char c) {
    SkipSpace();
    if (pos_ < s_.size() && s_[pos_] == c) {
      ++pos_;
      return true;
    }
    return false;
  }
  bool String(std::string* out) {
    SkipSpace();
    if (pos_ >= s_.size() || (s_[pos_] != '\'' && s_[pos_] != '"')) return false;
    const char quote = s_[pos_++];
    const size_t end = s_.find(quote, pos_);
    if (end == std::string::npos) return false;
    out->assign(s_, pos_, end - pos_);
    pos_ = end + 1;
    return true;
  }
  bool Bool(bool* out) {
    SkipSpace();
    for (const auto& [word, value] : {std::pair{"True", true}, std::pair{"False", false}}) {
      const size_t n = std::strlen(word);
      if (s_.compare(pos_, n, word) == 0) {
        pos_ += n;
        *out = value;
        return true;
      }
    }
    return false;
  }
  bool Tuple(std::vector<int64_t>* out) {
    out->clear();
    if (!Eat('(')) return false;
    while (true) {
      if (Eat(')')) return true;
      SkipSpace();
      int64_t v = 0;
      size_t digits = 0;
      while (pos_ < s_.size() && std::isdigit(static_cast<unsigned char>(s_[pos_]))) {
        if (v > (int64_t(1) << 40)) return false;  // Far beyond any readable file.
        v = v * 10 + (s_[pos_++] - '0');
        ++digits;
      }
      if (digits == 0) return false;
      if (pos_ < s_.size() && s_[pos_] == 'L') ++pos_;  // Python 2 long suffix.
      out->push_back(v);
      if (!Eat(',')) return Eat(')');
    }
  }

  const std::string& s_;
  size_t pos_ = 0;
};

}  // namespace

absl::StatusOr<NpyArray> ParseNpy(const std::string& bytes, const std::string& name) {
  if (bytes.size() < kMagicLen + 2 || bytes.compare(0, kMagicLen, kMagic, kMagicLen) != 0) {
    return Invalid(name, "not a .npy file (bad magic)");
  }
  const int major = static_cast<unsigned char>(bytes[kMagicLen]);
  size_t header_len = 0, prefix = 0;
  if (major == 1) {
    if (bytes.size() < 10) return Invalid(name, "truncated .npy header");
    header_len = static_cast<unsigned char>(bytes[8]) | (static_cast<unsigned char>(bytes[9]) << 8);
    prefix = 10;
  } else if (major == 2 || major == 3) {
    if (bytes.size() < 12) return Invalid(name, "truncated .npy header");
    uint32_t len;
    std::memcpy(&len, bytes.data() + 8, 4);
    header_len = len;
    prefix = 12;
  } else {
    return Invalid(name, absl::StrCat("unsupported .npy format version ", major));
  }
  if (bytes.size() - prefix < header_len) return Invalid(name, "truncated .npy header");
  const std::string header = bytes.substr(prefix, header_len);

  std::string descr;
  bool fortran_order = false;
  NpyArray out;
  if (!HeaderParser(header).Parse(&descr, &fortran_order, &out.shape)) {
    return Invalid(name, absl::StrCat("malformed .npy header: ", header));
  }
  size_t item = 0;
  if (descr == "<f8") {
    item = 8;
  } else if (descr == "<f4") {
    item = 4;
  } else {
    return Invalid(name, absl::StrCat("unsupported .npy dtype '", descr,
                                      "' (supported: '<f8' float64, '<f4' float32)"));
  }
  if (fortran_order) {
    return Invalid(name, "Fortran-order .npy arrays are not supported (expected C order)");
  }
  const size_t payload = bytes.size() - prefix - header_len;
  size_t count = 1;
  for (int64_t d : out.shape) {
    if (d != 0 && count > payload / size_t(d)) {
      return Invalid(
          name, absl::StrCat("truncated .npy data: shape needs more than ", payload, " bytes"));
    }
    count *= size_t(d);
  }
  if (count * item != payload) {
    return Invalid(
        name, absl::StrCat(count * item > payload ? "truncated" : "trailing bytes in",
                           " .npy data: shape needs ", count * item, " bytes, file has ", payload));
  }
  out.data.resize(count);
  const char* src = bytes.data() + prefix + header_len;
  for (size_t i = 0; i < count; ++i) {
    if (item == 8) {
      std::memcpy(&out.data[i], src + i * 8, 8);
    } else {
      float f;
      std::memcpy(&f, src + i * 4, 4);
      out.data[i] = f;
    }
  }
  return out;
}

absl::StatusOr<NpyArray> ReadNpy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open ", path));
  std::ostringstream ss;
  ss << in.rdbuf();
  return ParseNpy(ss.str(), path);
}

}  // namespace clnerf
