// Byte-level helpers shared by the version 1 and version 2 frame codecs (database/codec.cpp,
// database/codec_v2.cpp). Internal to database/: not part of the codec's interface.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>

#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"
#include "database/format/status.hpp"

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

// Both frame blob versions put a chunk table of 16-byte entries right after their header, and
// the header checksum over the header up to `checksum_offset` and that table at
// `checksum_offset`.
constexpr size_t kChunkEntrySize = 16;

inline uint64_t header_checksum(const uint8_t* blob, size_t header_size, size_t checksum_offset,
                                uint32_t chunk_count) {
  return xxh64(blob + header_size, size_t(chunk_count) * kChunkEntrySize,
               xxh64(blob, checksum_offset));
}

// What both versions' headers share (docs/DATABASE.md "Frame blob format"), checked in the order
// the messages need: the header and chunk table fit in `size`, the header checksum matches; then
// the common fields (counts at 8..23, bound and step at 24, origin at 40, qmax at 64) into `in`.
// The version's own fields and every value check are the caller's.
inline Status parse_common_header(const uint8_t* blob, size_t size, size_t header_size,
                                  size_t checksum_offset, BlobInfo* in, Error* err) {
  if (size < header_size)
    return fail(err, Status::Truncated, "frame blob truncated: %zu bytes, header needs %zu", size,
                header_size);
  const uint32_t chunk_count = get_u32(blob + 20);
  const uint64_t table_end = header_size + uint64_t(chunk_count) * kChunkEntrySize;
  if (size < table_end)
    return fail(err, Status::Truncated,
                "frame blob truncated: %zu bytes, header and chunk table need %llu", size,
                (unsigned long long)table_end);
  const uint64_t stored = get_u64(blob + checksum_offset);
  const uint64_t actual = header_checksum(blob, header_size, checksum_offset, chunk_count);
  if (stored != actual)
    return fail(err, Status::ChecksumMismatch,
                "frame blob header checksum mismatch (stored %016llx, computed %016llx)",
                (unsigned long long)stored, (unsigned long long)actual);
  in->vertex_count = get_u32(blob + 8);
  in->frame_count = get_u32(blob + 12);
  in->key_interval = get_u32(blob + 16);
  in->chunk_count = chunk_count;
  in->bound = get_f64(blob + 24);
  in->step = get_f64(blob + 32);
  for (int a = 0; a < 3; ++a) {
    in->origin[a] = get_f64(blob + 40 + 8 * a);
    in->qmax[a] = get_u32(blob + 64 + 4 * a);
  }
  return Status::Ok;
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

namespace clothdb::codec::v3 {
// The version 3 halves (database/codec_v3.cpp); its segments are the chunks.
Status parse(const uint8_t* blob, size_t size, BlobInfo* info, Error* err);
Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
              size_t out_floats, DecodeScratch& scratch, Error* err, const Basis* basis);
void reseal(uint8_t* blob, size_t size);
// The segments of a blob parse() accepted.
void spans(const uint8_t* blob, std::vector<ChunkSpan>* out);
}  // namespace clothdb::codec::v3
