#include "database/codec/codec.hpp"

#include <zstd.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>

#include "database/codec/bytes.hpp"
#include "database/format/checksum.hpp"

namespace clothdb::codec {
namespace {

// Byte layout (little-endian), see docs/DATABASE.md:
//   0 magic "CLDF" | 4 u16 version | 6 u16 header size (88) | 8 u32 vertices | 12 u32 frames
//  16 u32 key interval | 20 u32 chunks | 24 f64 bound | 32 f64 step | 40 f64 origin[3]
//  64 u32 qmax[3] | 76 u32 row stride (0: none) | 80 u64 checksum of bytes 0..80 and the chunk
//  table 88 chunk table: per chunk u32 compressed size, u8 byte planes, u8 mode, u16 reserved (0),
//     u64 checksum of the compressed bytes | then the compressed chunks back to back.
constexpr size_t kHeaderSize = 88;
constexpr size_t kChecksumOffset = 80;
constexpr size_t kEntrySize = bytes::kChunkEntrySize;
// Quantised values stay below 2^28 so that 2 q[f-1] - q[f-2] and residuals fit in int32.
constexpr uint32_t kMaxQ = (1u << 28) - 1;
// Coordinates and bounds far beyond any garment are refused, so origin + q * step always fits a
// float and a tampered header cannot make the decoder emit infinities.
constexpr double kMaxCoordinate = 1e30;
constexpr double kMaxBound = 1e9;
// Chunk mode byte: bits 0-3 the temporal predictor for frames 1.. (1 delta, 2 linear, 3 none:
// every frame coded like a key frame, best when per-vertex motion is noisier than the shape;
// frame 1 uses delta for linear); bits 4-5 the spatial predictor applied to the temporal residuals
// of frames 1.. (0 none, 1 previous vertex, 2 Lorenzo over rows of row_stride vertices), which
// removes motion shared by neighbouring vertices (a swing, a gust, the character walking); bits 6-7
// the spatial predictor of the key frame's values (1 or 2).
constexpr uint8_t kTemporalMask = 0x0f;
constexpr uint8_t kSpatialMask = 0x30;
constexpr int kSpatialShift = 4;
constexpr uint8_t kKeyMask = 0xc0;
constexpr int kKeyShift = 6;

using namespace bytes;

struct Chunk {
  size_t offset;  // of the compressed bytes in the blob
  uint32_t size;
  uint8_t planes;
  uint8_t mode;  // predictor, see kSpatialBit
  uint64_t checksum;
};

Chunk read_entry(const uint8_t* blob, uint32_t index) {
  const uint8_t* e = blob + kHeaderSize + size_t(index) * kEntrySize;
  return {0, get_u32(e), e[4], e[5], get_u64(e + 8)};
}

// Parses and validates everything but the chunks' contents. Order matters for the messages: a
// foreign blob says "not a clothdb blob", a newer one says so, a short one says truncated, and
// only then are the checksum and the field values judged.
Status parse(const uint8_t* blob, size_t size, BlobInfo* info, Error* err) {
  if (blob == nullptr && size > 0)
    return fail(err, Status::InvalidArgument, "frame blob: null pointer");
  if (size < 4 || std::memcmp(blob, kMagic, 4) != 0)
    return fail(err, Status::NotClothdb, "not a clothdb frame blob (%zu bytes, no CLDF magic)",
                size);
  if (size < 6) return fail(err, Status::Truncated, "frame blob truncated at %zu bytes", size);
  const uint32_t version = get_u16(blob + 4);
  if (version > kNewestFormatVersion)
    return fail(err, Status::NewerVersion,
                "frame blob format version %u is newer than this build reads (up to %u)", version,
                kNewestFormatVersion);
  if (version == 0) return fail(err, Status::Corrupt, "frame blob format version 0 is invalid");
  if (version == kFormatVersionV2) return v2::parse(blob, size, info, err);
  if (version == kFormatVersionV3) return v3::parse(blob, size, info, err);
  BlobInfo in;
  if (Status st = parse_common_header(blob, size, kHeaderSize, kChecksumOffset, &in, err);
      st != Status::Ok)
    return st;
  const uint32_t chunk_count = in.chunk_count;
  in.version = version;
  in.row_stride = get_u32(blob + 76);
  if (get_u16(blob + 6) != kHeaderSize)
    return fail(err, Status::Corrupt, "frame blob header: unknown header size %u",
                get_u16(blob + 6));
  if (in.row_stride == 1 || in.row_stride >= std::max(in.vertex_count, 2u))
    return fail(err, Status::Corrupt, "frame blob header: row stride %u for %u vertices",
                in.row_stride, in.vertex_count);
  if (in.vertex_count == 0 || in.vertex_count > kMaxVertices)
    return fail(err, Status::Corrupt, "frame blob header: vertex count %u outside 1..%u",
                in.vertex_count, kMaxVertices);
  if (in.frame_count == 0 || in.key_interval == 0 || in.key_interval > in.frame_count)
    return fail(err, Status::Corrupt, "frame blob header: %u frames with key interval %u",
                in.frame_count, in.key_interval);
  if (uint64_t(in.key_interval) * in.vertex_count * 3 > kMaxChunkFloats)
    return fail(err, Status::Corrupt, "frame blob header: chunk of %u frames x %u vertices too big",
                in.key_interval, in.vertex_count);
  if (chunk_count != (uint64_t(in.frame_count) + in.key_interval - 1) / in.key_interval)
    return fail(err, Status::Corrupt, "frame blob header: %u chunks for %u frames with K=%u",
                chunk_count, in.frame_count, in.key_interval);
  if (!(in.bound > 0 && in.bound <= kMaxBound && std::isfinite(in.step) && in.step > 0 &&
        in.step <= 2 * in.bound))
    return fail(err, Status::Corrupt, "frame blob header: bound %g and step %g are inconsistent",
                in.bound, in.step);
  // Delta frames are range-checked against the largest axis range (one compare per value keeps
  // the loop vectorised), so every axis must stay representable up to that range.
  const double qlimit = std::max({in.qmax[0], in.qmax[1], in.qmax[2]});
  for (int a = 0; a < 3; ++a) {
    if (!(std::fabs(in.origin[a]) <= kMaxCoordinate) || in.qmax[a] > kMaxQ ||
        !(std::fabs(in.origin[a] + qlimit * in.step) <= kMaxCoordinate))
      return fail(err, Status::Corrupt, "frame blob header: axis %d origin %g / range %u invalid",
                  a, in.origin[a], in.qmax[a]);
  }
  uint64_t total = kHeaderSize + uint64_t(chunk_count) * kEntrySize;  // the chunk table's end
  for (uint32_t c = 0; c < chunk_count; ++c) {
    const uint8_t* e = blob + kHeaderSize + size_t(c) * kEntrySize;
    const uint32_t csize = get_u32(e);
    const int temporal = e[5] & kTemporalMask;
    const int spatial = (e[5] & kSpatialMask) >> kSpatialShift;
    const int key = (e[5] & kKeyMask) >> kKeyShift;
    if (csize == 0 || e[4] < 1 || e[4] > 4 || temporal < 1 || temporal > 3 || spatial > 2 ||
        key < 1 || key > 2 || ((spatial == 2 || key == 2) && in.row_stride == 0) ||
        get_u16(e + 6) != 0)
      return fail(err, Status::Corrupt, "frame blob chunk %u: invalid table entry", c);
    total += csize;
  }
  if (size < total)
    return fail(err, Status::Truncated, "frame blob truncated: %zu bytes of %llu", size,
                (unsigned long long)total);
  if (size > total)
    return fail(err, Status::Corrupt, "frame blob has %llu trailing bytes",
                (unsigned long long)(size - total));
  in.size = size;
  if (info) *info = in;
  return Status::Ok;
}

template <int NB>
inline uint32_t load(const uint8_t* p, size_t plane, size_t i) {
  uint32_t u = p[i];
  if constexpr (NB >= 2) u |= uint32_t(p[plane + i]) << 8;
  if constexpr (NB >= 3) u |= uint32_t(p[2 * plane + i]) << 16;
  if constexpr (NB >= 4) u |= uint32_t(p[3 * plane + i]) << 24;
  return u;
}

// Spatial prediction, the same for the encoder (forward) and the decoder (inverse). A value e[i]
// (coordinate a of vertex v) is predicted by
//   kind 1 (previous vertex): e[v-1]
//   kind 2 (Lorenzo, for meshes laid out in rows of `stride` vertices): e[v-1] + e[v-d] - e[v-d-1]
// on the same axis, with terms before vertex 0 taken as 0. Exact integer arithmetic (wrapping).
inline uint32_t spatial_prediction(const uint32_t* e, size_t v, int a, int kind, size_t d) {
  const uint32_t left = v >= 1 ? e[3 * (v - 1) + a] : 0u;
  if (kind == 1) return left;
  const uint32_t up = v >= d ? e[3 * (v - d) + a] : 0u;
  const uint32_t up_left = v >= d + 1 ? e[3 * (v - d - 1) + a] : 0u;
  return left + up - up_left;
}

// Decoder: turns spatial residuals in e[] into values, in place, in vertex order (each value
// needs its predecessors). The first d+1 vertices take the general path; the rest run branch-free.
inline void undo_spatial(uint32_t* e, size_t vertices, int kind, size_t d) {
  if (kind == 0) return;
  if (kind == 1) {
    uint32_t a0 = 0, a1 = 0, a2 = 0;
    for (size_t i = 0; i < 3 * vertices; i += 3) {
      a0 = e[i] += a0;
      a1 = e[i + 1] += a1;
      a2 = e[i + 2] += a2;
    }
    return;
  }
  const size_t head = std::min(vertices, d + 1);
  for (size_t v = 0; v < head; ++v)
    for (int a = 0; a < 3; ++a) e[3 * v + a] += spatial_prediction(e, v, a, kind, d);
  const size_t back = 3 * d;
  for (size_t i = 3 * head; i < 3 * vertices; i += 3) {
    e[i] += e[i - 3] + e[i - back] - e[i - back - 3];
    e[i + 1] += e[i - 2] + e[i + 1 - back] - e[i - back - 2];
    e[i + 2] += e[i - 1] + e[i + 2 - back] - e[i - back - 1];
  }
}

// Un-shuffles one frame's residuals from the byte planes and un-zigzags them.
template <int NB>
void gather(const uint8_t* r, size_t plane, size_t n, uint32_t* e) {
  for (size_t i = 0; i < n; ++i) e[i] = unzigzag(load<NB>(r, plane, i));
}

// Adds the temporal prediction and checks the range. Unsigned arithmetic wraps instead of
// overflowing; any value above the header's range means the data is corrupt (reachable past the
// checksums only by deliberate tampering), reported by returning false.
// kKind: 0 none, 1 delta, 2 linear.
template <int kKind>
bool add_temporal(const uint32_t* e, size_t n, uint32_t qlimit, const uint32_t* p1,
                  const uint32_t* p2, uint32_t* cur) {
  uint32_t bad = 0;
  for (size_t i = 0; i < n; ++i) {
    const uint32_t value = e[i] + (kKind == 2 ? 2 * p1[i] - p2[i] : kKind == 1 ? p1[i] : 0u);
    bad |= value > qlimit;
    cur[i] = value;
  }
  return bad == 0;
}

// Reconstructs frames [0, last] of one decompressed chunk of nf frames, writing frames
// [write_from, last] to out (out points at the slot of frame write_from; null: write nothing).
// q: the three frame buffers and one residual buffer of the scratch.
template <int NB>
bool reconstruct(const uint8_t* bytes, uint32_t nf, uint32_t last, uint32_t write_from,
                 uint8_t mode, const BlobInfo& info, std::vector<uint32_t>* q, float* out) {
  const size_t V = info.vertex_count;
  const size_t n = V * 3;
  const size_t plane = size_t(nf) * n;
  const uint32_t qlimit = std::max({info.qmax[0], info.qmax[1], info.qmax[2]});
  const int temporal = mode & kTemporalMask;
  const int spatial = (mode & kSpatialMask) >> kSpatialShift;
  const int key_spatial = (mode & kKeyMask) >> kKeyShift;
  const size_t d = info.row_stride;
  uint32_t* cur = q[0].data();
  uint32_t* p1 = q[1].data();
  uint32_t* p2 = q[2].data();
  uint32_t* e = q[3].data();
  const double step = info.step;
  const double ox = info.origin[0], oy = info.origin[1], oz = info.origin[2];
  for (uint32_t j = 0; j <= last; ++j) {
    const uint8_t* r = bytes + size_t(j) * n;
    if (j == 0) {
      gather<NB>(r, plane, n, cur);
      undo_spatial(cur, V, key_spatial, d);
      uint32_t bad = 0;
      for (size_t i = 0; i < n; i += 3)
        bad |= (cur[i] > info.qmax[0]) | (cur[i + 1] > info.qmax[1]) | (cur[i + 2] > info.qmax[2]);
      if (bad) return false;
    } else {
      gather<NB>(r, plane, n, e);
      undo_spatial(e, V, spatial, d);
      const int kind = (temporal == int(Predictor::Linear) && j < 2) ? 1 : temporal;
      const bool ok = kind == int(Predictor::Linear)  ? add_temporal<2>(e, n, qlimit, p1, p2, cur)
                      : kind == int(Predictor::Delta) ? add_temporal<1>(e, n, qlimit, p1, p2, cur)
                                                      : add_temporal<0>(e, n, qlimit, p1, p2, cur);
      if (!ok) return false;
    }
    if (out && j >= write_from) {
      float* o = out + size_t(j - write_from) * n;
      for (size_t v = 0; v < V; ++v) {
        o[3 * v] = dequantise(ox, step, cur[3 * v]);
        o[3 * v + 1] = dequantise(oy, step, cur[3 * v + 1]);
        o[3 * v + 2] = dequantise(oz, step, cur[3 * v + 2]);
      }
    }
    // Rotate: the current frame becomes the previous one.
    uint32_t* t = p2;
    p2 = p1;
    p1 = cur;
    cur = t;
  }
  return true;
}

// Picks the Lorenzo row stride from one frame of quantised values: the d in [2, 2048] whose
// prediction residuals (L1, on a sample of vertices) are smallest, or 0 if none beats the
// previous-vertex predictor.
uint32_t choose_row_stride(const uint32_t* q, uint32_t vertex_count) {
  const size_t max_d = std::min<size_t>(2048, vertex_count / 2);
  if (max_d < 2) return 0;
  const size_t sample_step = std::max<size_t>(1, vertex_count / 4096);
  auto cost = [&](int kind, size_t d) {
    uint64_t c = 0;
    for (size_t v = d + 1; v < vertex_count; v += sample_step)
      for (int a = 0; a < 3; ++a) {
        const int32_t r = int32_t(q[3 * v + a] - spatial_prediction(q, v, a, kind, d));
        c += uint64_t(r < 0 ? -int64_t(r) : r);
      }
    return c;
  };
  uint64_t best = UINT64_MAX;
  size_t best_d = 0;
  for (size_t d = 2; d <= max_d; ++d) {
    const uint64_t c = cost(2, d);
    if (c < best) {
      best = c;
      best_d = d;
    }
  }
  return best < cost(1, best_d) ? uint32_t(best_d) : 0;
}

}  // namespace

struct DecoderAccess {
  static Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
                       size_t out_floats, DecodeScratch& s, Error* err, const Basis* basis) {
    s.frames_reconstructed_ = 0;
    BlobInfo info;
    if (Status st = parse(blob, size, &info, err); st != Status::Ok) return st;
    if (info.version == kFormatVersionV2)
      return v2::decode(blob, size, first, count, out, out_floats, s, err, basis);
    if (info.version == kFormatVersionV3)
      return v3::decode(blob, size, first, count, out, out_floats, s, err, basis);
    if (count == 0) return Status::Ok;
    if (first >= info.frame_count || count > info.frame_count - first)
      return fail(err, Status::InvalidArgument, "frames %u..%u requested from a %u-frame blob",
                  first, first + count - 1, info.frame_count);
    const size_t n = size_t(info.vertex_count) * 3;
    if (out && out_floats < size_t(count) * n)
      return fail(err, Status::OutputTooSmall, "output holds %zu floats, %u frames need %zu",
                  out_floats, count, size_t(count) * n);
    s.reserve(info.vertex_count, info.key_interval);
    const uint32_t K = info.key_interval;
    const uint32_t last = first + count - 1;
    size_t offset = kHeaderSize + size_t(info.chunk_count) * kEntrySize;
    for (uint32_t c = 0; c <= last / K; ++c) {
      Chunk chunk = read_entry(blob, c);
      chunk.offset = offset;
      offset += chunk.size;
      if (c < first / K) continue;
      const uint8_t* src = blob + chunk.offset;
      const uint64_t sum = xxh64(src, chunk.size);
      if (sum != chunk.checksum)
        return fail(err, Status::ChecksumMismatch, "frame blob chunk %u checksum mismatch", c);
      const uint32_t f0 = c * K;
      const uint32_t nf = std::min(K, info.frame_count - f0);
      const size_t expected = size_t(chunk.planes) * nf * n;
      const unsigned long long declared = ZSTD_getFrameContentSize(src, chunk.size);
      if (declared != expected)
        return fail(err, Status::Corrupt,
                    "frame blob chunk %u: zstd frame declares %llu bytes, "
                    "expected %zu",
                    c, declared, expected);
      const size_t got = ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(s.dctx_), s.bytes_.data(),
                                             expected, src, chunk.size);
      if (ZSTD_isError(got))
        return fail(err, Status::Corrupt, "frame blob chunk %u: zstd: %s", c,
                    ZSTD_getErrorName(got));
      if (got != expected)
        return fail(err, Status::Corrupt, "frame blob chunk %u: %zu bytes decompressed of %zu", c,
                    got, expected);
      const uint32_t chunk_last = std::min(last, f0 + nf - 1) - f0;
      const uint32_t write_from = first > f0 ? first - f0 : 0;
      float* dst = out ? out + size_t(f0 + write_from - first) * n : nullptr;
      bool ok = false;
      switch (chunk.planes) {
        case 1:
          ok = reconstruct<1>(s.bytes_.data(), nf, chunk_last, write_from, chunk.mode, info, s.q_,
                              dst);
          break;
        case 2:
          ok = reconstruct<2>(s.bytes_.data(), nf, chunk_last, write_from, chunk.mode, info, s.q_,
                              dst);
          break;
        case 3:
          ok = reconstruct<3>(s.bytes_.data(), nf, chunk_last, write_from, chunk.mode, info, s.q_,
                              dst);
          break;
        default:
          ok = reconstruct<4>(s.bytes_.data(), nf, chunk_last, write_from, chunk.mode, info, s.q_,
                              dst);
          break;
      }
      s.frames_reconstructed_ += chunk_last + 1;
      if (!ok)
        return fail(err, Status::Corrupt,
                    "frame blob chunk %u: reconstructed values outside the blob's range", c);
    }
    return Status::Ok;
  }
};

DecodeScratch::DecodeScratch() : dctx_(ZSTD_createDCtx()) {}
DecodeScratch::~DecodeScratch() {
  ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(dctx_));
}
DecodeScratch::DecodeScratch(DecodeScratch&& other) noexcept
    : dctx_(other.dctx_),
      bytes_(std::move(other.bytes_)),
      subspace_(std::move(other.subspace_)),
      coefficients_(std::move(other.coefficients_)),
      body_(std::move(other.body_)),
      v3_ints_(std::move(other.v3_ints_)),
      v3_lanes_(std::move(other.v3_lanes_)),
      v3_key_(other.v3_key_),
      v3_segment_(other.v3_segment_),
      v3_segments_(other.v3_segments_),
      v3_valid_(other.v3_valid_),
      frames_reconstructed_(other.frames_reconstructed_) {
  other.v3_valid_ = false;
  for (int i = 0; i < 4; ++i) q_[i] = std::move(other.q_[i]);
  other.dctx_ = ZSTD_createDCtx();
}
DecodeScratch& DecodeScratch::operator=(DecodeScratch&& other) noexcept {
  if (this != &other) {
    std::swap(dctx_, other.dctx_);
    std::swap(bytes_, other.bytes_);
    for (int i = 0; i < 4; ++i) std::swap(q_[i], other.q_[i]);
    std::swap(subspace_, other.subspace_);
    std::swap(coefficients_, other.coefficients_);
    std::swap(body_, other.body_);
    std::swap(v3_ints_, other.v3_ints_);
    std::swap(v3_lanes_, other.v3_lanes_);
    std::swap(v3_key_, other.v3_key_);
    std::swap(v3_segment_, other.v3_segment_);
    std::swap(v3_segments_, other.v3_segments_);
    std::swap(v3_valid_, other.v3_valid_);
    frames_reconstructed_ = other.frames_reconstructed_;
  }
  return *this;
}

void DecodeScratch::reserve(uint32_t vertex_count, uint32_t key_interval, uint32_t modes) {
  const size_t n = size_t(vertex_count) * 3;
  // Version 2 chunks also carry 12 floats of body transform per frame.
  const size_t bytes = 4 * (n + modes + (modes > 0 ? 12 : 0)) * key_interval;
  if (bytes_.size() < bytes) bytes_.resize(bytes);
  for (auto& q : q_)
    if (q.size() < n) q.resize(n);
  if (modes > 0) {
    if (subspace_.size() < n * key_interval) subspace_.resize(n * key_interval);
    if (coefficients_.size() < size_t(modes) * key_interval)
      coefficients_.resize(size_t(modes) * key_interval);
    if (body_.size() < size_t(12) * key_interval) body_.resize(size_t(12) * key_interval);
    // Version 3: two segments of coefficients and residual as integers (decoded in one pass over
    // the basis), and eight frames of the residual side by side for the spatial pass.
    if (v3_ints_.size() < 2 * (n + modes) * key_interval)
      v3_ints_.resize(2 * (n + modes) * key_interval);
    if (v3_lanes_.size() < 8 * n) v3_lanes_.resize(8 * n);
  }
}

size_t DecodeScratch::memory_bytes() const {
  size_t bytes =
      bytes_.capacity() + 4 * (subspace_.capacity() + coefficients_.capacity() + body_.capacity() +
                               v3_ints_.capacity() + v3_lanes_.capacity());
  for (const auto& q : q_) bytes += 4 * q.capacity();
  return bytes;
}

Status read_info(const uint8_t* blob, size_t size, BlobInfo* info, Error* err) {
  return parse(blob, size, info, err);
}

Status chunk_spans(const uint8_t* blob, size_t size, std::vector<ChunkSpan>* out, Error* err) {
  out->clear();
  BlobInfo info;
  if (Status st = parse(blob, size, &info, err); st != Status::Ok) return st;
  if (info.version == kFormatVersionV3) {
    v3::spans(blob, out);
    return Status::Ok;
  }
  // Versions 1 and 2: u16 header size at byte 6, then the chunk table (u32 compressed size first in
  // each entry), then the chunks back to back; parse() has checked all of it fits.
  const size_t header = get_u16(blob + 6);
  size_t offset = header + kEntrySize * size_t(info.chunk_count);
  for (uint32_t k = 0; k < info.chunk_count; ++k) {
    const uint32_t csize = get_u32(blob + header + kEntrySize * size_t(k));
    out->push_back({offset, csize});
    offset += csize;
  }
  return Status::Ok;
}

std::string version_is_sql(const std::string& column, uint32_t version) {
  // The u16 version at byte 4, little-endian: its low byte (versions stay below 256).
  char hex[3];
  std::snprintf(hex, sizeof hex, "%02x", version & 0xffu);
  return "substr(" + column + ", 5, 1) = x'" + hex + "'";
}

Status decode_frames(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
                     size_t out_floats, DecodeScratch& scratch, Error* err, const Basis* basis) {
  if (out == nullptr && count > 0)
    return fail(err, Status::InvalidArgument, "decode_frames: null output buffer");
  return DecoderAccess::decode(blob, size, first, count, out, out_floats, scratch, err, basis);
}

Status decode_all(const uint8_t* blob, size_t size, std::vector<float>& out, DecodeScratch& scratch,
                  Error* err, const Basis* basis) {
  BlobInfo info;
  if (Status st = parse(blob, size, &info, err); st != Status::Ok) return st;
  out.resize(size_t(info.frame_count) * info.vertex_count * 3);
  return DecoderAccess::decode(blob, size, 0, info.frame_count, out.data(), out.size(), scratch,
                               err, basis);
}

Status verify(const uint8_t* blob, size_t size, DecodeScratch& scratch, Error* err,
              const Basis* basis) {
  BlobInfo info;
  if (Status st = parse(blob, size, &info, err); st != Status::Ok) return st;
  return DecoderAccess::decode(blob, size, 0, info.frame_count, nullptr, 0, scratch, err, basis);
}

uint64_t decode_cost(const BlobInfo& info, uint32_t first, uint32_t count) {
  if (count == 0 || info.key_interval == 0) return 0;
  const uint64_t key = uint64_t(first / info.key_interval) * info.key_interval;
  return uint64_t(first) + count - key;
}

namespace {

[[noreturn]] void invalid(const std::string& what) {
  throw ClothdbError(Status::InvalidArgument, "encode: " + what);
}

// Validated settings and the per-axis value range, shared by the grid attempts.
struct Prepared {
  uint32_t K = 0;
  double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
};

Prepared prepare_encode(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                        const EncodeSettings& settings) {
  if (frames == nullptr || frame_count == 0 || vertex_count == 0)
    invalid("no frames (" + std::to_string(frame_count) + " frames of " +
            std::to_string(vertex_count) + " vertices)");
  if (vertex_count > kMaxVertices)
    invalid(std::to_string(vertex_count) + " vertices, at most " + std::to_string(kMaxVertices));
  if (!(settings.bound > 0 && settings.bound <= kMaxBound))
    invalid("error bound must be in (0, 1e9], got " + std::to_string(settings.bound));
  if (settings.zstd_level < ZSTD_minCLevel() || settings.zstd_level > ZSTD_maxCLevel())
    invalid("zstd level " + std::to_string(settings.zstd_level) + " outside " +
            std::to_string(ZSTD_minCLevel()) + ".." + std::to_string(ZSTD_maxCLevel()));
  if (settings.predictor != Predictor::Auto && settings.predictor != Predictor::Delta &&
      settings.predictor != Predictor::Linear && settings.predictor != Predictor::None)
    invalid("unknown predictor");
  if (settings.spatial != SpatialMode::Auto && settings.spatial != SpatialMode::Off &&
      settings.spatial != SpatialMode::On)
    invalid("unknown spatial mode");
  if (settings.grid != GridMode::Auto && settings.grid != GridMode::Plain &&
      settings.grid != GridMode::Fine)
    invalid("unknown grid mode");
  const uint32_t K =
      settings.key_interval == 0 ? frame_count : std::min(settings.key_interval, frame_count);
  if (uint64_t(K) * vertex_count * 3 > kMaxChunkFloats)
    invalid("key interval " + std::to_string(K) + " x " + std::to_string(vertex_count) +
            " vertices exceeds the chunk limit");

  Prepared p;
  p.K = K;
  const size_t n = size_t(vertex_count) * 3;
  const size_t total = size_t(frame_count) * n;
  double* lo = p.lo;
  double* hi = p.hi;
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = double(frames[a]);
  for (size_t i = 0; i < total; ++i) {
    const double x = frames[i];
    if (!(std::fabs(x) <= kMaxCoordinate))
      invalid("coordinate " + std::to_string(i % 3) + " of vertex " + std::to_string((i % n) / 3) +
              " in frame " + std::to_string(i / n) + " is not finite or beyond 1e30");
    lo[i % 3] = std::min(lo[i % 3], x);
    hi[i % 3] = std::max(hi[i % 3], x);
  }
  return p;
}

// Encodes on a grid of step just under 2 * bound / divisions (1 or 2).
std::vector<uint8_t> encode_grid(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                                 const EncodeSettings& settings, const Prepared& p, int divisions,
                                 double* step_out, int* retries_out) {
  const uint32_t K = p.K;
  const double* lo = p.lo;
  const double* hi = p.hi;
  // Quantise. A step of exactly 2*bound/divisions would put the rounding error right at the
  // bound, where the final float rounding of origin + q*step can push it over; start slightly
  // below and shrink further if any coordinate still misses (only when the bound nears float
  // precision). Besides the nearest grid value, record whether its neighbours are within the
  // bound too: the residual stage may pick whichever valid value its prediction is closest to.
  const size_t n = size_t(vertex_count) * 3;
  const size_t total = size_t(frame_count) * n;
  std::vector<uint32_t> q(total);
  std::vector<uint8_t> room(total);  // bit 0: q-1 is within the bound, bit 1: q+1 is
  double step = 2 * settings.bound * (1.0 - 1.0 / 1024) / divisions;
  uint32_t qmax[3] = {0, 0, 0};
  int retries = 0;
  for (;; ++retries) {
    if (retries > 40)
      invalid("error bound " + std::to_string(settings.bound) +
              " is below the float precision of coordinates up to " +
              std::to_string(std::max({std::fabs(lo[0]), std::fabs(hi[0]), std::fabs(lo[1]),
                                       std::fabs(hi[1]), std::fabs(lo[2]), std::fabs(hi[2])})));
    for (int a = 0; a < 3; ++a) {
      const double steps = std::ceil((hi[a] - lo[a]) / step);
      if (steps > double(kMaxQ))
        invalid("coordinate range " + std::to_string(hi[a] - lo[a]) + " on axis " +
                std::to_string(a) + " needs more than 2^28 steps of " + std::to_string(step));
      qmax[a] = uint32_t(steps);
    }
    bool ok = true;
    for (size_t i = 0; i < total && ok; ++i) {
      const int a = int(i % 3);
      const double x = frames[i];
      const double t = std::nearbyint((x - lo[a]) / step);
      const uint32_t qi = uint32_t(std::clamp(t, 0.0, double(qmax[a])));
      auto within = [&](uint32_t c) {
        return std::fabs(double(dequantise(lo[a], step, c)) - x) <= settings.bound;
      };
      ok = within(qi);
      q[i] = qi;
      room[i] = uint8_t((qi > 0 && within(qi - 1)) | (qi < qmax[a] && within(qi + 1)) << 1);
    }
    if (ok) break;
    step *= 0.75;
  }
  if (retries_out) *retries_out = retries;

  // Row stride for the Lorenzo predictor: the vertex offset d that makes frame 0 smoothest
  // under it (meshes generated or modelled in rows have one; for others it loses to the
  // previous-vertex predictor, chosen per chunk below, and costs nothing).
  const uint32_t stride = choose_row_stride(q.data(), vertex_count);

  // Residuals per chunk, zigzagged, shuffled into byte planes, compressed.
  const uint32_t chunk_count = (frame_count + K - 1) / K;
  std::vector<uint8_t> header(kHeaderSize + size_t(chunk_count) * kEntrySize, 0);
  std::vector<uint8_t> body;
  std::vector<uint32_t> zz(size_t(K) * n);
  std::vector<uint32_t> e(n);
  std::vector<uint32_t> chosen(size_t(K) * n);
  std::vector<uint32_t> best_zz(size_t(K) * n);
  std::vector<uint8_t> planes(4 * size_t(K) * n);
  std::vector<uint8_t> compressed;
  ZSTD_CCtx* cctx = ZSTD_createCCtx();
  if (!cctx) throw ClothdbError(Status::IoError, "encode: cannot create a zstd context");
  try {
    for (uint32_t c = 0; c < chunk_count; ++c) {
      const uint32_t f0 = c * K;
      const uint32_t nf = std::min(K, frame_count - f0);
      const uint32_t* qc = q.data() + size_t(f0) * n;
      // Residuals of chunk frame j into z, choosing the frame's values into `chosen` (nf * n):
      // temporal prediction from the chosen previous frames (none for the key frame, delta for
      // frame 1, delta, linear or none after), plus spatial prediction from the chosen residuals of
      // the previous vertices. Each value is the valid grid value nearest that prediction, so the
      // residual is often 0 where the nearest value would not be; the decoder needs no change.
      auto residuals = [&](uint32_t j, int temporal, int spatial, uint32_t* z) {
        const uint32_t* nearest = qc + size_t(j) * n;
        const uint8_t* r = room.data() + (size_t(f0) + j) * n;
        uint32_t* cq = chosen.data() + size_t(j) * n;
        const uint32_t* c1 = j >= 1 ? cq - n : nullptr;
        const uint32_t* c2 = j >= 2 ? cq - 2 * n : nullptr;
        for (size_t v = 0; v < vertex_count; ++v) {
          for (int a = 0; a < 3; ++a) {
            const size_t i = 3 * v + a;
            const uint32_t tp = (j == 0 || temporal == int(Predictor::None))     ? 0u
                                : (j >= 2 && temporal == int(Predictor::Linear)) ? 2 * c1[i] - c2[i]
                                                                                 : c1[i];
            const uint32_t pred =
                tp + (spatial ? spatial_prediction(e.data(), v, a, spatial, stride) : 0u);
            uint32_t c = nearest[i];
            const int32_t off = int32_t(pred - c);
            if (off < 0 && (r[i] & 1)) c -= 1;
            if (off > 0 && (r[i] & 2)) c += 1;
            cq[i] = c;
            e[i] = c - tp;
            z[i] = zigzag(c - pred);
          }
        }
      };
      auto bits = [&](const uint32_t* z) {
        uint64_t b = 0;
        for (size_t i = 0; i < n; ++i) b += std::bit_width(z[i]);
        return b;
      };
      const int max_spatial = stride ? 2 : 1;
      // Key frame: the cheaper spatial predictor.
      int key_spatial = 1;
      residuals(0, false, 1, zz.data());
      if (stride) {
        const uint64_t b1 = bits(zz.data());
        residuals(0, false, 2, zz.data());
        if (bits(zz.data()) < b1)
          key_spatial = 2;
        else
          residuals(0, false, 1, zz.data());
      }
      // Other frames: the combination whose residuals need the fewest bits (a cheap proxy for
      // zstd's output size). best_zz keeps the winner's residuals (frame 0 is shared).
      int best_temporal =
          settings.predictor == Predictor::Auto ? int(Predictor::Delta) : int(settings.predictor);
      int best_spatial = settings.spatial == SpatialMode::On ? max_spatial : 0;
      std::copy(zz.begin(), zz.begin() + std::ptrdiff_t(n), best_zz.begin());
      if (nf > 1) {
        uint64_t best_bits = UINT64_MAX;
        for (int temporal = 1; temporal <= 3; ++temporal) {
          if (settings.predictor != Predictor::Auto && temporal != int(settings.predictor))
            continue;
          if (temporal == int(Predictor::Linear) && nf < 3 && settings.predictor == Predictor::Auto)
            continue;
          for (int spatial = 0; spatial <= max_spatial; ++spatial) {
            if (settings.spatial == SpatialMode::Off && spatial != 0) continue;
            if (settings.spatial == SpatialMode::On && spatial == 0) continue;
            uint64_t b = 0;
            for (uint32_t j = 1; j < nf; ++j) {
              uint32_t* z = zz.data() + size_t(j) * n;
              residuals(j, temporal, spatial, z);
              b += bits(z);
            }
            if (b < best_bits) {
              best_bits = b;
              best_temporal = temporal;
              best_spatial = spatial;
              std::copy(zz.begin() + std::ptrdiff_t(n), zz.begin() + std::ptrdiff_t(nf * n),
                        best_zz.begin() + std::ptrdiff_t(n));
            }
          }
        }
      }
      zz.swap(best_zz);
      const uint8_t mode = uint8_t(best_temporal) | uint8_t(best_spatial << kSpatialShift) |
                           uint8_t(key_spatial << kKeyShift);
      const size_t count = size_t(nf) * n;
      uint32_t all = 0;
      for (size_t i = 0; i < count; ++i) all |= zz[i];
      const int nplanes = std::max(1, (int(std::bit_width(all)) + 7) / 8);
      for (int b = 0; b < nplanes; ++b) {
        uint8_t* p = planes.data() + size_t(b) * count;
        for (size_t i = 0; i < count; ++i) p[i] = uint8_t(zz[i] >> (8 * b));
      }
      const size_t raw = size_t(nplanes) * count;
      compressed.resize(ZSTD_compressBound(raw));
      const size_t csize = ZSTD_compressCCtx(cctx, compressed.data(), compressed.size(),
                                             planes.data(), raw, settings.zstd_level);
      if (ZSTD_isError(csize))
        throw ClothdbError(Status::IoError,
                           std::string("encode: zstd failed: ") + ZSTD_getErrorName(csize));
      if (csize > UINT32_MAX) invalid("chunk too large");
      uint8_t* e = header.data() + kHeaderSize + size_t(c) * kEntrySize;
      put_u32(e, uint32_t(csize));
      e[4] = uint8_t(nplanes);
      e[5] = mode;
      put_u64(e + 8, xxh64(compressed.data(), csize));
      body.insert(body.end(), compressed.begin(), compressed.begin() + csize);
    }
  } catch (...) {
    ZSTD_freeCCtx(cctx);
    throw;
  }
  ZSTD_freeCCtx(cctx);

  uint8_t* h = header.data();
  std::memcpy(h, kMagic, 4);
  put_u16(h + 4, uint16_t(kFormatVersion));
  put_u16(h + 6, uint16_t(kHeaderSize));
  put_u32(h + 8, vertex_count);
  put_u32(h + 12, frame_count);
  put_u32(h + 16, K);
  put_u32(h + 20, chunk_count);
  put_f64(h + 24, settings.bound);
  put_f64(h + 32, step);
  for (int a = 0; a < 3; ++a) {
    put_f64(h + 40 + 8 * a, lo[a]);
    put_u32(h + 64 + 4 * a, qmax[a]);
  }
  put_u32(h + 76, stride);
  put_u64(h + kChecksumOffset, header_checksum(h, kHeaderSize, kChecksumOffset, chunk_count));
  std::vector<uint8_t> blob = std::move(header);
  blob.insert(blob.end(), body.begin(), body.end());
  if (step_out) *step_out = step;
  return blob;
}

}  // namespace

std::vector<uint8_t> encode(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                            const EncodeSettings& settings, EncodeStats* stats) {
  const Prepared p = prepare_encode(frames, frame_count, vertex_count, settings);
  const size_t total = size_t(frame_count) * vertex_count * 3;
  // The finer grid wins where motion is predictable (values hug their prediction), the plain
  // one where it is noisy; with Auto both are tried and the smaller blob kept.
  double step = 0;
  int retries = 0;
  std::vector<uint8_t> blob;
  for (int divisions : {1, 2}) {
    if (settings.grid != GridMode::Auto && divisions != int(settings.grid)) continue;
    double s = 0;
    int r = 0;
    std::vector<uint8_t> candidate =
        encode_grid(frames, frame_count, vertex_count, settings, p, divisions, &s, &r);
    if (blob.empty() || candidate.size() < blob.size()) {
      blob = std::move(candidate);
      step = s;
      retries = r;
    }
  }
  double max_error = settings.bound;

  if (settings.verify) {
    DecodeScratch scratch;
    std::vector<float> decoded;
    Error err;
    if (decode_all(blob.data(), blob.size(), decoded, scratch, &err) != Status::Ok)
      throw ClothdbError(Status::Corrupt,
                         std::string("encode: the new blob does not decode: ") + err.message);
    max_error = 0;
    for (size_t i = 0; i < total; ++i) {
      const double e = std::fabs(double(decoded[i]) - double(frames[i]));
      if (!(e <= settings.bound))
        throw ClothdbError(Status::Corrupt, "encode: decoded coordinate " + std::to_string(i) +
                                                " misses the error bound; the codec is broken");
      max_error = std::max(max_error, e);
    }
  }
  if (stats) {
    stats->max_error = max_error;
    stats->step = step;
    stats->step_retries = retries;
    stats->raw_bytes = total * sizeof(float);
    stats->encoded_bytes = blob.size();
  }
  return blob;
}

namespace detail {
void reseal(uint8_t* blob, size_t size) {
  if (size < 6 || std::memcmp(blob, kMagic, 4) != 0) return;
  if (get_u16(blob + 4) == kFormatVersionV3) return v3::reseal(blob, size);
  if (size < kHeaderSize) return;
  if (get_u16(blob + 4) == kFormatVersionV2) return v2::reseal(blob, size);
  const uint32_t chunk_count = get_u32(blob + 20);
  const uint64_t table_end = kHeaderSize + uint64_t(chunk_count) * kEntrySize;
  if (size < table_end) return;
  uint64_t offset = table_end;
  for (uint32_t c = 0; c < chunk_count; ++c) {
    uint8_t* e = blob + kHeaderSize + size_t(c) * kEntrySize;
    const uint32_t csize = get_u32(e);
    if (offset + csize > size) break;
    put_u64(e + 8, xxh64(blob + offset, csize));
    offset += csize;
  }
  put_u64(blob + kChecksumOffset, header_checksum(blob, kHeaderSize, kChecksumOffset, chunk_count));
}
}  // namespace detail

}  // namespace clothdb::codec
