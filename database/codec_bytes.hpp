// Byte-level helpers shared by the version 1 and version 2 frame codecs (database/codec.cpp,
// database/codec_v2.cpp). Internal to database/: not part of the codec's interface.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>

#include "database/codec.hpp"

namespace clothdb::codec::bytes {

constexpr uint8_t kMagic[4] = {'C', 'L', 'D', 'F'};

inline void put_u16(uint8_t* p, uint16_t v) {
  p[0] = uint8_t(v);
  p[1] = uint8_t(v >> 8);
}
inline void put_u32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
inline void put_u64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = uint8_t(v >> (8 * i));
}
inline void put_f64(uint8_t* p, double v) {
  put_u64(p, std::bit_cast<uint64_t>(v));
}
inline void put_f32(uint8_t* p, float v) {
  put_u32(p, std::bit_cast<uint32_t>(v));
}
inline uint16_t get_u16(const uint8_t* p) {
  return uint16_t(p[0] | p[1] << 8);
}
inline uint32_t get_u32(const uint8_t* p) {
  return uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24;
}
inline uint64_t get_u64(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}
inline double get_f64(const uint8_t* p) {
  return std::bit_cast<double>(get_u64(p));
}
inline float get_f32(const uint8_t* p) {
  return std::bit_cast<float>(get_u32(p));
}

// The one dequantisation formula, shared by both encoders' bound checks and both decoders. The
// library is built with -ffp-contract=off so every call site rounds identically.
// q is below 2^28 (range-checked first), so going through int32 is exact and lets the compiler use
// the plain signed conversion instead of the slower unsigned one.
inline float dequantise(double origin, double step, uint32_t q) {
  return float(origin + double(int32_t(q)) * step);
}

inline uint32_t zigzag(uint32_t r) {
  return (r << 1) ^ (0u - (r >> 31));
}
inline uint32_t unzigzag(uint32_t u) {
  return (u >> 1) ^ (0u - (u & 1u));
}

}  // namespace clothdb::codec::bytes

namespace clothdb::codec::v2 {
// The version 2 halves of read_info, decode_frames and detail::reseal (database/codec_v2.cpp);
// codec.cpp dispatches on the version field.
Status parse(const uint8_t* blob, size_t size, BlobInfo* info, Error* err);
Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
              size_t out_floats, DecodeScratch& scratch, Error* err, const Basis* basis);
void reseal(uint8_t* blob, size_t size);
}  // namespace clothdb::codec::v2
