// Byte I/O: the one little-endian binary writer and bounds-checked reader
// that every clnerf file format uses (checkpoints, replay memories). Values
// are stored little-endian whatever the host; arrays of arithmetic types are
// copied in one memcpy on little-endian hosts. A ByteReader never reads past
// its input: every getter returns false instead, and array counts are checked
// against the remaining bytes before anything is allocated.
//
// Thread-safety: a writer or reader is used by one thread at a time.
#ifndef CLNERF_CORE_IO_BYTE_IO_H_
#define CLNERF_CORE_IO_BYTE_IO_H_

#include <bit>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace clnerf {

template <typename U>
U ToLittle(U v) {
  static_assert(std::is_unsigned_v<U>);
  if constexpr (std::endian::native == std::endian::little || sizeof(U) == 1) {
    return v;
  } else {
    U r = 0;
    for (size_t i = 0; i < sizeof(U); ++i) {
      r = U(r << 8) | U(v & 0xff);
      v = U(v >> 8);
    }
    return r;
  }
}

// The unsigned integer type with the same size as T (T: float, integers).
template <typename T>
using Bits = std::conditional_t<
    sizeof(T) == 1, uint8_t,
    std::conditional_t<sizeof(T) == 2, uint16_t, std::conditional_t<sizeof(T) == 4, uint32_t, uint64_t>>>;

class ByteWriter {
 public:
  explicit ByteWriter(std::string* out) : out_(out) {}

  template <typename T>
  void Put(T v) {
    static_assert(std::is_arithmetic_v<T> &&
                  (sizeof(T) == 1 || sizeof(T) == 2 || sizeof(T) == 4 || sizeof(T) == 8));
    const Bits<T> le = ToLittle(std::bit_cast<Bits<T>>(v));
    out_->append(reinterpret_cast<const char*>(&le), sizeof(le));
  }
  void I32(int v) { Put(int32_t(v)); }
  void Bytes(std::string_view s) { out_->append(s.data(), s.size()); }
  void String(std::string_view s) {
    Put(uint64_t(s.size()));
    Bytes(s);
  }
  template <typename T>
  void Array(const std::vector<T>& v) {
    if constexpr (std::endian::native == std::endian::little) {
      if (!v.empty()) out_->append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
    } else {
      for (const T& x : v) Put(x);
    }
  }

  // Sections: Begin writes the tag and a length placeholder, End patches it.
  size_t BeginSection(uint32_t tag) {
    Put(tag);
    const size_t at = out_->size();
    Put(uint64_t(0));
    return at;
  }
  void EndSection(size_t at) {
    const uint64_t len = ToLittle(uint64_t(out_->size() - at - sizeof(uint64_t)));
    std::memcpy(out_->data() + at, &len, sizeof(len));
  }

 private:
  std::string* out_;
};

// Bounds-checked reader over one section's payload. Every Get fails (returns
// false) instead of reading past the end.
class ByteReader {
 public:
  explicit ByteReader(std::string_view data) : data_(data) {}

  size_t remaining() const { return data_.size() - pos_; }
  bool done() const { return pos_ == data_.size(); }

  template <typename T>
  bool Get(T* v) {
    if (remaining() < sizeof(T)) return false;
    Bits<T> le;
    std::memcpy(&le, data_.data() + pos_, sizeof(le));
    *v = std::bit_cast<T>(ToLittle(le));
    pos_ += sizeof(T);
    return true;
  }
  bool I32(int* v) {
    int32_t x;
    if (!Get(&x)) return false;
    *v = x;
    return true;
  }
  bool Bytes(size_t n, std::string_view* out) {
    if (remaining() < n) return false;
    *out = data_.substr(pos_, n);
    pos_ += n;
    return true;
  }
  bool String(std::string* s) {
    uint64_t n;
    std::string_view v;
    if (!Get(&n) || n > remaining() || !Bytes(size_t(n), &v)) return false;
    s->assign(v.data(), v.size());
    return true;
  }
  // Reads `count` elements; the count is checked against the remaining bytes
  // before anything is allocated.
  template <typename T>
  bool Array(uint64_t count, std::vector<T>* v) {
    if (count > remaining() / sizeof(T)) return false;
    v->resize(size_t(count));
    if constexpr (std::endian::native == std::endian::little) {
      if (count > 0) std::memcpy(v->data(), data_.data() + pos_, size_t(count) * sizeof(T));
      pos_ += size_t(count) * sizeof(T);
    } else {
      for (T& x : *v) Get(&x);
    }
    return true;
  }

 private:
  std::string_view data_;
  size_t pos_ = 0;
};

}  // namespace clnerf

#endif  // CLNERF_CORE_IO_BYTE_IO_H_
