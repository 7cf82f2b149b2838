// Codec version 3 (docs/DATABASE.md, "version 3"): a clip as the coefficients of the garment's
// subspace (Kim et al. 2013, section 6: a few hundred PCA modes per garment) plus, only where the
// error contract (contract.hpp) needs it, a residual predicted from frame to frame whose
// quantisation is steered so the coding error stays smooth in time:
//  - coefficients are quantised finely (their error reaches a coordinate scaled by about
//    sqrt(modes / 3V)) and coded as their second difference in time (integers, so the decoder's
//    coefficients are exactly the encoder's);
//  - the residual r (what the decoded modes leave) is coded per coordinate as r^[f] = 2 r^[f-1] -
//    r^[f-2] + s q[f]. The coding error e = r^ - r then has second difference e''[f] = s q[f] -
//    r''[f] exactly, so any vertex's three q within J of r''/s (a ball; steer_ball, tried first,
//    or the cube inside it, steer) keep the jitter under its cap J whatever the error itself is;
//    among those the encoder takes 0 (nothing to send) while the error stays in
//    a band, and otherwise the q that steers the error back (a double integrator driven by a
//    bounded acceleration: bang-bang control toward zero error and zero velocity). Rounding each
//    frame on its own instead would give jitter up to 2 s per coordinate (version 1's 0.57 mm at
//    a 0.1 mm bound, docs/notebook/codec_v3.md).
// A clip is cut into segments of K frames, each its own zstd frame and decodable on its own (the
// first two frames of a segment carry their values, the rest second differences), so a player
// stages one segment, not the clip. The encoder measures the contract on the decoded blob against
// its input and tries cheaper settings first (no residual, then finer steps and narrower bands);
// the first that holds is kept.
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include "database/codec/bytes.hpp"
#include "database/codec/codec.hpp"
#include "database/codec/contract.hpp"
#include "database/format/checksum.hpp"

namespace clothdb::codec {
namespace {

using namespace bytes;

// Byte layout (little-endian), docs/DATABASE.md "version 3":
//   0 magic "CLDF" | 4 u16 version (3) | 6 u16 header size (64) | 8 u32 vertices V
//  12 u32 frames F | 16 u32 modes M | 20 u32 segment frames K | 24 i64 basis id
//  32 f64 coefficient step | 40 f64 residual step (0: no residual) | 48 u32 segments S
//  52 u32 row P (0: the residual's spatial predictor is the previous vertex alone, as blobs written
//     before the row existed) | 56 u64 XXH64 of bytes 0..55 and the segment table
//  64 segment table: S x {u64 XXH64 of the segment's bytes, u32 compressed bytes, u32 bytes before
//     zstd} | then the segments back to back, each one zstd frame.
// A segment of k frames before zstd: k x M zigzagged int32 coefficients, then (with a residual)
// k x 3V zigzagged int32 residual values, each part split into 4 byte planes (all low bytes, then
// all second bytes, ...); both frame-major, the segment's first frame as is, its second minus the
// first, the rest minus the linear prediction 2 a[f-1] - a[f-2]. The residual's values in time then
// minus a spatial prediction from vertices before them on the same axis (`spatial_prediction`).
constexpr size_t kHeaderSize = 64;
constexpr size_t kChecksumOffset = 56;
constexpr size_t kEntrySize = 16;
constexpr int32_t kMaxInt = (1 << 27) - 1;  // so 2 a - b never overflows int32
constexpr double kMaxStep = 1e3;
constexpr uint32_t kMaxSegmentFrames = 4096;

// The decoder's kernels (reconstruct, unpack_lanes8, add_spatial_prediction8, integrate_lanes8)
// are built for AVX-512 (x86-64-v4: the mode sum's 16-float vectors one register each) and AVX2 as
// well as the x86-64 baseline, picked at load time (as version 2's predict and the runtime's
// playback kernels): without FMA (and with -ffp-contract=off) all round every operation alike, and
// integer code is exact, so the frames are bit-identical whichever runs (checked for all three
// against the pinned test's hashes: docs/notebook/codec_v3.md, "Seventh session").
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define CLOTHDB_V3_MULTIVERSION __attribute__((target_clones("arch=x86-64-v4", "avx2", "default")))
#else
#define CLOTHDB_V3_MULTIVERSION
#endif

struct Header {
  uint32_t V = 0, F = 0, modes = 0, K = 0, S = 0;
  uint32_t row = 0;  // P: the residual's spatial predictor (spatial_prediction)
  int64_t basis_id = 0;
  double cstep = 0, rstep = 0;
  bool residual() const { return rstep > 0; }
  uint32_t frames_in(uint32_t s) const { return std::min(K, F - s * K); }
  size_t ints_per_frame() const { return size_t(modes) + (residual() ? size_t(V) * 3 : 0); }
};

Status parse_header(const uint8_t* blob, size_t size, Header* h, Error* err) {
  if (size < kHeaderSize)
    return fail(err, Status::Truncated, "frame blob truncated: %zu bytes, header needs %zu", size,
                kHeaderSize);
  if (get_u16(blob + 6) != kHeaderSize)
    return fail(err, Status::Corrupt, "frame blob (codec version 3): header size %u, expected %zu",
                get_u16(blob + 6), kHeaderSize);
  h->S = get_u32(blob + 48);
  const uint64_t table = kHeaderSize + uint64_t(h->S) * kEntrySize;
  if (size < table)
    return fail(err, Status::Truncated, "frame blob truncated: %zu bytes, segment table needs %llu",
                size, (unsigned long long)table);
  const uint64_t stored = get_u64(blob + kChecksumOffset);
  uint64_t actual = xxh64(blob, kChecksumOffset);
  actual ^= xxh64(blob + kHeaderSize, size_t(table - kHeaderSize)) * 0x9E3779B97F4A7C15ull;
  if (stored != actual)
    return fail(err, Status::ChecksumMismatch,
                "frame blob header checksum mismatch (stored %016llx, computed %016llx)",
                (unsigned long long)stored, (unsigned long long)actual);
  h->V = get_u32(blob + 8);
  h->F = get_u32(blob + 12);
  h->modes = get_u32(blob + 16);
  h->K = get_u32(blob + 20);
  h->basis_id = int64_t(get_u64(blob + 24));
  h->cstep = get_f64(blob + 32);
  h->rstep = get_f64(blob + 40);
  if (h->V == 0 || h->V > kMaxVertices)
    return fail(err, Status::Corrupt, "frame blob: %u vertices (1..%u)", h->V, kMaxVertices);
  if (h->F == 0) return fail(err, Status::Corrupt, "frame blob: 0 frames");
  if (h->modes > kMaxBasisModes)
    return fail(err, Status::Corrupt, "frame blob: %u modes (at most %u)", h->modes,
                kMaxBasisModes);
  if (!(h->cstep > 0 && h->cstep <= kMaxStep) || !(h->rstep >= 0 && h->rstep <= kMaxStep))
    return fail(err, Status::Corrupt, "frame blob: coefficient or residual step out of range");
  if (h->K == 0 || h->K > kMaxSegmentFrames)
    return fail(err, Status::Corrupt, "frame blob: %u frames per segment (1..%u)", h->K,
                kMaxSegmentFrames);
  if (uint64_t(h->S) != (uint64_t(h->F) + h->K - 1) / h->K)
    return fail(err, Status::Corrupt, "frame blob: %u segments, %u frames of %u need %u", h->S,
                h->F, h->K, (h->F + h->K - 1) / h->K);
  if (uint64_t(h->K) * h->ints_per_frame() > kMaxChunkFloats)
    return fail(err, Status::Corrupt, "frame blob: segments of %u frames too large", h->K);
  h->row = get_u32(blob + 52);
  if (h->row >= h->V)
    return fail(err, Status::Corrupt, "frame blob: residual predictor row %u of %u vertices",
                h->row, h->V);
  uint64_t end = table;
  for (uint32_t s = 0; s < h->S; ++s) {
    const uint8_t* e = blob + kHeaderSize + size_t(s) * kEntrySize;
    if (get_u32(e + 12) != 4 * h->frames_in(s) * h->ints_per_frame())
      return fail(err, Status::Corrupt,
                  "frame blob: segment %u of %u bytes does not fit its counts", s, get_u32(e + 12));
    end += get_u32(e + 8);
  }
  if (size != end) {
    if (size < end)
      return fail(err, Status::Truncated, "frame blob truncated: %zu bytes, header says %llu", size,
                  (unsigned long long)end);
    return fail(err, Status::Corrupt, "frame blob: %zu bytes, header says %llu", size,
                (unsigned long long)end);
  }
  return Status::Ok;
}

size_t segment_offset(const uint8_t* blob, const Header& h, uint32_t s) {
  size_t off = kHeaderSize + size_t(h.S) * kEntrySize;
  for (uint32_t i = 0; i < s; ++i) off += get_u32(blob + kHeaderSize + size_t(i) * kEntrySize + 8);
  return off;
}

// Frames of the subspace plus the residual: out[j] = mean + sum_k c_jk modes[k] (+ s_r r_j), in
// float, each coordinate summed in mode order whatever the blocking (the mean, then mode 0, 1, ...,
// then the residual), so encoder and decoder agree to the bit (the library is built with
// -ffp-contract=off) and so does every build of this function. q: count x M coefficient units
// (stride M); Q: count x n residual units or null.
//
// It is a matrix product, (count x M) weights times (M x n) modes, blocked as one: a chunk of
// coordinates of all M modes (at most kChunkBytes) stays in the L2 cache while every frame of the
// call uses it; within it a register block of kFrames frames x kCoords coordinates is summed over
// the M modes, so each value of a mode read from cache serves kFrames frames (the loop the
// version before this one ran read a mode's value once per frame, from a tile larger than L1:
// docs/notebook/codec_v3.md, "Decoding speed").
constexpr uint32_t kFrames = 6;
constexpr size_t kCoords = 16;
constexpr size_t kChunkBytes = 128 * 1024;
constexpr size_t kResidualAhead = 4 * kCoords;  // how far ahead the residual is fetched

// Sixteen floats as one value (GCC and Clang vector extensions): element by element the same IEEE
// multiply and add as scalar code, but the register block below stays in registers, which the
// plain loops' auto-vectorised form did not (it shuffled and spilled: 2.7x slower than before).
// One register under AVX-512 (whose 512-bit operations the mode sum is bound by on a core that
// runs them at full width: docs/notebook/codec_v3.md, "Sixth session"), two under AVX2.
typedef float Floats16 __attribute__((vector_size(64)));

// One register block: frames [0, F) (F <= kFrames) of coordinates [lo, lo + kCoords). w: F x M
// weights (stride M); u: the modes from coordinate lo (stride n).
template <uint32_t F>
inline __attribute__((always_inline)) void sum_block(const float* __restrict u, size_t n,
                                                     uint32_t M, const float* __restrict w,
                                                     const float* __restrict mean,
                                                     float (&out)[kFrames][kCoords]) {
  static_assert(kCoords == 16, "one Floats16 per frame");
  Floats16 acc[F];
  for (uint32_t j = 0; j < F; ++j) std::memcpy(&acc[j], mean, sizeof acc[j]);
  for (uint32_t k = 0; k < M; ++k) {
    Floats16 uk;
    std::memcpy(&uk, u + size_t(k) * n, sizeof uk);
    for (uint32_t j = 0; j < F; ++j) {
      const float x = w[size_t(j) * M + k];
      const Floats16 wj = {x, x, x, x, x, x, x, x, x, x, x, x, x, x, x, x};
      acc[j] += wj * uk;
    }
  }
  for (uint32_t j = 0; j < F; ++j) std::memcpy(out[j], &acc[j], sizeof acc[j]);
}

// The same sum for `len` (< kCoords) coordinates of one frame: the chunk's last partial block.
inline void sum_tail(const float* u, size_t n, uint32_t M, const float* w, const float* mean,
                     size_t len, float* acc) {
  for (size_t i = 0; i < len; ++i) acc[i] = mean[i];
  for (uint32_t k = 0; k < M; ++k) {
    const float* uk = u + size_t(k) * n;
    const float wk = w[k];
    for (size_t i = 0; i < len; ++i) acc[i] += wk * uk[i];
  }
}

// acc plus the residual (if any) into out, `len` coordinates.
inline void store(const float* acc, const int32_t* r, double rstep, size_t len, float* out) {
  if (r != nullptr)
    for (size_t i = 0; i < len; ++i) out[i] = acc[i] + float(double(r[i]) * rstep);
  else
    std::memcpy(out, acc, len * sizeof(float));
}

template <uint32_t F>
inline __attribute__((always_inline)) void reconstruct_frames(const Basis& b, uint32_t M,
                                                              const float* w, const int32_t* Q,
                                                              double rstep, float* out, size_t n,
                                                              size_t lo, size_t hi, size_t ahead) {
  float acc[kFrames][kCoords];
  size_t c = lo;
  for (; c + kCoords <= hi; c += kCoords) {
    // The same block of the next chunk, `ahead` coordinates on, fetched into the cache now: the
    // modes are read M rows apart (a different 4 KB page each), which the hardware prefetcher does
    // not follow, and the first pass over a chunk otherwise waits on every one of those loads
    // (docs/notebook/codec_v3.md, "Fifth session").
    if (ahead != 0 && c + ahead < n)
      for (uint32_t k = 0; k < M; ++k) {
        const float* u = b.modes.data() + size_t(k) * n + c + ahead;
        __builtin_prefetch(u);
        __builtin_prefetch(u + kCoords - 1);
      }
    // The residual's rows of these frames, kResidualAhead blocks on: integrate_lanes8 wrote them
    // a whole segment before (7.7 MB for two at 10,000 vertices), so they come from L3 or memory,
    // F rows at a time, which the hardware prefetcher picks up too late at each chunk's start.
    if (Q != nullptr && c + kResidualAhead < n)
      for (uint32_t j = 0; j < F; ++j) __builtin_prefetch(Q + size_t(j) * n + c + kResidualAhead);
    sum_block<F>(b.modes.data() + c, n, M, w, b.mean.data() + c, acc);
    for (uint32_t j = 0; j < F; ++j)
      store(acc[j], Q ? Q + size_t(j) * n + c : nullptr, rstep, kCoords, out + size_t(j) * n + c);
  }
  if (c < hi)
    for (uint32_t j = 0; j < F; ++j) {
      sum_tail(b.modes.data() + c, n, M, w + size_t(j) * M, b.mean.data() + c, hi - c, acc[0]);
      store(acc[0], Q ? Q + size_t(j) * n + c : nullptr, rstep, hi - c, out + size_t(j) * n + c);
    }
}

CLOTHDB_V3_MULTIVERSION
void reconstruct(const Basis& b, uint32_t M, const int32_t* q, double cstep, const int32_t* Q,
                 double rstep, uint32_t count, float* out, size_t n) {
  // Coordinates per chunk: kChunkBytes of modes, a whole number of register blocks.
  const size_t chunk = std::max(
      kCoords, kChunkBytes / (sizeof(float) * std::max<uint32_t>(M, 1)) / kCoords * kCoords);
  float w[kFrames * kMaxBasisModes];
  for (size_t lo = 0; lo < n; lo += chunk) {
    const size_t hi = std::min(n, lo + chunk);
    for (uint32_t j0 = 0; j0 < count; j0 += kFrames) {
      const uint32_t F = std::min(kFrames, count - j0);
      const size_t ahead = j0 == 0 ? chunk : 0;  // the next chunk, during the first pass
      for (uint32_t j = 0; j < F; ++j)
        for (uint32_t k = 0; k < M; ++k)
          w[size_t(j) * M + k] = float(double(q[size_t(j0 + j) * M + k]) * cstep);
      const int32_t* Qj = Q ? Q + size_t(j0) * n : nullptr;
      float* oj = out + size_t(j0) * n;
      switch (F) {
        case 6:
          reconstruct_frames<6>(b, M, w, Qj, rstep, oj, n, lo, hi, ahead);
          break;
        case 5:
          reconstruct_frames<5>(b, M, w, Qj, rstep, oj, n, lo, hi, ahead);
          break;
        case 4:
          reconstruct_frames<4>(b, M, w, Qj, rstep, oj, n, lo, hi, ahead);
          break;
        case 3:
          reconstruct_frames<3>(b, M, w, Qj, rstep, oj, n, lo, hi, ahead);
          break;
        case 2:
          reconstruct_frames<2>(b, M, w, Qj, rstep, oj, n, lo, hi, ahead);
          break;
        default:
          reconstruct_frames<1>(b, M, w, Qj, rstep, oj, n, lo, hi, ahead);
          break;
      }
    }
  }
}

// The median edge detector for a value with a row above it (row > 0, c >= 3 row + 3).
inline int32_t median_prediction(const int32_t* d, size_t c, size_t row) {
  const int32_t left = d[c - 3];
  const int32_t up = d[c - 3 * row], corner = d[c - 3 * row - 3];
  // corner >= max(left, up) gives the smaller, corner <= min(left, up) the larger, otherwise
  // left + up - corner. Written with masks, not comparisons the compiler turns into branches: the
  // decoder's spatial pass is a chain through `left`, and on real residuals those branches go
  // either way at random (GCC 12 branched on std::min).
  const int32_t lt = -int32_t(left < up);  // all ones where left < up
  const int32_t lo = (left & lt) | (up & ~lt), hi = (up & lt) | (left & ~lt);
  const int32_t inside = int32_t(uint32_t(left) + uint32_t(up) - uint32_t(corner));
  const int32_t ge = -int32_t(corner >= hi), le = -int32_t(corner <= lo);
  const int32_t below = (hi & le) | (inside & ~le);
  return (lo & ge) | (below & ~ge);
}

// The spatial prediction of value c (x y z per vertex) of one frame's residual-in-time values d,
// from vertices before it on the same axis. Row P = 0: the previous vertex's (i - 1). Row P > 0:
// the median edge detector of LOCO-I (Weinberger et al. 2000, JPEG-LS) over the previous vertex
// (left, i - 1), the vertex P before (up, i - P) and the one before that (i - P - 1): for a garment
// made of rows of P vertices (a skirt's rings) these are its neighbours on the previous row, and
// the residual moves alike across a patch of cloth, not only along a row (measured: 12 % fewer
// residual bits than the previous vertex alone on the whole-motion skirt,
// docs/notebook/codec_v3.md). Vertices of the first row use the previous vertex alone.
inline int32_t spatial_prediction(const int32_t* d, size_t c, size_t row) {
  if (c < 3) return 0;
  if (row == 0 || c < 3 * row + 3) return d[c - 3];
  return median_prediction(d, c, row);
}

// Values [0, width) of one frame of the coefficients from their 4 byte planes (p: the frame's first
// low byte; N: values per plane), zigzagged in the payload. (The residual: unpack_lanes8.)
inline void unpack(const uint8_t* __restrict p, size_t N, size_t width, int32_t* __restrict d) {
  const uint8_t *p1 = p + N, *p2 = p1 + N, *p3 = p2 + N;
  for (size_t i = 0; i < width; ++i)
    d[i] = int32_t(unzigzag(uint32_t(p[i]) | uint32_t(p1[i]) << 8 | uint32_t(p2[i]) << 16 |
                            uint32_t(p3[i]) << 24));
}

// The spatial pass over eight frames of a segment's residual at once, in place: each value plus its
// spatial prediction in the same frame (spatial_prediction with `row`). lanes holds value c of
// frame g at lanes[8 c + g], so one vector of eight lanes is one value of eight frames: each
// frame's pass is a chain through the value to its left (one per axis), which runs at the latency
// of the median per value frame by frame, and eight frames side by side take the same time.
// spatial_prediction's cases split by range, so neither loop branches on c: the previous vertex
// alone (a running sum per axis) over the first row (every value when row is 0), then the median
// edge detector, as median_prediction computes it, with masks.
typedef int32_t Ints8 __attribute__((vector_size(32)));
typedef uint32_t Uints8 __attribute__((vector_size(32)));
CLOTHDB_V3_MULTIVERSION
void add_spatial_prediction8(int32_t* lanes, size_t width, size_t row) {
  // (Loads and stores through memcpy: no alignment assumed, and no vector passed by value, which
  // would change the baseline build's calling convention.)
  auto at = [&](Uints8& v, size_t c) { std::memcpy(&v, lanes + 8 * c, sizeof v); };
  auto put = [&](size_t c, const Uints8& v) { std::memcpy(lanes + 8 * c, &v, sizeof v); };
  const size_t first_row_end = row == 0 ? width : std::min(width, 3 * row + 3);
  Uints8 x, y;
  for (size_t c = 3; c < first_row_end; ++c) {
    at(x, c);
    at(y, c - 3);
    put(c, x + y);
  }
  if (first_row_end >= width) return;
  Uints8 left[3];
  for (size_t a = 0; a < 3; ++a) at(left[a], first_row_end - 3 + a);
  for (size_t c = first_row_end; c < width; c += 3)
    for (size_t a = 0; a < 3; ++a) {
      Uints8 up, corner, d;
      at(up, c + a - 3 * row);
      at(corner, c + a - 3 * row - 3);
      at(d, c + a);
      const Ints8 l = Ints8(left[a]), u = Ints8(up), k = Ints8(corner);
      const Uints8 lt = Uints8(l < u);  // all ones where left < up
      const Uints8 lo = (left[a] & lt) | (up & ~lt), hi = (up & lt) | (left[a] & ~lt);
      const Uints8 inside = left[a] + up - corner;
      const Uints8 ge = Uints8(k >= Ints8(hi)), le = Uints8(k <= Ints8(lo));
      const Uints8 below = (hi & le) | (inside & ~le);
      left[a] = d + ((lo & ge) | (below & ~ge));
      put(c + a, left[a]);
    }
}

// Eight rows of eight values transposed in place (m[i][j] becomes m[j][i]): three rounds of
// two-input shuffles, the AVX2 unpack pattern (32-bit pairs, 64-bit pairs, 128-bit halves).
inline __attribute__((always_inline)) void transpose8(Uints8 (&m)[8]) {
  Uints8 t[8], u[8];
  for (int i = 0; i < 8; i += 2) {
    t[i] = __builtin_shufflevector(m[i], m[i + 1], 0, 8, 1, 9, 4, 12, 5, 13);
    t[i + 1] = __builtin_shufflevector(m[i], m[i + 1], 2, 10, 3, 11, 6, 14, 7, 15);
  }
  for (int i = 0; i < 8; i += 4)
    for (int j = 0; j < 2; ++j) {
      u[i + 2 * j] = __builtin_shufflevector(t[i + j], t[i + j + 2], 0, 1, 8, 9, 4, 5, 12, 13);
      u[i + 2 * j + 1] =
          __builtin_shufflevector(t[i + j], t[i + j + 2], 2, 3, 10, 11, 6, 7, 14, 15);
    }
  for (int j = 0; j < 4; ++j) {
    m[j] = __builtin_shufflevector(u[j], u[j + 4], 0, 1, 2, 3, 8, 9, 10, 11);
    m[j + 4] = __builtin_shufflevector(u[j], u[j + 4], 4, 5, 6, 7, 12, 13, 14, 15);
  }
}

// Values c..c+7 of one frame from its 4 byte planes (p: the frame's first low byte, N: values per
// plane), unzigzagged. Each plane's 8 bytes are read as one 64-bit load and the bytes interleaved
// by shuffles: GCC 12 reads an 8-byte vector type byte by byte through general registers
// (docs/notebook/codec_v3.md, "Sixth session"), which cost more than the work.
typedef uint8_t Bytes16 __attribute__((vector_size(16)));
typedef uint64_t U64x2 __attribute__((vector_size(16)));
typedef uint16_t U16x8 __attribute__((vector_size(16)));
inline __attribute__((always_inline)) void unpack_row8(const uint8_t* p, size_t N, size_t c,
                                                       Uints8& out) {
  uint64_t b[4];
  for (int i = 0; i < 4; ++i) std::memcpy(&b[i], p + size_t(i) * N + c, 8);
  const U64x2 v01 = {b[0], b[1]}, v23 = {b[2], b[3]};
  // Low and high 16 bits of each value: byte i of plane 0 beside byte i of plane 1 (2 and 3).
  const U16x8 lo = U16x8(__builtin_shufflevector(Bytes16(v01), Bytes16(v01), 0, 8, 1, 9, 2, 10, 3,
                                                 11, 4, 12, 5, 13, 6, 14, 7, 15));
  const U16x8 hi = U16x8(__builtin_shufflevector(Bytes16(v23), Bytes16(v23), 0, 8, 1, 9, 2, 10, 3,
                                                 11, 4, 12, 5, 13, 6, 14, 7, 15));
  typedef uint16_t U16x16 __attribute__((vector_size(32)));
  const Uints8 z = Uints8(U16x16(
      __builtin_shufflevector(lo, hi, 0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15)));
  out = (z >> 1) ^ (0u - (z & 1u));  // unzigzag, lane by lane
}

// Frames f0..f0+G-1 (G <= 8) of a segment's residual unpacked into the spatial pass's lanes (value
// c of frame g at lanes[8 c + g]; lanes of frames g >= G zero). p: the residual's first low byte;
// N: values per plane; width: values per frame. Blocks of 8 values of the 8 frames are read as rows
// and transposed in registers, so lanes is written in whole vectors, not one value at a time.
CLOTHDB_V3_MULTIVERSION
void unpack_lanes8(const uint8_t* p, size_t N, size_t width, uint32_t f0, uint32_t G,
                   int32_t* lanes) {
  size_t c = 0;
  for (; c + 8 <= width; c += 8) {
    Uints8 m[8];
    for (uint32_t g = 0; g < 8; ++g)
      if (g < G)
        unpack_row8(p + size_t(f0 + g) * width, N, c, m[g]);
      else
        m[g] = Uints8{};
    transpose8(m);
    std::memcpy(lanes + 8 * c, m, sizeof m);
  }
  for (; c < width; ++c)
    for (uint32_t g = 0; g < 8; ++g) {
      const uint8_t* q = p + size_t(f0 + g) * width + c;
      lanes[8 * c + g] =
          g < G ? int32_t(unzigzag(uint32_t(q[0]) | uint32_t(q[N]) << 8 | uint32_t(q[2 * N]) << 16 |
                                   uint32_t(q[3 * N]) << 24))
                : 0;
    }
}

// The time pass of frames f0..f0+G-1 (G <= 8) of a segment's residual from the spatial pass's
// lanes, into v (frames of `width` values, frame-major; frames before f0 done): each value the lane
// value plus, for the segment's first frame nothing, its second the first, the rest 2 a[f-1] -
// a[f-2] (as add_time_prediction, the same wrapping integer sums). Blocks of 8 values are
// transposed back to frame rows in registers and the chain through the frames runs along them.
// Returns false if a value leaves the range (as add_time_prediction).
CLOTHDB_V3_MULTIVERSION
bool integrate_lanes8(const int32_t* lanes, size_t width, uint32_t f0, uint32_t G, int32_t* v) {
  Uints8 bad = {};
  const Uints8 kMax = Uints8{} + uint32_t(kMaxInt), kSpan = Uints8{} + 2u * uint32_t(kMaxInt);
  size_t c = 0;
  for (; c + 8 <= width; c += 8) {
    Uints8 m[8];
    std::memcpy(m, lanes + 8 * c, sizeof m);
    transpose8(m);
    // a: frame f - 1, b: frame f - 2 (the segment's first frame: both zero; its second: both the
    // first, as 2 a - a = a).
    Uints8 a = {}, b = {};
    if (f0 >= 2) {
      std::memcpy(&a, v + size_t(f0 - 1) * width + c, sizeof a);
      std::memcpy(&b, v + size_t(f0 - 2) * width + c, sizeof b);
    }
    for (uint32_t g = 0; g < G; ++g) {
      if (f0 + g == 1) b = a;
      const Uints8 x = 2 * a - b + m[g];
      bad |= Uints8(x + kMax > kSpan);
      std::memcpy(v + size_t(f0 + g) * width + c, &x, sizeof x);
      b = a;
      a = x;
    }
  }
  uint32_t bad_tail = 0;
  for (; c < width; ++c) {
    uint32_t a = 0, b = 0;
    if (f0 >= 2) {
      a = uint32_t(v[size_t(f0 - 1) * width + c]);
      b = uint32_t(v[size_t(f0 - 2) * width + c]);
    }
    for (uint32_t g = 0; g < G; ++g) {
      if (f0 + g == 1) b = a;
      const uint32_t x = 2 * a - b + uint32_t(lanes[8 * c + g]);
      bad_tail |= uint32_t(x + uint32_t(kMaxInt) > 2u * uint32_t(kMaxInt));
      v[size_t(f0 + g) * width + c] = int32_t(x);
      b = a;
      a = x;
    }
  }
  for (int i = 0; i < 8; ++i) bad_tail |= bad[i];
  return bad_tail == 0;
}

// Frame f of a segment part (frames of `width` values, frame-major, v) in time, once the frames
// before it are done, in place: value c plus, for the first frame nothing, the second the first,
// the rest 2 a[f-1] - a[f-2]. Wrapping arithmetic, then range-checked so a damaged payload cannot
// overflow later. (The coefficients; the residual's time pass is integrate_lanes8.)
bool add_time_prediction(int32_t* v, uint32_t f, size_t width) {
  int32_t* d = v + size_t(f) * width;
  // In range: -kMaxInt <= x <= kMaxInt, as one unsigned comparison so the loops vectorise.
  auto out_of_range = [](int32_t x) {
    return uint32_t(uint32_t(x) + uint32_t(kMaxInt) > 2u * kMaxInt);
  };
  uint32_t bad = 0;
  if (f == 0) {
    for (size_t c = 0; c < width; ++c) bad |= out_of_range(d[c]);
  } else if (f == 1) {
    const int32_t* __restrict a = d - width;
    for (size_t c = 0; c < width; ++c) {
      const int32_t x = int32_t(uint32_t(a[c]) + uint32_t(d[c]));
      bad |= out_of_range(x);
      d[c] = x;
    }
  } else {
    const int32_t* __restrict a = d - width;
    const int32_t* __restrict b = a - width;
    for (size_t c = 0; c < width; ++c) {
      const int32_t x = int32_t(2 * uint32_t(a[c]) - uint32_t(b[c]) + uint32_t(d[c]));
      bad |= out_of_range(x);
      d[c] = x;
    }
  }
  return bad == 0;
}

}  // namespace

struct DecoderV3Access {
  // The scratch holds up to kPass consecutive segments: one pass of the mode sum over the basis
  // makes the frames of all of them (the basis, 7.7 MB at 10,000 vertices and 64 modes, is read
  // from memory once per call of reconstruct: docs/notebook/codec_v3.md, "Sixth session"). Slot i
  // holds frames [i K, i K + k) of the scratch's `held` frames: coefficients at v3_ints_ + i K M,
  // the residual at v3_ints_ + held M + i K 3V, so the frames of consecutive segments follow one
  // another. Segments of more than kPairedInts integers are decoded one at a time, so a hostile
  // header cannot ask for more than one segment's worth (kMaxChunkFloats) as before; 10,000
  // vertices in segments of 32 frames need 1 M.
  static constexpr uint32_t kPass = 2;
  static constexpr size_t kPairedInts = size_t(1) << 24;
  static uint32_t pass(const Header& h) {
    return h.S > 1 && size_t(h.K) * h.ints_per_frame() <= kPairedInts ? kPass : 1;
  }
  static size_t held(const Header& h) { return h.S > 1 ? size_t(pass(h)) * h.K : h.F; }

  // Where slot i's coefficients and residual go.
  static int32_t* coefficients(DecodeScratch& s, const Header& h, uint32_t i) {
    return s.v3_ints_.data() + size_t(i) * h.K * h.modes;
  }
  static int32_t* residual(DecodeScratch& s, const Header& h, uint32_t i) {
    return s.v3_ints_.data() + held(h) * h.modes + size_t(i) * h.K * h.V * 3;
  }

  // Decompresses and checks segment seg into slot i of the scratch (coefficients k x M, residual
  // k x 3V). The caller marks what the scratch holds.
  static Status load(const uint8_t* blob, const Header& h, uint32_t seg, uint32_t slot,
                     DecodeScratch& s, Error* err) {
    const uint8_t* entry = blob + kHeaderSize + size_t(seg) * kEntrySize;
    const uint32_t csize = get_u32(entry + 8), raw = get_u32(entry + 12);
    const uint8_t* src = blob + segment_offset(blob, h, seg);
    if (xxh64(src, csize) != get_u64(entry))
      return fail(err, Status::ChecksumMismatch, "frame blob segment %u checksum mismatch", seg);
    const unsigned long long declared = ZSTD_getFrameContentSize(src, csize);
    if (declared != raw)
      return fail(err, Status::Corrupt,
                  "frame blob segment %u: zstd frame declares %llu bytes, expected %u", seg,
                  declared, raw);
    if (s.bytes_.size() < raw) s.bytes_.resize(raw);
    const size_t got =
        ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(s.dctx_), s.bytes_.data(), raw, src, csize);
    if (ZSTD_isError(got))
      return fail(err, Status::Corrupt, "frame blob segment %u: zstd: %s", seg,
                  ZSTD_getErrorName(got));
    if (got != raw)
      return fail(err, Status::Corrupt, "frame blob segment %u: %zu bytes decompressed of %u", seg,
                  got, raw);
    // Room for pass(h) segments (once for the largest blob: decoding allocates nothing after).
    const size_t ints = held(h) * h.ints_per_frame();
    if (s.v3_ints_.size() < ints) s.v3_ints_.resize(ints);
    const uint32_t k = h.frames_in(seg);
    const size_t N = raw / 4;
    int32_t* v = coefficients(s, h, slot);
    const uint8_t* b = s.bytes_.data();
    // Two parts, each in 4 byte planes: the coefficients (k x M), then the residual (k x 3V).
    const size_t Nc = size_t(k) * h.modes, n = N - Nc;
    for (uint32_t f = 0; f < k; ++f) {
      unpack(b + size_t(f) * h.modes, Nc, h.modes, v + size_t(f) * h.modes);
      if (!add_time_prediction(v, f, h.modes))
        return fail(err, Status::Corrupt, "frame blob segment %u: coefficient out of range", seg);
    }
    if (n > 0) {
      // Eight frames at a time: unpacked, their spatial passes side by side in eight lanes
      // (add_spatial_prediction8), then each frame's time pass (from the two frames before it).
      const size_t width = size_t(h.V) * 3;
      int32_t* r = residual(s, h, slot);
      if (s.v3_lanes_.size() < 8 * width) s.v3_lanes_.resize(8 * width);
      int32_t* lanes = s.v3_lanes_.data();
      for (uint32_t f0 = 0; f0 < k; f0 += 8) {
        const uint32_t G = std::min(8u, k - f0);
        unpack_lanes8(b + 4 * Nc, n, width, f0, G, lanes);
        add_spatial_prediction8(lanes, width, h.row);
        if (!integrate_lanes8(lanes, width, f0, G, r))
          return fail(err, Status::Corrupt, "frame blob segment %u: residual out of range", seg);
      }
    }
    return Status::Ok;
  }

  static Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
                       size_t out_floats, DecodeScratch& s, Error* err, const Basis* basis) {
    s.frames_reconstructed_ = 0;
    Header h;
    if (Status st = parse_header(blob, size, &h, err); st != Status::Ok) return st;
    if (basis == nullptr)
      return fail(err, Status::NotFound,
                  "frame blob (codec version 3) needs basis %lld, and none was given",
                  (long long)h.basis_id);
    if (basis->id != h.basis_id)
      return fail(err, Status::NotFound, "frame blob needs basis %lld, the decoder has basis %lld",
                  (long long)h.basis_id, (long long)basis->id);
    const size_t n = size_t(h.V) * 3;
    if (basis->vertex_count != h.V || h.modes > basis->mode_count || basis->mean.size() != n ||
        basis->modes.size() < size_t(h.modes) * n)
      return fail(err, Status::Corrupt,
                  "frame blob of %u vertices and %u modes does not fit basis %lld (%u vertices, "
                  "%u modes)",
                  h.V, h.modes, (long long)basis->id, basis->vertex_count, basis->mode_count);
    if (count == 0 && out != nullptr) return Status::Ok;
    if (out == nullptr) {   // verify: every segment, no output
      s.v3_valid_ = false;  // verify checks the bytes even when a segment is cached
      for (uint32_t seg = 0; seg < h.S; ++seg)
        if (Status st = load(blob, h, seg, 0, s, err); st != Status::Ok) return st;
      return Status::Ok;
    }
    if (first >= h.F || count > h.F - first)
      return fail(err, Status::InvalidArgument, "frames %u..%u requested from a %u-frame blob",
                  first, first + count - 1, h.F);
    if (out_floats < size_t(count) * n)
      return fail(err, Status::OutputTooSmall, "output holds %zu floats, %u frames need %zu",
                  out_floats, count, size_t(count) * n);
    const uint64_t key = get_u64(blob + kChecksumOffset);
    const uint32_t end = first + count;
    for (uint32_t f = first; f < end;) {
      // Segments seg..last (at most kPass) hold the next frames asked for; each but the blob's
      // last has K frames, so their frames follow one another in the scratch.
      const uint32_t seg = f / h.K, last = std::min((end - 1) / h.K, seg + pass(h) - 1);
      if (!(s.v3_valid_ && s.v3_key_ == key && s.v3_segment_ <= seg &&
            last < s.v3_segment_ + s.v3_segments_)) {
        s.v3_valid_ = false;
        for (uint32_t i = 0; i <= last - seg; ++i)
          if (Status st = load(blob, h, seg + i, i, s, err); st != Status::Ok) return st;
        s.v3_key_ = key;
        s.v3_segment_ = seg;
        s.v3_segments_ = last - seg + 1;
        s.v3_valid_ = true;
      }
      const uint32_t take = std::min(end, last * h.K + h.frames_in(last)) - f;
      const size_t row = size_t(f) - size_t(s.v3_segment_) * h.K;  // the scratch's frame
      const int32_t* Q = h.residual() ? residual(s, h, 0) + row * n : nullptr;
      reconstruct(*basis, h.modes, coefficients(s, h, 0) + row * h.modes, h.cstep, Q, h.rstep, take,
                  out + size_t(f - first) * n, n);
      s.frames_reconstructed_ += take;
      f += take;
    }
    return Status::Ok;
  }
};

namespace v3 {

Status parse(const uint8_t* blob, size_t size, BlobInfo* info, Error* err) {
  Header h;
  if (Status st = parse_header(blob, size, &h, err); st != Status::Ok) return st;
  BlobInfo in;
  in.version = kFormatVersionV3;
  in.vertex_count = h.V;
  in.frame_count = h.F;
  in.key_interval = std::min(h.K, h.F);  // a segment decodes on its own
  in.chunk_count = h.S;
  in.step = h.rstep;
  in.size = size;
  in.basis_id = h.basis_id;
  in.modes = h.modes;
  in.coefficient_step = h.cstep;
  in.uses_mean = true;
  in.residual_interval = h.residual() ? 1 : 0;
  *info = in;
  return Status::Ok;
}

Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
              size_t out_floats, DecodeScratch& scratch, Error* err, const Basis* basis) {
  return DecoderV3Access::decode(blob, size, first, count, out, out_floats, scratch, err, basis);
}

void reseal(uint8_t* blob, size_t size) {
  if (size < kHeaderSize) return;
  const uint32_t S = get_u32(blob + 48);
  const uint64_t table = kHeaderSize + uint64_t(S) * kEntrySize;
  if (table > size) return;
  uint64_t off = table;
  for (uint32_t s = 0; s < S; ++s) {
    uint8_t* e = blob + kHeaderSize + size_t(s) * kEntrySize;
    const uint32_t csize = get_u32(e + 8);
    if (off + csize > size) break;
    put_u64(e, xxh64(blob + off, csize));
    off += csize;
  }
  put_u64(blob + kChecksumOffset,
          xxh64(blob, kChecksumOffset) ^
              xxh64(blob + kHeaderSize, size_t(table - kHeaderSize)) * 0x9E3779B97F4A7C15ull);
}

void spans(const uint8_t* blob, std::vector<ChunkSpan>* out) {
  const uint32_t S = get_u32(blob + 48);
  size_t off = kHeaderSize + size_t(S) * kEntrySize;
  for (uint32_t s = 0; s < S; ++s) {
    const uint32_t csize = get_u32(blob + kHeaderSize + size_t(s) * kEntrySize + 8);
    out->push_back({off, csize});
    off += csize;
  }
}

}  // namespace v3

namespace {

int32_t quantise(double x, double step, const char* what) {
  const double q = std::nearbyint(x / step);
  if (!(std::fabs(q) <= double(kMaxInt)))
    throw ClothdbError(Status::InvalidArgument,
                       std::string("encode_v3: ") + what + " does not fit its step");
  return int32_t(q);
}

// Appends `width` values of k frames (frame-major) as their prediction residuals (see integrate),
// zigzagged, in 4 byte planes.
void put_planes(const int32_t* v, uint32_t k, size_t width, bool spatial, size_t row,
                std::vector<uint8_t>& raw) {
  const size_t N = size_t(k) * width, at = raw.size();
  raw.resize(at + 4 * N);
  uint8_t* p = raw.data() + at;
  auto in_time = [&](size_t i, uint32_t f) {
    const int32_t pred = f == 0 ? 0 : f == 1 ? v[i - width] : 2 * v[i - width] - v[i - 2 * width];
    return int32_t(uint32_t(v[i]) - uint32_t(pred));
  };
  std::vector<int32_t> d(width);
  for (uint32_t f = 0; f < k; ++f)
    for (size_t c = 0; c < width; ++c) {
      const size_t i = size_t(f) * width + c;
      d[c] = in_time(i, f);
      int32_t r = d[c];
      if (spatial) r = int32_t(uint32_t(r) - uint32_t(spatial_prediction(d.data(), c, row)));
      const uint32_t z = zigzag(uint32_t(r));
      p[i] = uint8_t(z);
      p[N + i] = uint8_t(z >> 8);
      p[2 * N + i] = uint8_t(z >> 16);
      p[3 * N + i] = uint8_t(z >> 24);
    }
}

size_t zstd_into(const std::vector<uint8_t>& raw, int level, std::vector<uint8_t>& out) {
  const size_t at = out.size();
  out.resize(at + ZSTD_compressBound(raw.size()));
  const size_t csize =
      ZSTD_compress(out.data() + at, out.size() - at, raw.data(), raw.size(), level);
  if (ZSTD_isError(csize))
    throw ClothdbError(Status::InvalidArgument,
                       std::string("encode_v3: zstd failed: ") + ZSTD_getErrorName(csize));
  out.resize(at + csize);
  return csize;
}

// q: F x M coefficient units; Q: F x 3V residual units (empty: no residual).
std::vector<uint8_t> assemble(uint32_t V, uint32_t F, const Basis& basis, uint32_t M, uint32_t K,
                              double cstep, const std::vector<int32_t>& q, double rstep,
                              const std::vector<int32_t>& Q, uint32_t row, int level,
                              V3Stats* stats) {
  const size_t n = size_t(V) * 3;
  const uint32_t S = (F + K - 1) / K;
  std::vector<uint8_t> blob(kHeaderSize + size_t(S) * kEntrySize), raw, scratch;
  size_t coefficient_bytes = 0;
  for (uint32_t s = 0; s < S; ++s) {
    const uint32_t f0 = s * K, k = std::min(K, F - f0);
    raw.clear();
    put_planes(q.data() + size_t(f0) * M, k, M, false, 0, raw);
    if (stats) {
      scratch.clear();
      coefficient_bytes += zstd_into(raw, level, scratch);
    }
    if (!Q.empty()) put_planes(Q.data() + size_t(f0) * n, k, n, true, row, raw);
    const size_t csize = zstd_into(raw, level, blob);
    uint8_t* e = blob.data() + kHeaderSize + size_t(s) * kEntrySize;
    put_u32(e + 8, uint32_t(csize));
    put_u32(e + 12, uint32_t(raw.size()));
  }
  uint8_t* h = blob.data();
  std::memcpy(h, kMagic, 4);
  put_u16(h + 4, uint16_t(kFormatVersionV3));
  put_u16(h + 6, uint16_t(kHeaderSize));
  put_u32(h + 8, V);
  put_u32(h + 12, F);
  put_u32(h + 16, M);
  put_u32(h + 20, K);
  put_u64(h + 24, uint64_t(basis.id));
  put_f64(h + 32, cstep);
  put_f64(h + 40, Q.empty() ? 0.0 : rstep);
  put_u32(h + 48, S);
  put_u32(h + 52, Q.empty() ? 0 : row);
  v3::reseal(blob.data(), blob.size());
  if (stats) {
    stats->header_bytes = kHeaderSize + size_t(S) * kEntrySize;
    stats->coefficient_bytes = coefficient_bytes;
    stats->residual_bytes = blob.size() - stats->header_bytes - coefficient_bytes;
  }
  return blob;
}

// The row P of the residual's spatial predictor (spatial_prediction) for a garment: the offset d
// (2..512 vertices) at which vertex i - d lies nearest vertex i in the basis's mean shape, on
// average over a sample of vertices; for a garment made of rows (a skirt's rings) that is the row
// length. 0 (the previous vertex alone) when no offset brings a vertex within twice the mean
// distance to the previous vertex: the vertex order then has no rows to use.
uint32_t choose_residual_row(const Basis& b) {
  const uint32_t V = b.vertex_count;
  const float* x = b.mean.data();
  auto mean_distance = [&](uint32_t d) {
    double sum = 0;
    uint32_t count = 0;
    for (uint32_t i = d; i < V; i += 7, ++count) {
      const float *p = x + 3 * size_t(i), *q = x + 3 * size_t(i - d);
      sum += std::sqrt(double(p[0] - q[0]) * (p[0] - q[0]) + double(p[1] - q[1]) * (p[1] - q[1]) +
                       double(p[2] - q[2]) * (p[2] - q[2]));
    }
    return count ? sum / count : 0.0;
  };
  if (V < 4) return 0;
  const double previous = mean_distance(1);
  uint32_t best = 0;
  double best_distance = 2 * previous;
  for (uint32_t d = 2; d <= std::min<uint32_t>(512, V - 2); ++d) {
    const double m = mean_distance(d);
    if (m < best_distance) {
      best_distance = m;
      best = d;
    }
  }
  return best;
}

// The residual's symbols (file comment), all coordinates frame by frame. t: the residual in units
// of the step (F x n); Q: the decoded residual's integers (F x n). jmax: the jitter allowed per
// coordinate in step units (>= 1, so at least two symbols are always allowed); band: how far the
// error may drift (step units) before the controller steers it back. Among the allowed symbols the
// one nearest the spatial prediction from the frame's symbols before it (spatial_prediction with
// `row`) is preferred: the payload codes each symbol minus that one, and what the modes leave moves
// alike at neighbouring vertices.
void steer(const double* t, size_t n, uint32_t F, double jmax, double band, size_t row,
           int32_t* Q) {
  // Frames 0 and 1 carry no jitter of their own (the first second difference is at frame 2): start
  // with zero error where the band allows nothing at all.
  for (size_t c = 0; c < n; ++c) {
    const int32_t q0 = std::fabs(t[c]) <= 0.5 * band ? 0 : int32_t(std::nearbyint(t[c]));
    Q[c] = q0;
    if (F > 1)
      Q[n + c] = std::fabs(q0 - t[n + c]) <= 0.5 * band ? q0 : int32_t(std::nearbyint(t[n + c]));
  }
  // The acceleration the controller can always choose in either direction (allowed symbols are
  // spaced 1 apart over a window of 2 jmax around r''/s).
  const double amin = std::max(0.25, jmax - 0.5);
  std::vector<int32_t> syms(n);
  for (uint32_t f = 2; f < F; ++f) {
    const double *t0 = t + size_t(f) * n, *t1 = t0 - n, *t2 = t1 - n;
    int32_t* q = Q + size_t(f) * n;
    const int32_t *q1 = q - n, *q2 = q1 - n;
    for (size_t c = 0; c < n; ++c) {
      const double tpp = t0[c] - 2 * t1[c] + t2[c];
      const double e1 = q1[c] - t1[c], v1 = e1 - (q2[c] - t2[c]);
      const double lo = std::ceil(tpp - jmax), hi = std::floor(tpp + jmax);
      // Where the error would come to rest with the strongest braking after this frame.
      auto rest = [&](double sym) {
        const double v = v1 + (sym - tpp), e = e1 + v;
        return e + v * std::fabs(v) / (2 * amin);
      };
      double sym = std::clamp(double(spatial_prediction(syms.data(), c, row)), lo, hi);
      if (std::fabs(rest(sym)) > band) {
        double best = std::fabs(rest(sym));
        for (double k = lo; k <= hi; k += 1)
          if (std::fabs(rest(k)) < best) {
            best = std::fabs(rest(k));
            sym = k;
          }
      }
      syms[c] = int32_t(sym);
      q[c] = int32_t(2 * q1[c] - q2[c] + int64_t(sym));
    }
  }
}

// The residual's symbols with the jitter cap kept on the vertex rather than on each axis: a
// vertex's three symbols may be any integer point within `radius` (step units) of r''/s, a ball,
// where steer keeps each axis within J / sqrt(3) (the cube inscribed in that ball, 1 / 2.7 of its
// volume), so the step can be coarser for the same freedom. Each axis is scored as steer chooses:
// its spatial prediction while the error's rest point stays in the band, otherwise the smallest
// rest; the vertex takes the point of least total score. radius >= sqrt(3) / 2, so the ball always
// holds a point.
void steer_ball(const double* t, size_t n, uint32_t F, double radius, double band, size_t row,
                int32_t* Q) {
  for (size_t c = 0; c < n; ++c) {
    const int32_t q0 = std::fabs(t[c]) <= 0.5 * band ? 0 : int32_t(std::nearbyint(t[c]));
    Q[c] = q0;
    if (F > 1)
      Q[n + c] = std::fabs(q0 - t[n + c]) <= 0.5 * band ? q0 : int32_t(std::nearbyint(t[n + c]));
  }
  // What one axis can always choose either way while the other two take their nearest symbols.
  const double amin = std::max(0.25, std::sqrt(std::max(0.0, radius * radius - 0.5)) - 0.5);
  const double r2 = radius * radius;
  std::vector<int32_t> syms(n);
  for (uint32_t f = 2; f < F; ++f) {
    const double *t0 = t + size_t(f) * n, *t1 = t0 - n, *t2 = t1 - n;
    int32_t* q = Q + size_t(f) * n;
    const int32_t *q1 = q - n, *q2 = q1 - n;
    for (size_t c0 = 0; c0 + 3 <= n; c0 += 3) {
      double tpp[3], e1[3], v1[3], pred[3];
      int lo[3], hi[3];
      for (int a = 0; a < 3; ++a) {
        const size_t c = c0 + size_t(a);
        tpp[a] = t0[c] - 2 * t1[c] + t2[c];
        e1[a] = q1[c] - t1[c];
        v1[a] = e1[a] - (q2[c] - t2[c]);
        lo[a] = int(std::ceil(tpp[a] - radius));
        hi[a] = int(std::floor(tpp[a] + radius));
        pred[a] = double(spatial_prediction(syms.data(), c, row));
      }
      // Each axis's score for a symbol: 0 for its prediction within the band, 1 for another symbol
      // within the band, beyond the band 1000 + how far the error would come to rest.
      auto score = [&](int a, double sym) {
        const double v = v1[a] + (sym - tpp[a]), e = e1[a] + v;
        const double rest = std::fabs(e + v * std::fabs(v) / (2 * amin));
        if (rest > band) return 1000 + rest;
        return sym == pred[a] ? 0.0 : 1.0 + 1e-3 * std::fabs(sym - pred[a]);
      };
      double best = HUGE_VAL;
      double pick[3] = {std::nearbyint(tpp[0]), std::nearbyint(tpp[1]), std::nearbyint(tpp[2])};
      for (int x = lo[0]; x <= hi[0]; ++x) {
        const double dx = x - tpp[0], sx = score(0, x);
        for (int y = lo[1]; y <= hi[1]; ++y) {
          const double dy = y - tpp[1];
          if (dx * dx + dy * dy > r2) continue;
          const double sy = sx + score(1, y);
          for (int z = lo[2]; z <= hi[2]; ++z) {
            const double dz = z - tpp[2];
            if (dx * dx + dy * dy + dz * dz > r2) continue;
            const double total = sy + score(2, z);
            if (total < best) {
              best = total;
              pick[0] = x;
              pick[1] = y;
              pick[2] = z;
            }
          }
        }
      }
      for (int a = 0; a < 3; ++a) {
        const size_t c = c0 + size_t(a);
        syms[c] = int32_t(pick[a]);
        q[c] = int32_t(2 * q1[c] - q2[c] + int64_t(pick[a]));
      }
    }
  }
}

}  // namespace

std::vector<uint8_t> encode_v3(const float* frames, uint32_t F, uint32_t V, const Basis& basis,
                               const V3Settings& settings, V3Stats* stats) {
  const Contract& cap = settings.contract;
  if (F == 0 || V == 0)
    throw ClothdbError(Status::InvalidArgument, "encode_v3: no frames or no vertices");
  if (!(cap.rms > 0) || !(cap.max > 0) || !(cap.jitter > 0))
    throw ClothdbError(Status::InvalidArgument,
                       "encode_v3: the contract needs positive RMS, max and jitter caps");
  const size_t n = size_t(V) * 3;
  if (basis.vertex_count != V || basis.mean.size() != n)
    throw ClothdbError(Status::InvalidArgument, "encode_v3: basis of " +
                                                    std::to_string(basis.vertex_count) +
                                                    " vertices for frames of " + std::to_string(V));
  if (settings.zstd_level < ZSTD_minCLevel() || settings.zstd_level > ZSTD_maxCLevel())
    throw ClothdbError(Status::InvalidArgument, "encode_v3: zstd level out of range");
  if (settings.segment_frames == 0 || settings.segment_frames > kMaxSegmentFrames)
    throw ClothdbError(Status::InvalidArgument, "encode_v3: segment frames out of range (1.." +
                                                    std::to_string(kMaxSegmentFrames) + ")");
  for (size_t i = 0; i < size_t(F) * n; ++i)
    if (!std::isfinite(frames[i]))
      throw ClothdbError(Status::InvalidArgument, "encode_v3: non-finite coordinate");
  const uint32_t M =
      settings.modes == 0 ? basis.mode_count : std::min(settings.modes, basis.mode_count);
  const uint32_t K = std::min(settings.segment_frames, F);
  // Coefficients: a coefficient's error e reaches a coordinate as e x (the mode's entry, about
  // 1 / sqrt(3V)); a step of half the jitter cap keeps their jitter far below it.
  const double cstep = settings.coefficient_step > 0 ? settings.coefficient_step : 0.5 * cap.jitter;
  std::vector<int32_t> q(size_t(F) * M);
  for (uint32_t f = 0; f < F; ++f) {
    const float* x = frames + size_t(f) * n;
    for (uint32_t k = 0; k < M; ++k) {
      const float* u = basis.modes.data() + size_t(k) * n;
      double dot = 0, uu = 0;
      for (size_t i = 0; i < n; ++i) {
        dot += double(u[i]) * (double(x[i]) - double(basis.mean[i]));
        uu += double(u[i]) * double(u[i]);
      }
      q[size_t(f) * M + k] = quantise(uu > 0 ? dot / uu : 0.0, cstep, "a coefficient");
    }
  }
  // What the decoded modes leave, in metres.
  std::vector<float> decoded(size_t(F) * n);
  for (uint32_t f0 = 0; f0 < F; f0 += K) {
    const uint32_t k = std::min(K, F - f0);
    reconstruct(basis, M, q.data() + size_t(f0) * M, cstep, nullptr, 0, k,
                decoded.data() + size_t(f0) * n, n);
  }
  std::vector<double> T(size_t(F) * n);
  for (size_t i = 0; i < T.size(); ++i) T[i] = double(frames[i]) - double(decoded[i]);
  // Attempts, cheapest first: no residual; then the steered residual at the coarsest step the
  // jitter cap allows (per coordinate J / sqrt(3), so the vertex's second difference stays under
  // J) with the error's band at the RMS cap over sqrt(3) (a coordinate's share), then narrower
  // bands and finer steps. Each is decoded and measured.
  struct Attempt {
    double step, band;  // m
    bool ball = false;  // steer_ball (step: radius 0.98 J / step) instead of steer
  };
  const double j = cap.jitter / std::sqrt(3.0);
  const double band0 = std::min(cap.rms, 0.5 * cap.max) / std::sqrt(3.0);
  std::vector<Attempt> attempts = {{0, 0}};
  // First the jitter cap on the vertex (steer_ball) at a step of J: a radius of 0.98 steps, where
  // the axis-by-axis steer needs a step of 0.98 J / sqrt(3). Measured on the whole-motion skirt
  // (docs/notebook/codec_v3.md, "Decoding speed, and the residual's ball"): 18.14 -> 16.04 bits per
  // vertex-frame at RMS 1 / max 3 / jitter 0.1 mm (steps of 0.7, 0.8, 1.1 and 1.13 J: 17.25,
  // 16.79, 16.50, 16.61). Where the controller then loses the error, the finer attempts follow.
  for (double k : {1.0, 0.5, 0.25}) attempts.push_back({cap.jitter, band0 * k, true});
  for (double k : {1.0, 0.5, 0.25, 0.125}) attempts.push_back({0.98 * j, band0 * k});
  for (double k : {0.5, 0.25}) attempts.push_back({0.98 * j * k, band0 * 0.125});
  if (settings.residual_row >= int64_t(V))
    throw ClothdbError(Status::InvalidArgument, "encode_v3: residual predictor row " +
                                                    std::to_string(settings.residual_row) + " of " +
                                                    std::to_string(V) + " vertices");
  const uint32_t row =
      settings.residual_row < 0 ? choose_residual_row(basis) : uint32_t(settings.residual_row);
  DecodeScratch scratch;
  std::vector<int32_t> Q, none;
  std::vector<double> t(T.size());
  int tried = 0;
  ContractFigures figures;
  for (const Attempt& a : attempts) {
    ++tried;
    Q.clear();
    uint64_t nonzero = 0, symbols = 0;
    if (a.step > 0) {
      Q.resize(size_t(F) * n);
      for (size_t i = 0; i < T.size(); ++i) t[i] = T[i] / a.step;
      for (double v : t)
        if (std::fabs(v) > double(kMaxInt) / 4)
          throw ClothdbError(Status::InvalidArgument,
                             "encode_v3: the residual does not fit its step");
      if (a.ball)
        steer_ball(t.data(), n, F, 0.98 * cap.jitter / a.step, a.band / a.step, row, Q.data());
      else
        steer(t.data(), n, F, 0.98 * j / a.step, a.band / a.step, row, Q.data());
      std::vector<int32_t> syms(n);
      for (uint32_t f = 0; f < F; ++f) {
        if (f % K < 2) continue;
        for (size_t c = 0; c < n; ++c) {
          const size_t i = size_t(f) * n + c;
          syms[c] = Q[i] - 2 * Q[i - n] + Q[i - 2 * n];
          nonzero += syms[c] != spatial_prediction(syms.data(), c, row);
        }
        symbols += n;
      }
      for (int32_t v : Q)
        if (v > kMaxInt / 2 || v < -kMaxInt / 2)
          throw ClothdbError(Status::InvalidArgument,
                             "encode_v3: the residual does not fit its step");
    }
    V3Stats parts;
    std::vector<uint8_t> blob = assemble(V, F, basis, M, K, cstep, q, a.step, a.step > 0 ? Q : none,
                                         row, settings.zstd_level, &parts);
    Error err;
    std::vector<float>& out = decoded;
    if (decode_frames(blob.data(), blob.size(), 0, F, out.data(), out.size(), scratch, &err,
                      &basis) != Status::Ok)
      throw ClothdbError(Status::Corrupt,
                         std::string("encode_v3: own blob does not decode: ") + err.message);
    figures = measure_contract(out.data(), frames, F, V);
    if (within(figures, cap)) {
      if (stats) {
        *stats = parts;
        stats->figures = figures;
        stats->residual_interval = a.step > 0 ? 1 : 0;
        stats->residual_step = a.step;
        stats->residual_band = a.band;
        stats->attempts = tried;
        stats->modes = M;
        stats->residual_symbols = symbols;
        stats->residual_nonzero = nonzero;
        stats->residual_row = a.step > 0 ? row : 0;
      }
      return blob;
    }
  }
  throw ClothdbError(
      Status::InvalidArgument,
      "encode_v3: contract not met even with the finest residual: " + describe(figures));
}

}  // namespace clothdb::codec
