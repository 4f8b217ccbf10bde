// IEEE 754 binary16 ("half") <-> binary32 conversion, portable bit
// manipulation (no F16C needed; checkpoints convert a few million values, so
// speed does not matter).
//
// FloatToHalf rounds to nearest, ties to even, like a hardware conversion
// (F16C _cvtss_sh with _MM_FROUND_TO_NEAREST_INT): values whose magnitude
// rounds beyond the largest half (65504) become +-infinity, tiny values become
// half subnormals or +-0, infinities stay infinities, and NaNs stay NaNs (quiet,
// sign and the top 9 payload bits kept). HalfToFloat is exact (every half is a
// float).
#ifndef CLNERF_CORE_IO_HALF_H_
#define CLNERF_CORE_IO_HALF_H_

#include <bit>
#include <cstdint>

namespace clnerf {

inline constexpr float kMaxHalf = 65504.0f;

constexpr uint16_t FloatToHalf(float value) {
  const uint32_t f = std::bit_cast<uint32_t>(value);
  const uint16_t sign = uint16_t((f >> 16) & 0x8000u);
  const uint32_t abs = f & 0x7fffffffu;
  if (abs >= 0x7f800000u) {  // Inf or NaN.
    if (abs == 0x7f800000u) return uint16_t(sign | 0x7c00u);
    return uint16_t(sign | 0x7e00u | ((abs >> 13) & 0x1ffu));  // Quiet NaN.
  }
  const int exp = int(abs >> 23) - 127;  // Unbiased exponent of the float.
  if (exp >= 16) return uint16_t(sign | 0x7c00u);  // >= 65536: overflow.
  if (exp >= -14) {
    // Normal half: keep 10 of the 23 mantissa bits, round the 13 dropped.
    // Adding the rounding bias may carry into the exponent, which is exactly
    // right (including overflow to infinity at 65520).
    const uint32_t h = ((uint32_t(exp + 15) << 10) | ((abs >> 13) & 0x3ffu));
    const uint32_t rest = abs & 0x1fffu;
    const uint32_t round_up = rest > 0x1000u || (rest == 0x1000u && (h & 1u));
    return uint16_t(sign | (h + round_up));
  }
  if (exp < -25) return sign;  // Below half the smallest subnormal (2^-24): +-0.
  // Subnormal half: value = m * 2^-24 with m = mantissa(1.x) >> shift.
  const uint32_t mant = (abs & 0x7fffffu) | 0x800000u;  // 24 significant bits.
  const int shift = -exp - 1;  // 14..24: 2^exp * 1.x = (mant >> (13 + (-14 - exp))) * 2^-24.
  const uint32_t h = mant >> shift;
  const uint32_t rest = mant & ((1u << shift) - 1u);
  const uint32_t half_way = 1u << (shift - 1);
  const uint32_t round_up = rest > half_way || (rest == half_way && (h & 1u));
  return uint16_t(sign | (h + round_up));  // A carry into 0x400 gives the smallest normal.
}

constexpr float HalfToFloat(uint16_t h) {
  const uint32_t sign = uint32_t(h & 0x8000u) << 16;
  const uint32_t exp = (h >> 10) & 0x1fu;
  const uint32_t mant = h & 0x3ffu;
  if (exp == 0x1f) return std::bit_cast<float>(sign | 0x7f800000u | (mant << 13));  // Inf / NaN.
  if (exp != 0) return std::bit_cast<float>(sign | ((exp + 112) << 23) | (mant << 13));
  if (mant == 0) return std::bit_cast<float>(sign);  // +-0.
  // Subnormal: mant * 2^-24, exact in float.
  const float magnitude = float(mant) * (1.0f / 16777216.0f);
  return sign ? -magnitude : magnitude;
}

}  // namespace clnerf

#endif  // CLNERF_CORE_IO_HALF_H_
