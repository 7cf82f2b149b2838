// Frame codec version 2 (docs/DATABASE.md, "version 2"): every frame is predicted from a
// per-garment subspace (Kim et al. 2013 keep a garment's shapes in a few hundred modes), and what
// the subspace misses is coded on version 1's grid, so the hard per-coordinate bound holds exactly
// as in version 1.
//
// Per frame f of a chunk:
//  1. Coefficients c[f] (M integers, coefficient = c * coefficient_step) are predicted in time:
//     the key frame's as they are, the others by delta or linear extrapolation (chosen per chunk).
//  2. The subspace prediction S = mean + sum_k (c_k * coefficient_step) * modes[k] is evaluated
//     in float32 in a fixed order (mode 0 first), every operation correctly rounded and none fused
//     (-ffp-contract=off), so every IEEE-754 build computes the same S bit for bit; it is put on
//     the blob's grid: p = clamp(floor((S - origin) / step + 0.5), 0, qmax).
//  3. The value q of each coordinate is p (plus, in "carry" chunks, the previous frame's
//     correction q - p: what the subspace misses persists from frame to frame) plus a residual.
//     Each input coordinate has an interval of grid values within the bound; the encoder takes the
//     one nearest that prediction, so a coordinate the subspace already places within the bound
//     costs a zero residual.
//  4. Coefficient and residual streams are zigzagged, split into byte planes and compressed with
//     zstd per chunk, with XXH64 checksums over the header and table and over each chunk.
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include "database/codec/bytes.hpp"
#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"

namespace clothdb::codec {

using namespace bytes;

namespace {

// Byte layout (little-endian), docs/DATABASE.md "Frame blob format (version 2)":
//   0 magic "CLDF" | 4 u16 version 2 | 6 u16 header size (112) | 8 u32 vertices | 12 u32 frames
//  16 u32 key interval | 20 u32 chunks | 24 f64 bound | 32 f64 step | 40 f64 origin[3]
//  64 u32 qmax[3] | 76 u32 modes used | 80 i64 basis id | 88 f64 coefficient step | 96 u8 flags
//  (bit 0: the basis mean is added) | 97 7 bytes 0 | 104 u64 XXH64 of bytes 0..103 and the table
// 112 chunk table: per chunk u32 compressed size, u8 residual byte planes (1..4), u8 mode (bit 0
//     carry, bit 1 linear coefficients), u8 coefficient byte planes (1..4; 0 without modes), u8 0,
//     u64 XXH64 of the compressed bytes | the compressed chunks back to back. A chunk decompresses
//     to the coefficient planes (planes x frames x M bytes) then the residual planes.
constexpr size_t kHeaderSize = 112;
constexpr size_t kChecksumOffset = 104;
constexpr size_t kEntrySize = bytes::kChunkEntrySize;
constexpr uint32_t kMaxQ = (1u << 28) - 1;
constexpr int32_t kMaxCoefficient = (1 << 28) - 1;
constexpr double kMaxCoordinate = 1e30;
constexpr double kMaxBound = 1e9;
constexpr uint8_t kCarry = 1;    // the previous frame's correction predicts this one's
constexpr uint8_t kLinear = 2;   // coefficients extrapolated linearly (else delta)
constexpr uint8_t kSpatial = 4;  // what is left is predicted again from the previous vertex
constexpr uint8_t kFlagMean = 1;
constexpr uint8_t kFlagBody = 2;    // each chunk starts with its frames' body transforms
constexpr size_t kBodyFloats = 12;  // R row by row, then t
// A stored rotation entry beyond this (or a translation beyond kMaxCoordinate) is corrupt.
constexpr float kMaxRotationEntry = 1.01f;

constexpr uint8_t kBasisMagic[4] = {'C', 'L', 'B', 'S'};
constexpr size_t kBasisHeader = 24;

[[noreturn]] void invalid(const std::string& what) {
  throw ClothdbError(Status::InvalidArgument, "encode_v2: " + what);
}

// Step 2 above, shared by the encoder and the decoder: the subspace predictions of frames
// [0, frames) of a chunk (coefficients c, frame-major; predictions s, frame-major) in float32.
// Each element sees the same sequence of roundings (the mean, then mode 0, 1, ...) however the
// loops are blocked or vectorised; blocks of coordinates keep the frames' predictions in cache
// while each mode block is read once for all of them.
// Built for AVX2 as well as the x86-64 baseline, picked at load time (as the runtime's
// playback kernels): the mode loop is a multiply and an add per coordinate, which AVX2 does twice
// as wide. Without FMA (and with -ffp-contract=off) both versions round every operation alike,
// so the predictions are bit-identical whichever runs.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define CLOTHDB_MULTIVERSION __attribute__((target_clones("avx2", "default")))
#else
#define CLOTHDB_MULTIVERSION
#endif
CLOTHDB_MULTIVERSION
void predict(const Basis& basis, uint32_t modes, bool use_mean, const int32_t* c, uint32_t frames,
             double coefficient_step, float* s, size_t n) {
  constexpr size_t kBlock = 1024;
  for (size_t b0 = 0; b0 < n; b0 += kBlock) {
    const size_t b1 = std::min(n, b0 + kBlock);
    for (uint32_t j = 0; j < frames; ++j) {
      float* sj = s + size_t(j) * n;
      if (use_mean)
        std::memcpy(sj + b0, basis.mean.data() + b0, (b1 - b0) * sizeof(float));
      else
        std::fill(sj + b0, sj + b1, 0.0f);
    }
    for (uint32_t k = 0; k < modes; ++k) {
      const float* u = basis.modes.data() + size_t(k) * n;
      for (uint32_t j = 0; j < frames; ++j) {
        const float w = float(double(c[size_t(j) * modes + k]) * coefficient_step);
        if (w == 0.0f) continue;  // adds +-0: skipping it changes no value's grid point
        float* sj = s + size_t(j) * n;
        for (size_t i = b0; i < b1; ++i) sj[i] += w * u[i];
      }
    }
  }
}

// Cloth relative to the body: s = R s + t for one frame (T: R row by row, then t), in float32 with
// one fixed order of correctly rounded operations (no fusing), shared by the encoder and decoder.
void to_world(const float* T, float* s, size_t n) {
  for (size_t i = 0; i < n; i += 3) {
    const float x = s[i], y = s[i + 1], z = s[i + 2];
    s[i] = ((T[0] * x + T[1] * y) + T[2] * z) + T[9];
    s[i + 1] = ((T[3] * x + T[4] * y) + T[5] * z) + T[10];
    s[i + 2] = ((T[6] * x + T[7] * y) + T[8] * z) + T[11];
  }
}

// The prediction on the grid. NaN or infinite predictions (only from tampered blobs) clamp too.
void to_grid(const float* s, size_t n, const double origin[3], double step, const uint32_t qmax[3],
             uint32_t* p) {
  const double inv = 1.0 / step;
  for (size_t i = 0; i < n; i += 3)
    for (int a = 0; a < 3; ++a) {
      double t = (double(s[i + a]) - origin[a]) * inv + 0.5;
      t = t > 0 ? t : 0.0;
      t = t < double(qmax[a]) ? t : double(qmax[a]);
      p[i + a] = uint32_t(int32_t(t));
    }
}

Status parse_impl(const uint8_t* blob, size_t size, BlobInfo* info, Error* err) {
  BlobInfo in;
  if (Status st = parse_common_header(blob, size, kHeaderSize, kChecksumOffset, &in, err);
      st != Status::Ok)
    return st;
  const uint32_t chunk_count = in.chunk_count;
  in.version = kFormatVersionV2;
  in.modes = get_u32(blob + 76);
  in.basis_id = int64_t(get_u64(blob + 80));
  in.coefficient_step = get_f64(blob + 88);
  const uint8_t flags = blob[96];
  in.uses_mean = (flags & kFlagMean) != 0;
  in.body_frame = (flags & kFlagBody) != 0;
  if (get_u16(blob + 6) != kHeaderSize)
    return fail(err, Status::Corrupt, "frame blob header: unknown header size %u",
                get_u16(blob + 6));
  bool reserved_zero = (flags & ~(kFlagMean | kFlagBody)) == 0;
  for (size_t i = 97; i < kChecksumOffset; ++i) reserved_zero = reserved_zero && blob[i] == 0;
  if (!reserved_zero) return fail(err, Status::Corrupt, "frame blob header: reserved bytes set");
  if (in.vertex_count == 0 || in.vertex_count > kMaxVertices)
    return fail(err, Status::Corrupt, "frame blob header: vertex count %u outside 1..%u",
                in.vertex_count, kMaxVertices);
  if (in.frame_count == 0 || in.key_interval == 0 || in.key_interval > in.frame_count)
    return fail(err, Status::Corrupt, "frame blob header: %u frames with key interval %u",
                in.frame_count, in.key_interval);
  if (in.modes > kMaxBasisModes)
    return fail(err, Status::Corrupt, "frame blob header: %u modes, at most %u", in.modes,
                kMaxBasisModes);
  if (uint64_t(in.key_interval) * (uint64_t(in.vertex_count) * 3 + in.modes) > kMaxChunkFloats)
    return fail(err, Status::Corrupt, "frame blob header: chunk of %u frames x %u vertices too big",
                in.key_interval, in.vertex_count);
  if (chunk_count != (uint64_t(in.frame_count) + in.key_interval - 1) / in.key_interval)
    return fail(err, Status::Corrupt, "frame blob header: %u chunks for %u frames with K=%u",
                chunk_count, in.frame_count, in.key_interval);
  if (!(in.bound > 0 && in.bound <= kMaxBound && std::isfinite(in.step) && in.step > 0 &&
        in.step <= 2 * in.bound))
    return fail(err, Status::Corrupt, "frame blob header: bound %g and step %g are inconsistent",
                in.bound, in.step);
  if (in.basis_id <= 0)
    return fail(err, Status::Corrupt, "frame blob header: basis id %lld is invalid",
                (long long)in.basis_id);
  if (in.body_frame && !in.uses_mean)
    return fail(err, Status::Corrupt, "frame blob header: a body frame without the basis mean");
  if (!(in.coefficient_step > 0 && in.coefficient_step * kMaxCoefficient <= kMaxCoordinate))
    return fail(err, Status::Corrupt, "frame blob header: coefficient step %g is invalid",
                in.coefficient_step);
  for (int a = 0; a < 3; ++a) {
    if (!(std::fabs(in.origin[a]) <= kMaxCoordinate) || in.qmax[a] > kMaxQ ||
        !(std::fabs(in.origin[a] + in.qmax[a] * in.step) <= kMaxCoordinate))
      return fail(err, Status::Corrupt, "frame blob header: axis %d origin %g / range %u invalid",
                  a, in.origin[a], in.qmax[a]);
  }
  uint64_t total = kHeaderSize + uint64_t(chunk_count) * kEntrySize;  // the chunk table's end
  for (uint32_t c = 0; c < chunk_count; ++c) {
    const uint8_t* e = blob + kHeaderSize + size_t(c) * kEntrySize;
    const uint32_t csize = get_u32(e);
    const bool coefficient_planes_ok = in.modes == 0 ? e[6] == 0 : (e[6] >= 1 && e[6] <= 4);
    if (csize == 0 || e[4] < 1 || e[4] > 4 || e[5] > (kCarry | kLinear | kSpatial) ||
        !coefficient_planes_ok || e[7] != 0)
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

uint32_t load_any(const uint8_t* p, size_t plane, size_t i, int nb) {
  uint32_t u = 0;
  for (int b = 0; b < nb; ++b) u |= uint32_t(p[size_t(b) * plane + i]) << (8 * b);
  return u;
}

// The residual layer of one frame: the correction d = q - p of each coordinate is predicted by
// the previous frame's (carry) plus, with spatial, the previous vertex's change e = d - (carry
// part) on the same axis; q = p + d, range-checked. corr holds d of the previous frame on entry
// and of this one on return (each element reads its own old value first).
template <int NB, bool kCarryOn, bool kSpatialOn>
bool add_residuals(const uint8_t* r, size_t plane, size_t n, const uint32_t qmax[3],
                   const uint32_t* p, uint32_t* corr, uint32_t* q) {
  uint32_t bad = 0;
  uint32_t last[3] = {0, 0, 0};
  for (size_t i = 0; i < n; i += 3)
    for (int a = 0; a < 3; ++a) {
      const size_t k = i + a;
      uint32_t e = unzigzag(load<NB>(r, plane, k));
      if constexpr (kSpatialOn) {
        e += last[a];
        last[a] = e;
      }
      const uint32_t d = kCarryOn ? corr[k] + e : e;
      const uint32_t value = p[k] + d;
      bad |= value > qmax[a];
      q[k] = value;
      corr[k] = d;
    }
  return bad == 0;
}

template <bool kCarryOn, bool kSpatialOn>
bool add_residuals_planes(int nb, const uint8_t* r, size_t plane, size_t n, const uint32_t qmax[3],
                          const uint32_t* p, uint32_t* corr, uint32_t* q) {
  switch (nb) {
    case 1:
      return add_residuals<1, kCarryOn, kSpatialOn>(r, plane, n, qmax, p, corr, q);
    case 2:
      return add_residuals<2, kCarryOn, kSpatialOn>(r, plane, n, qmax, p, corr, q);
    case 3:
      return add_residuals<3, kCarryOn, kSpatialOn>(r, plane, n, qmax, p, corr, q);
    default:
      return add_residuals<4, kCarryOn, kSpatialOn>(r, plane, n, qmax, p, corr, q);
  }
}

bool add_residuals_mode(uint8_t mode, int nb, const uint8_t* r, size_t plane, size_t n,
                        const uint32_t qmax[3], const uint32_t* p, uint32_t* corr, uint32_t* q) {
  const bool carry = (mode & kCarry) != 0, spatial = (mode & kSpatial) != 0;
  if (carry && spatial) return add_residuals_planes<true, true>(nb, r, plane, n, qmax, p, corr, q);
  if (carry) return add_residuals_planes<true, false>(nb, r, plane, n, qmax, p, corr, q);
  if (spatial) return add_residuals_planes<false, true>(nb, r, plane, n, qmax, p, corr, q);
  return add_residuals_planes<false, false>(nb, r, plane, n, qmax, p, corr, q);
}

}  // namespace

struct DecoderV2Access {
  static Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
                       size_t out_floats, DecodeScratch& s, Error* err, const Basis* basis) {
    s.frames_reconstructed_ = 0;
    BlobInfo info;
    if (Status st = parse_impl(blob, size, &info, err); st != Status::Ok) return st;
    if (basis == nullptr)
      return fail(err, Status::NotFound,
                  "frame blob (codec version 2) needs basis %lld, and none was given",
                  (long long)info.basis_id);
    if (basis->id != info.basis_id)
      return fail(err, Status::NotFound, "frame blob needs basis %lld, the decoder has basis %lld",
                  (long long)info.basis_id, (long long)basis->id);
    const size_t n = size_t(info.vertex_count) * 3;
    if (basis->vertex_count != info.vertex_count || info.modes > basis->mode_count ||
        basis->mean.size() != n || basis->modes.size() < size_t(info.modes) * n)
      return fail(err, Status::Corrupt,
                  "frame blob of %u vertices and %u modes does not fit basis %lld (%u vertices, "
                  "%u modes)",
                  info.vertex_count, info.modes, (long long)basis->id, basis->vertex_count,
                  basis->mode_count);
    if (count == 0) return Status::Ok;
    if (first >= info.frame_count || count > info.frame_count - first)
      return fail(err, Status::InvalidArgument, "frames %u..%u requested from a %u-frame blob",
                  first, first + count - 1, info.frame_count);
    if (out && out_floats < size_t(count) * n)
      return fail(err, Status::OutputTooSmall, "output holds %zu floats, %u frames need %zu",
                  out_floats, count, size_t(count) * n);
    const uint32_t M = info.modes;
    s.reserve(info.vertex_count, info.key_interval, std::max(M, 1u));
    const uint32_t K = info.key_interval;
    const uint32_t last = first + count - 1;
    size_t offset = kHeaderSize + size_t(info.chunk_count) * kEntrySize;
    int32_t* coef = s.coefficients_.data();  // K x M, frame-major
    uint32_t* q = s.q_[0].data();
    uint32_t* corr = s.q_[1].data();
    uint32_t* p = s.q_[2].data();
    float* sub = s.subspace_.data();  // K x 3V
    for (uint32_t c = 0; c <= last / K; ++c) {
      const uint8_t* e = blob + kHeaderSize + size_t(c) * kEntrySize;
      const uint32_t csize = get_u32(e);
      const int rplanes = e[4], cplanes = e[6];
      const uint8_t mode = e[5];
      const uint64_t sum_stored = get_u64(e + 8);
      const uint8_t* src = blob + offset;
      offset += csize;
      if (c < first / K) continue;
      if (xxh64(src, csize) != sum_stored)
        return fail(err, Status::ChecksumMismatch, "frame blob chunk %u checksum mismatch", c);
      const uint32_t f0 = c * K;
      const uint32_t nf = std::min(K, info.frame_count - f0);
      const size_t tbytes = info.body_frame ? size_t(nf) * kBodyFloats * 4 : 0;
      const size_t cbytes = size_t(cplanes) * nf * M;
      const size_t expected = tbytes + cbytes + size_t(rplanes) * nf * n;
      const unsigned long long declared = ZSTD_getFrameContentSize(src, csize);
      if (declared != expected)
        return fail(err, Status::Corrupt,
                    "frame blob chunk %u: zstd frame declares %llu bytes, expected %zu", c,
                    declared, expected);
      const size_t got = ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(s.dctx_), s.bytes_.data(),
                                             expected, src, csize);
      if (ZSTD_isError(got))
        return fail(err, Status::Corrupt, "frame blob chunk %u: zstd: %s", c,
                    ZSTD_getErrorName(got));
      if (got != expected)
        return fail(err, Status::Corrupt, "frame blob chunk %u: %zu bytes decompressed of %zu", c,
                    got, expected);
      const uint8_t* tb = s.bytes_.data();
      const uint8_t* cb = tb + tbytes;
      const uint8_t* rb = cb + cbytes;
      float* body = s.body_.data();  // this chunk's transforms, checked before use
      if (info.body_frame)
        for (size_t i = 0; i < size_t(nf) * kBodyFloats; ++i) {
          body[i] = get_f32(tb + 4 * i);
          const bool rotation = i % kBodyFloats < 9;
          if (!(std::fabs(body[i]) <= (rotation ? kMaxRotationEntry : float(kMaxCoordinate))))
            return fail(err, Status::Corrupt, "frame blob chunk %u: body transform out of range",
                        c);
        }
      const size_t cplane = size_t(nf) * M, rplane = size_t(nf) * n;
      const uint32_t chunk_last = std::min(last, f0 + nf - 1) - f0;
      const uint32_t write_from = first > f0 ? first - f0 : 0;
      // Frames before the first requested one are needed only for their corrections (carry).
      const uint32_t from = (mode & kCarry) ? 0 : write_from;
      // Coefficients of frames 0..chunk_last: temporal prediction in wrapping unsigned
      // arithmetic, then range-checked.
      for (uint32_t j = 0; j <= chunk_last; ++j)
        for (uint32_t k = 0; k < M; ++k) {
          const size_t i = size_t(j) * M + k;
          const uint32_t r = unzigzag(load_any(cb, cplane, i, cplanes));
          const uint32_t pred = j == 0 ? 0u
                                : (j >= 2 && (mode & kLinear) != 0)
                                    ? 2 * uint32_t(coef[i - M]) - uint32_t(coef[i - 2 * M])
                                    : uint32_t(coef[i - M]);
          const int32_t v = int32_t(pred + r);
          if (v > kMaxCoefficient || v < -kMaxCoefficient)
            return fail(err, Status::Corrupt, "frame blob chunk %u: coefficient out of range", c);
          coef[i] = v;
        }
      predict(*basis, M, info.uses_mean, coef + size_t(from) * M, chunk_last + 1 - from,
              info.coefficient_step, sub, n);
      std::fill(corr, corr + n, 0u);
      for (uint32_t j = from; j <= chunk_last; ++j) {
        if (info.body_frame)
          to_world(body + size_t(j) * kBodyFloats, sub + size_t(j - from) * n, n);
        to_grid(sub + size_t(j - from) * n, n, info.origin, info.step, info.qmax, p);
        if (!add_residuals_mode(mode, rplanes, rb + size_t(j) * n, rplane, n, info.qmax, p, corr,
                                q))
          return fail(err, Status::Corrupt,
                      "frame blob chunk %u: reconstructed values outside the blob's range", c);
        ++s.frames_reconstructed_;
        if (out && j >= write_from) {
          float* o = out + (size_t(f0 + j) - first) * n;
          for (size_t i = 0; i < n; i += 3) {
            o[i] = dequantise(info.origin[0], info.step, q[i]);
            o[i + 1] = dequantise(info.origin[1], info.step, q[i + 1]);
            o[i + 2] = dequantise(info.origin[2], info.step, q[i + 2]);
          }
        }
      }
    }
    return Status::Ok;
  }
};

namespace v2 {
Status parse(const uint8_t* blob, size_t size, BlobInfo* info, Error* err) {
  return parse_impl(blob, size, info, err);
}
Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
              size_t out_floats, DecodeScratch& scratch, Error* err, const Basis* basis) {
  return DecoderV2Access::decode(blob, size, first, count, out, out_floats, scratch, err, basis);
}
void reseal(uint8_t* blob, size_t size) {
  if (size < kHeaderSize) return;
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
}  // namespace v2

// ---- basis ------------------------------------------------------------------------------------

void to_body_frame(const float* T, const float* x, size_t n, double* out) {
  for (size_t i = 0; i < n; i += 3) {
    const double px = double(x[i]) - T[9], py = double(x[i + 1]) - T[10],
                 pz = double(x[i + 2]) - T[11];
    out[i] = double(T[0]) * px + double(T[3]) * py + double(T[6]) * pz;
    out[i + 1] = double(T[1]) * px + double(T[4]) * py + double(T[7]) * pz;
    out[i + 2] = double(T[2]) * px + double(T[5]) * py + double(T[8]) * pz;
  }
}

Basis make_basis(int64_t id, uint32_t vertex_count, const float* mean, const float* modes,
                 uint32_t mode_count) {
  if (vertex_count == 0 || vertex_count > kMaxVertices)
    throw ClothdbError(Status::InvalidArgument, "basis: vertex count " +
                                                    std::to_string(vertex_count) + " outside 1.." +
                                                    std::to_string(kMaxVertices));
  const size_t n = size_t(vertex_count) * 3;
  if (mode_count > kMaxBasisModes || uint64_t(mode_count) * n > kMaxBasisValues)
    throw ClothdbError(Status::InvalidArgument, "basis: " + std::to_string(mode_count) +
                                                    " modes of " + std::to_string(vertex_count) +
                                                    " vertices exceed the basis limits");
  Basis b;
  b.id = id;
  b.vertex_count = vertex_count;
  b.mode_count = mode_count;
  b.mean.assign(mean, mean + n);
  for (size_t i = 0; i < n; ++i)
    if (!(std::fabs(b.mean[i]) <= kMaxCoordinate))
      throw ClothdbError(Status::InvalidArgument,
                         "basis: mean coordinate " + std::to_string(i) + " is not finite");
  b.scale.resize(mode_count);
  b.modes.resize(size_t(mode_count) * n);
  for (uint32_t k = 0; k < mode_count; ++k) {
    const float* u = modes + size_t(k) * n;
    double largest = 0;
    for (size_t i = 0; i < n; ++i) {
      if (!std::isfinite(u[i]))
        throw ClothdbError(Status::InvalidArgument,
                           "basis: mode " + std::to_string(k) + " is not finite");
      largest = std::max(largest, double(std::fabs(u[i])));
    }
    const float scale = largest > 0 ? float(largest / 32767.0) : 1.0f;
    b.scale[k] = scale;
    float* out = b.modes.data() + size_t(k) * n;
    for (size_t i = 0; i < n; ++i) {
      const double t = std::clamp(std::nearbyint(double(u[i]) / double(scale)), -32767.0, 32767.0);
      out[i] = float(int16_t(t)) * scale;
    }
  }
  return b;
}

std::vector<uint8_t> serialize_basis(const Basis& b) {
  const size_t n = size_t(b.vertex_count) * 3;
  std::vector<uint8_t> out(kBasisHeader + 4 * n + 4 * size_t(b.mode_count) +
                           2 * size_t(b.mode_count) * n);
  uint8_t* h = out.data();
  std::memcpy(h, kBasisMagic, 4);
  put_u16(h + 4, 1);
  put_u16(h + 6, uint16_t(kBasisHeader));
  put_u32(h + 8, b.vertex_count);
  put_u32(h + 12, b.mode_count);
  uint8_t* p = h + kBasisHeader;
  for (size_t i = 0; i < n; ++i, p += 4) put_f32(p, b.mean[i]);
  for (uint32_t k = 0; k < b.mode_count; ++k, p += 4) put_f32(p, b.scale[k]);
  for (uint32_t k = 0; k < b.mode_count; ++k)
    for (size_t i = 0; i < n; ++i, p += 2) {
      // modes[k][i] is float(int16) * scale exactly, so the division recovers the integer.
      const double t = std::nearbyint(double(b.modes[size_t(k) * n + i]) / double(b.scale[k]));
      put_u16(p, uint16_t(int16_t(std::clamp(t, -32767.0, 32767.0))));
    }
  put_u64(h + 16, xxh64(h + kBasisHeader, out.size() - kBasisHeader, xxh64(h, 16)));
  return out;
}

Status parse_basis(const uint8_t* data, size_t size, int64_t id, Basis* basis, Error* err) {
  if (data == nullptr && size > 0) return fail(err, Status::InvalidArgument, "basis: null pointer");
  if (size < 4 || std::memcmp(data, kBasisMagic, 4) != 0)
    return fail(err, Status::NotClothdb, "basis %lld: not a clothdb basis (no CLBS magic)",
                (long long)id);
  if (size < kBasisHeader)
    return fail(err, Status::Truncated, "basis %lld: truncated at %zu bytes", (long long)id, size);
  if (get_u16(data + 4) != 1)
    return fail(err, Status::NewerVersion, "basis %lld: format version %u is not 1", (long long)id,
                get_u16(data + 4));
  if (get_u16(data + 6) != kBasisHeader)
    return fail(err, Status::Corrupt, "basis %lld: unknown header size", (long long)id);
  const uint32_t V = get_u32(data + 8), M = get_u32(data + 12);
  if (V == 0 || V > kMaxVertices || M > kMaxBasisModes || uint64_t(M) * V * 3 > kMaxBasisValues)
    return fail(err, Status::Corrupt, "basis %lld: %u vertices, %u modes outside the limits",
                (long long)id, V, M);
  const size_t n = size_t(V) * 3;
  const size_t expected = kBasisHeader + 4 * n + 4 * size_t(M) + 2 * size_t(M) * n;
  if (size != expected)
    return fail(err, size < expected ? Status::Truncated : Status::Corrupt,
                "basis %lld: %zu bytes, %u vertices and %u modes need %zu", (long long)id, size, V,
                M, expected);
  if (get_u64(data + 16) != xxh64(data + kBasisHeader, size - kBasisHeader, xxh64(data, 16)))
    return fail(err, Status::ChecksumMismatch, "basis %lld: checksum mismatch", (long long)id);
  Basis b;
  b.id = id;
  b.vertex_count = V;
  b.mode_count = M;
  b.mean.resize(n);
  b.scale.resize(M);
  b.modes.resize(size_t(M) * n);
  const uint8_t* p = data + kBasisHeader;
  for (size_t i = 0; i < n; ++i, p += 4) {
    b.mean[i] = get_f32(p);
    if (!(std::fabs(b.mean[i]) <= kMaxCoordinate))
      return fail(err, Status::Corrupt, "basis %lld: mean value %zu is not finite", (long long)id,
                  i);
  }
  for (uint32_t k = 0; k < M; ++k, p += 4) {
    b.scale[k] = get_f32(p);
    if (!(b.scale[k] > 0 && b.scale[k] <= 1e6f))
      return fail(err, Status::Corrupt, "basis %lld: mode %u scale is invalid", (long long)id, k);
  }
  for (uint32_t k = 0; k < M; ++k)
    for (size_t i = 0; i < n; ++i, p += 2)
      b.modes[size_t(k) * n + i] = float(int16_t(get_u16(p))) * b.scale[k];
  *basis = std::move(b);
  return Status::Ok;
}

// ---- encoder ----------------------------------------------------------------------------------

namespace {

struct Plan {
  uint32_t K = 0, M = 0;
  double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  double coefficient_step = 0;
};

std::vector<uint8_t> encode_grid(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                                 const Basis& basis, const EncodeSettings& settings,
                                 const SubspaceSettings& subspace, const Plan& plan,
                                 const std::vector<int32_t>& coefficients, int divisions,
                                 double* step_out) {
  const uint32_t K = plan.K, M = plan.M;
  const double* lo = plan.lo;
  const double* hi = plan.hi;
  const size_t n = size_t(vertex_count) * 3;
  const size_t total = size_t(frame_count) * n;
  // The interval [qlo, qhi] of grid values within the bound of each input coordinate, on a step
  // just under 2 x bound / divisions (shrunk if float rounding ever misses, as in version 1).
  std::vector<uint32_t> qlo(total), qhi(total);
  double step = 2 * settings.bound * (1.0 - 1.0 / 1024) / divisions;
  uint32_t qmax[3] = {0, 0, 0};
  for (int retries = 0;; ++retries) {
    if (retries > 40)
      invalid("error bound " + std::to_string(settings.bound) +
              " is below the float precision of the coordinates");
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
      auto within = [&](uint32_t c) {
        return std::fabs(double(dequantise(lo[a], step, c)) - x) <= settings.bound;
      };
      const uint32_t qi =
          uint32_t(std::clamp(std::nearbyint((x - lo[a]) / step), 0.0, double(qmax[a])));
      ok = within(qi);
      uint32_t l = qi, h = qi;
      while (ok && l > 0 && within(l - 1)) --l;
      while (ok && h < qmax[a] && within(h + 1)) ++h;
      qlo[i] = l;
      qhi[i] = h;
    }
    if (ok) break;
    step *= 0.75;
  }

  const uint32_t chunk_count = (frame_count + K - 1) / K;
  std::vector<uint8_t> header(kHeaderSize + size_t(chunk_count) * kEntrySize, 0);
  std::vector<uint8_t> body;
  std::vector<uint32_t> pq(size_t(K) * n);    // subspace prediction on the grid, per chunk frame
  std::vector<uint32_t> zr(size_t(K) * n);    // residuals (zigzagged) of the candidate
  std::vector<uint32_t> best(size_t(K) * n);  // of the winner
  std::vector<uint32_t> zc(size_t(K) * M), zc_best(size_t(K) * M);
  std::vector<int32_t> corr(n);
  std::vector<float> sub(size_t(K) * n);
  std::vector<uint8_t> raw, compressed;
  ZSTD_CCtx* cctx = ZSTD_createCCtx();
  if (!cctx) throw ClothdbError(Status::IoError, "encode_v2: cannot create a zstd context");
  try {
    for (uint32_t c = 0; c < chunk_count; ++c) {
      const uint32_t f0 = c * K;
      const uint32_t nf = std::min(K, frame_count - f0);
      const int32_t* cc = coefficients.data() + size_t(f0) * M;
      predict(basis, M, subspace.use_mean, cc, nf, plan.coefficient_step, sub.data(), n);
      const float* transforms =
          subspace.body_frames ? subspace.body_frames + size_t(f0) * kBodyFloats : nullptr;
      for (uint32_t j = 0; j < nf; ++j) {
        if (transforms)
          to_world(transforms + size_t(j) * kBodyFloats, sub.data() + size_t(j) * n, n);
        to_grid(sub.data() + size_t(j) * n, n, lo, step, qmax, pq.data() + size_t(j) * n);
      }
      auto bits = [](const uint32_t* z, size_t count) {
        uint64_t b = 0;
        for (size_t i = 0; i < count; ++i) b += std::bit_width(z[i]);
        return b;
      };
      // Coefficient predictor: delta or linear, whichever leaves fewer bits.
      uint8_t mode = 0;
      uint64_t best_bits = UINT64_MAX;
      for (bool linear : {false, true}) {
        if (linear && nf < 3) continue;
        for (uint32_t j = 0; j < nf; ++j)
          for (uint32_t k = 0; k < M; ++k) {
            const size_t i = size_t(j) * M + k;
            const int64_t pred = j == 0               ? 0
                                 : (j >= 2 && linear) ? 2 * int64_t(cc[i - M]) - cc[i - 2 * M]
                                                      : int64_t(cc[i - M]);
            zc[i] = zigzag(uint32_t(int64_t(cc[i]) - pred));
          }
        const uint64_t b = bits(zc.data(), size_t(nf) * M);
        if (b < best_bits) {
          best_bits = b;
          mode = linear ? kLinear : 0;
          zc_best.swap(zc);
        }
      }
      // Residuals: the grid value within the bound nearest the prediction, for each predictor of
      // the correction d = q - p (none, the previous frame's, and either plus the previous
      // vertex's change), whichever leaves fewer bits.
      best_bits = UINT64_MAX;
      uint8_t carry_mode = 0;
      for (uint8_t candidate : {uint8_t(0), kCarry, kSpatial, uint8_t(kCarry | kSpatial)}) {
        const bool carry = candidate & kCarry, spatial = candidate & kSpatial;
        std::fill(corr.begin(), corr.end(), 0);
        for (uint32_t j = 0; j < nf; ++j) {
          const size_t fi = size_t(f0 + j) * n;
          const uint32_t* p = pq.data() + size_t(j) * n;
          uint32_t* z = zr.data() + size_t(j) * n;
          int64_t last[3] = {0, 0, 0};
          for (size_t i = 0; i < n; ++i) {
            const int a = int(i % 3);
            const int64_t tp = carry ? corr[i] : 0;
            const int64_t base = int64_t(p[i]) + tp + (spatial ? last[a] : 0);
            const int64_t v = std::clamp<int64_t>(base, qlo[fi + i], qhi[fi + i]);
            z[i] = zigzag(uint32_t(v - base));
            const int64_t d = v - int64_t(p[i]);
            last[a] = d - tp;
            corr[i] = int32_t(d);
          }
        }
        const uint64_t b = bits(zr.data(), size_t(nf) * n);
        if (b < best_bits) {
          best_bits = b;
          carry_mode = candidate;
          best.swap(zr);
        }
      }
      mode |= carry_mode;
      auto planes_of = [](const uint32_t* z, size_t count) {
        uint32_t all = 0;
        for (size_t i = 0; i < count; ++i) all |= z[i];
        return std::max(1, (int(std::bit_width(all)) + 7) / 8);
      };
      const size_t ccount = size_t(nf) * M, rcount = size_t(nf) * n;
      const int cplanes = M ? planes_of(zc_best.data(), ccount) : 0;
      const int rplanes = planes_of(best.data(), rcount);
      const size_t tbytes = transforms ? size_t(nf) * kBodyFloats * 4 : 0;
      raw.assign(tbytes + size_t(cplanes) * ccount + size_t(rplanes) * rcount, 0);
      for (size_t i = 0; i < tbytes / 4; ++i) put_f32(raw.data() + 4 * i, transforms[i]);
      uint8_t* cr = raw.data() + tbytes;
      for (int b = 0; b < cplanes; ++b)
        for (size_t i = 0; i < ccount; ++i)
          cr[size_t(b) * ccount + i] = uint8_t(zc_best[i] >> (8 * b));
      uint8_t* rr = cr + size_t(cplanes) * ccount;
      for (int b = 0; b < rplanes; ++b)
        for (size_t i = 0; i < rcount; ++i)
          rr[size_t(b) * rcount + i] = uint8_t(best[i] >> (8 * b));
      compressed.resize(ZSTD_compressBound(raw.size()));
      const size_t csize = ZSTD_compressCCtx(cctx, compressed.data(), compressed.size(), raw.data(),
                                             raw.size(), settings.zstd_level);
      if (ZSTD_isError(csize))
        throw ClothdbError(Status::IoError,
                           std::string("encode_v2: zstd failed: ") + ZSTD_getErrorName(csize));
      if (csize > UINT32_MAX) invalid("chunk too large");
      uint8_t* e = header.data() + kHeaderSize + size_t(c) * kEntrySize;
      put_u32(e, uint32_t(csize));
      e[4] = uint8_t(rplanes);
      e[5] = mode;
      e[6] = uint8_t(cplanes);
      put_u64(e + 8, xxh64(compressed.data(), csize));
      body.insert(body.end(), compressed.begin(), compressed.begin() + std::ptrdiff_t(csize));
    }
  } catch (...) {
    ZSTD_freeCCtx(cctx);
    throw;
  }
  ZSTD_freeCCtx(cctx);

  uint8_t* h = header.data();
  std::memcpy(h, kMagic, 4);
  put_u16(h + 4, uint16_t(kFormatVersionV2));
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
  put_u32(h + 76, M);
  put_u64(h + 80, uint64_t(basis.id));
  put_f64(h + 88, plan.coefficient_step);
  h[96] = uint8_t((subspace.use_mean ? kFlagMean : 0) | (subspace.body_frames ? kFlagBody : 0));
  put_u64(h + kChecksumOffset, header_checksum(h, kHeaderSize, kChecksumOffset, chunk_count));
  std::vector<uint8_t> blob = std::move(header);
  blob.insert(blob.end(), body.begin(), body.end());
  if (step_out) *step_out = step;
  return blob;
}

}  // namespace

std::vector<uint8_t> encode_v2(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                               const Basis& basis, const EncodeSettings& settings,
                               const SubspaceSettings& subspace, EncodeStats* stats) {
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
  if (basis.id <= 0) invalid("the basis has no id (store it first)");
  const size_t n = size_t(vertex_count) * 3;
  if (basis.vertex_count != vertex_count || basis.mean.size() != n ||
      basis.modes.size() != size_t(basis.mode_count) * n)
    invalid("basis " + std::to_string(basis.id) + " is for " + std::to_string(basis.vertex_count) +
            " vertices, the frames have " + std::to_string(vertex_count));
  if (subspace.modes > basis.mode_count)
    invalid(std::to_string(subspace.modes) + " modes asked, basis " + std::to_string(basis.id) +
            " has " + std::to_string(basis.mode_count));
  if (!(subspace.coefficient_step_factor > 0 && subspace.coefficient_step_factor <= 1e6))
    invalid("coefficient step factor must be in (0, 1e6]");
  if (subspace.grid_divisions < 0 || subspace.grid_divisions > 2)
    invalid("grid divisions must be 0 (try both), 1 or 2");
  if (subspace.body_frames && !subspace.use_mean)
    invalid("a body frame is for positions (use_mean), not velocities");
  if (subspace.body_frames)
    for (size_t i = 0; i < size_t(frame_count) * kBodyFloats; ++i) {
      const float t = subspace.body_frames[i];
      const bool rotation = i % kBodyFloats < 9;
      if (!(std::fabs(t) <= (rotation ? kMaxRotationEntry : float(kMaxCoordinate))))
        invalid("body transform " + std::to_string(i % kBodyFloats) + " of frame " +
                std::to_string(i / kBodyFloats) + " is not finite or out of range");
    }
  Plan plan;
  plan.M = subspace.modes ? subspace.modes : basis.mode_count;
  plan.K = settings.key_interval == 0 ? frame_count : std::min(settings.key_interval, frame_count);
  if (uint64_t(plan.K) * (n + plan.M) > kMaxChunkFloats)
    invalid("key interval " + std::to_string(plan.K) + " x " + std::to_string(vertex_count) +
            " vertices exceeds the chunk limit");
  plan.coefficient_step = subspace.coefficient_step_factor * settings.bound;
  if (!(plan.coefficient_step * kMaxCoefficient <= kMaxCoordinate))
    invalid("coefficient step too large");
  const size_t total = size_t(frame_count) * n;
  for (int a = 0; a < 3; ++a) plan.lo[a] = plan.hi[a] = double(frames[a]);
  for (size_t i = 0; i < total; ++i) {
    const double x = frames[i];
    if (!(std::fabs(x) <= kMaxCoordinate))
      invalid("coordinate " + std::to_string(i % 3) + " of vertex " + std::to_string((i % n) / 3) +
              " in frame " + std::to_string(i / n) + " is not finite or beyond 1e30");
    plan.lo[i % 3] = std::min(plan.lo[i % 3], x);
    plan.hi[i % 3] = std::max(plan.hi[i % 3], x);
  }
  // Coefficients: projection onto the modes (orthonormal up to their int16 rounding; the residual
  // layer absorbs the difference), in double, rounded to the coefficient step.
  std::vector<int32_t> coefficients(size_t(frame_count) * plan.M);
  std::vector<double> d(n);
  for (uint32_t f = 0; f < frame_count; ++f) {
    const float* x = frames + size_t(f) * n;
    if (subspace.body_frames)
      to_body_frame(subspace.body_frames + size_t(f) * kBodyFloats, x, n, d.data());
    else
      for (size_t i = 0; i < n; ++i) d[i] = double(x[i]);
    for (size_t i = 0; i < n; ++i) d[i] -= subspace.use_mean ? double(basis.mean[i]) : 0.0;
    for (uint32_t k = 0; k < plan.M; ++k) {
      const float* u = basis.modes.data() + size_t(k) * n;
      double dot = 0;
      for (size_t i = 0; i < n; ++i) dot += d[i] * double(u[i]);
      const double t = std::nearbyint(dot / plan.coefficient_step);
      coefficients[size_t(f) * plan.M + k] =
          int32_t(std::clamp(t, -double(kMaxCoefficient), double(kMaxCoefficient)));
    }
  }

  std::vector<uint8_t> blob;
  double step = 0;
  for (int divisions : {1, 2}) {
    if (subspace.grid_divisions != 0 && divisions != subspace.grid_divisions) continue;
    double s = 0;
    std::vector<uint8_t> candidate = encode_grid(frames, frame_count, vertex_count, basis, settings,
                                                 subspace, plan, coefficients, divisions, &s);
    if (blob.empty() || candidate.size() < blob.size()) {
      blob = std::move(candidate);
      step = s;
    }
  }
  double max_error = settings.bound;
  if (settings.verify) {
    DecodeScratch scratch;
    std::vector<float> decoded;
    Error err;
    if (decode_all(blob.data(), blob.size(), decoded, scratch, &err, &basis) != Status::Ok)
      throw ClothdbError(Status::Corrupt,
                         std::string("encode_v2: the new blob does not decode: ") + err.message);
    max_error = 0;
    for (size_t i = 0; i < total; ++i) {
      const double e = std::fabs(double(decoded[i]) - double(frames[i]));
      if (!(e <= settings.bound))
        throw ClothdbError(Status::Corrupt, "encode_v2: decoded coordinate " + std::to_string(i) +
                                                " misses the error bound; the codec is broken");
      max_error = std::max(max_error, e);
    }
  }
  if (stats) {
    stats->max_error = max_error;
    stats->step = step;
    stats->step_retries = 0;
    stats->raw_bytes = total * sizeof(float);
    stats->encoded_bytes = blob.size();
  }
  return blob;
}

}  // namespace clothdb::codec
