// Codec version 3 (docs/DATABASE.md, "version 3"): a clip as the coefficients of the garment's
// subspace (Kim et al. 2013, section 6: a few hundred PCA modes per garment) plus, only where the
// error contract (contract.hpp) needs it, a residual that is smooth in time: a uniform cubic
// B-spline over frames whose control points are least-squares fits of what the modes leave.
// Every part of the coding error is smooth in time or tiny, so the jitter a player would see stays
// under its cap:
//  - coefficients are quantised finely (their error reaches a coordinate scaled by about
//    sqrt(modes / 3V)) and coded as their second difference in time (integers, so the decoder's
//    coefficients are exactly the encoder's);
//  - what the modes leave of a smooth motion is smooth;
//  - the B-spline's second difference is that of its control points divided by R^2 (R frames
//    between knots), so quantising control points coarsely adds little jitter.
// The encoder measures the contract on the decoded clip against its input and tries cheaper
// residuals first (none, then knots every 16, 8, 4, 2, 1 frames, each at a coarse step and 1/2,
// 1/4, 1/8 of it); the first that holds is kept.
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
//   0 magic "CLDF" | 4 u16 version (3) | 6 u16 header size (80) | 8 u32 vertices | 12 u32 frames
//  16 u32 modes | 20 u32 residual knot interval R (0: no residual) | 24 i64 basis id
//  32 f64 coefficient step | 40 f64 residual step | 48 u32 control points P (0 without residual)
//  52 u32 payload bytes before zstd | 56 u32 payload bytes (zstd) | 60 u32 reserved (0)
//  64 u64 XXH64 of the payload | 72 u64 XXH64 of bytes 0..71 | 80 the payload (one zstd frame).
// Payload before zstd: N = F x modes + P x 3V zigzagged int32 split into 4 byte planes (all
// low bytes, then all second bytes, ...): first the coefficients' second differences in time
// (frame-major; frame 0 as is, frame 1 minus frame 0), then the control points' differences from
// the previous point (control point-major, x y z per vertex; point 0 as is).
constexpr size_t kHeaderSize = 80;
constexpr size_t kChecksumOffset = 72;
constexpr int32_t kMaxInt = (1 << 27) - 1;  // so 2 a - b never overflows int32
constexpr double kMaxStep = 1e3;
constexpr uint32_t kMaxKnotInterval = 1024;

struct Header {
  uint32_t V = 0, F = 0, modes = 0, R = 0, P = 0, raw = 0, csize = 0;
  int64_t basis_id = 0;
  double cstep = 0, rstep = 0;
};

Status parse_header(const uint8_t* blob, size_t size, Header* h, Error* err) {
  if (size < kHeaderSize)
    return fail(err, Status::Truncated, "frame blob truncated: %zu bytes, header needs %zu", size,
                kHeaderSize);
  const uint64_t stored = get_u64(blob + kChecksumOffset);
  const uint64_t actual = xxh64(blob, kChecksumOffset);
  if (stored != actual)
    return fail(err, Status::ChecksumMismatch,
                "frame blob header checksum mismatch (stored %016llx, computed %016llx)",
                (unsigned long long)stored, (unsigned long long)actual);
  if (get_u16(blob + 6) != kHeaderSize)
    return fail(err, Status::Corrupt, "frame blob (codec version 3): header size %u, expected %zu",
                get_u16(blob + 6), kHeaderSize);
  h->V = get_u32(blob + 8);
  h->F = get_u32(blob + 12);
  h->modes = get_u32(blob + 16);
  h->R = get_u32(blob + 20);
  h->basis_id = int64_t(get_u64(blob + 24));
  h->cstep = get_f64(blob + 32);
  h->rstep = get_f64(blob + 40);
  h->P = get_u32(blob + 48);
  h->raw = get_u32(blob + 52);
  h->csize = get_u32(blob + 56);
  if (h->V == 0 || h->V > kMaxVertices)
    return fail(err, Status::Corrupt, "frame blob: %u vertices (1..%u)", h->V, kMaxVertices);
  if (h->F == 0) return fail(err, Status::Corrupt, "frame blob: 0 frames");
  if (h->modes > kMaxBasisModes)
    return fail(err, Status::Corrupt, "frame blob: %u modes (at most %u)", h->modes,
                kMaxBasisModes);
  if (!(h->cstep > 0 && h->cstep <= kMaxStep) ||
      (h->R > 0 && !(h->rstep > 0 && h->rstep <= kMaxStep)))
    return fail(err, Status::Corrupt, "frame blob: coefficient or residual step out of range");
  if (h->R > kMaxKnotInterval)
    return fail(err, Status::Corrupt, "frame blob: residual knot interval %u (at most %u)", h->R,
                kMaxKnotInterval);
  const uint64_t segments =
      h->R == 0 ? 0 : std::max<uint64_t>(1, (uint64_t(h->F) - 1 + h->R - 1) / h->R);
  const uint64_t P = h->R == 0 ? 0 : segments + 3;
  if (P != h->P)
    return fail(err, Status::Corrupt,
                "frame blob: %u control points, %u frames at interval %u need %llu", h->P, h->F,
                h->R, (unsigned long long)P);
  const uint64_t ints = uint64_t(h->F) * h->modes + P * 3 * h->V;
  if (ints * 4 != h->raw || ints > kMaxChunkFloats)
    return fail(err, Status::Corrupt, "frame blob: payload of %u bytes does not fit its counts",
                h->raw);
  if (get_u32(blob + 60) != 0)
    return fail(err, Status::Corrupt, "frame blob header: reserved bytes set");
  if (size != kHeaderSize + uint64_t(h->csize)) {
    if (size < kHeaderSize + uint64_t(h->csize))
      return fail(err, Status::Truncated, "frame blob truncated: %zu bytes, header says %llu", size,
                  (unsigned long long)(kHeaderSize + uint64_t(h->csize)));
    return fail(err, Status::Corrupt, "frame blob: %zu bytes, header says %llu", size,
                (unsigned long long)(kHeaderSize + uint64_t(h->csize)));
  }
  return Status::Ok;
}

// Uniform cubic B-spline weights at u in [0, 1] (de Boor; the segment's four control points).
void bspline_weights(double u, double w[4]) {
  const double u2 = u * u, u3 = u2 * u, v = 1 - u;
  w[0] = v * v * v / 6;
  w[1] = (3 * u3 - 6 * u2 + 4) / 6;
  w[2] = (-3 * u3 + 3 * u2 + 3 * u + 1) / 6;
  w[3] = u3 / 6;
}

// Frame f's segment (first control point) and weights for knots every R frames, P points.
uint32_t segment(uint32_t f, uint32_t R, uint32_t P, double w[4]) {
  const uint32_t i = std::min(f / R, P - 4);
  bspline_weights(double(f - i * R) / double(R), w);
  return i;
}

// One frame of the subspace: mean + sum_k c_k modes[k] in float, the same order in encoder and
// decoder (the library is built with -ffp-contract=off).
void subspace_frame(const Basis& b, uint32_t modes, const int32_t* q, double cstep, float* out,
                    size_t n) {
  std::memcpy(out, b.mean.data(), n * sizeof(float));
  for (uint32_t k = 0; k < modes; ++k) {
    const float w = float(double(q[k]) * cstep);
    if (w == 0.0f) continue;
    const float* u = b.modes.data() + size_t(k) * n;
    for (size_t i = 0; i < n; ++i) out[i] += w * u[i];
  }
}

void add_residual(const int32_t* Q, uint32_t f, uint32_t R, uint32_t P, double rstep, float* out,
                  size_t n) {
  double w[4];
  const uint32_t i = segment(f, R, P, w);
  const int32_t* q0 = Q + size_t(i) * n;
  for (size_t c = 0; c < n; ++c) {
    const double r = w[0] * q0[c] + w[1] * q0[n + c] + w[2] * q0[2 * n + c] + w[3] * q0[3 * n + c];
    out[c] += float(r * rstep);
  }
}

}  // namespace

struct DecoderV3Access {
  // Decompresses and checks the payload into s.v3_ints_ (coefficients F x modes, then control
  // points P x 3V), unless the scratch already holds this blob's (same header checksum).
  static Status load(const uint8_t* blob, const Header& h, DecodeScratch& s, Error* err) {
    const uint8_t* src = blob + kHeaderSize;
    if (xxh64(src, h.csize) != get_u64(blob + 64))
      return fail(err, Status::ChecksumMismatch, "frame blob payload checksum mismatch");
    const uint64_t key = get_u64(blob + kChecksumOffset);
    if (s.v3_key_ == key && s.v3_valid_) return Status::Ok;
    s.v3_valid_ = false;
    const unsigned long long declared = ZSTD_getFrameContentSize(src, h.csize);
    if (declared != h.raw)
      return fail(err, Status::Corrupt, "frame blob: zstd frame declares %llu bytes, expected %u",
                  declared, h.raw);
    if (s.bytes_.size() < h.raw) s.bytes_.resize(h.raw);
    const size_t got =
        ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(s.dctx_), s.bytes_.data(), h.raw, src, h.csize);
    if (ZSTD_isError(got))
      return fail(err, Status::Corrupt, "frame blob: zstd: %s", ZSTD_getErrorName(got));
    if (got != h.raw)
      return fail(err, Status::Corrupt, "frame blob: %zu bytes decompressed of %u", got, h.raw);
    const size_t N = h.raw / 4;
    if (s.v3_ints_.size() < N) s.v3_ints_.resize(N);
    int32_t* v = s.v3_ints_.data();
    const uint8_t* b = s.bytes_.data();
    for (size_t i = 0; i < N; ++i)
      v[i] = int32_t(unzigzag(uint32_t(b[i]) | uint32_t(b[N + i]) << 8 |
                              uint32_t(b[2 * N + i]) << 16 | uint32_t(b[3 * N + i]) << 24));
    // Coefficients: second differences in time, back to values (wrapping, then range-checked).
    const uint32_t M = h.modes;
    for (uint32_t f = 0; f < h.F; ++f)
      for (uint32_t k = 0; k < M; ++k) {
        const size_t i = size_t(f) * M + k;
        const uint32_t pred = f == 0   ? 0u
                              : f == 1 ? uint32_t(v[i - M])
                                       : 2 * uint32_t(v[i - M]) - uint32_t(v[i - 2 * M]);
        const int32_t x = int32_t(pred + uint32_t(v[i]));
        if (x > kMaxInt || x < -kMaxInt)
          return fail(err, Status::Corrupt, "frame blob: coefficient out of range");
        v[i] = x;
      }
    const size_t n = size_t(h.V) * 3;
    int32_t* Q = v + size_t(h.F) * M;
    for (uint32_t j = 1; j < h.P; ++j)
      for (size_t c = 0; c < n; ++c) {
        const size_t i = size_t(j) * n + c;
        const int32_t x = int32_t(uint32_t(Q[i - n]) + uint32_t(Q[i]));
        if (x > kMaxInt || x < -kMaxInt)
          return fail(err, Status::Corrupt, "frame blob: residual control point out of range");
        Q[i] = x;
      }
    s.v3_key_ = key;
    s.v3_valid_ = true;
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
    if (out == nullptr) {  // verify: the whole payload, no output
      first = 0;
      count = 0;
    } else if (first >= h.F || count > h.F - first) {
      return fail(err, Status::InvalidArgument, "frames %u..%u requested from a %u-frame blob",
                  first, first + count - 1, h.F);
    } else if (out_floats < size_t(count) * n) {
      return fail(err, Status::OutputTooSmall, "output holds %zu floats, %u frames need %zu",
                  out_floats, count, size_t(count) * n);
    }
    if (Status st = load(blob, h, s, err); st != Status::Ok) return st;
    const int32_t* q = s.v3_ints_.data();
    const int32_t* Q = q + size_t(h.F) * h.modes;
    for (uint32_t j = 0; j < count; ++j) {
      const uint32_t f = first + j;
      float* o = out + size_t(j) * n;
      subspace_frame(*basis, h.modes, q + size_t(f) * h.modes, h.cstep, o, n);
      if (h.R > 0) add_residual(Q, f, h.R, h.P, h.rstep, o, n);
      ++s.frames_reconstructed_;
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
  in.key_interval = h.F;  // the payload is one unit: any frame costs one frame once it is loaded
  in.chunk_count = 1;
  in.step = h.rstep;
  in.size = size;
  in.basis_id = h.basis_id;
  in.modes = h.modes;
  in.coefficient_step = h.cstep;
  in.uses_mean = true;
  in.residual_interval = h.R;
  *info = in;
  return Status::Ok;
}

Status decode(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
              size_t out_floats, DecodeScratch& scratch, Error* err, const Basis* basis) {
  return DecoderV3Access::decode(blob, size, first, count, out, out_floats, scratch, err, basis);
}

void reseal(uint8_t* blob, size_t size) {
  if (size < kHeaderSize) return;
  const uint32_t csize = get_u32(blob + 56);
  if (kHeaderSize + uint64_t(csize) <= size) put_u64(blob + 64, xxh64(blob + kHeaderSize, csize));
  put_u64(blob + kChecksumOffset, xxh64(blob, kChecksumOffset));
}

ChunkSpan payload(const uint8_t* blob) {
  return {kHeaderSize, get_u32(blob + 56)};
}

}  // namespace v3

namespace {

// Least-squares control points (P x n, point-major) of a uniform cubic B-spline with knots every R
// frames through T (F x n), with a small penalty on the control points' second difference so the
// system is well posed when P > F (short clips, R = 1) and the points stay smooth (cheap to code).
// The normal matrix is banded (width 3): Cholesky in O(P), solved for all n columns at once.
std::vector<double> fit_bspline(const std::vector<double>& T, uint32_t F, size_t n, uint32_t R,
                                uint32_t P) {
  std::vector<double> N(size_t(P) * P, 0.0), B(size_t(P) * n, 0.0);
  double w[4];
  for (uint32_t f = 0; f < F; ++f) {
    const uint32_t i = segment(f, R, P, w);
    for (int a = 0; a < 4; ++a) {
      for (int b = 0; b < 4; ++b) N[size_t(i + a) * P + (i + b)] += w[a] * w[b];
      double* dst = B.data() + size_t(i + a) * n;
      const double* src = T.data() + size_t(f) * n;
      for (size_t c = 0; c < n; ++c) dst[c] += w[a] * src[c];
    }
  }
  // With knots every frame (R = 1) the spline must follow the frames exactly, noise included (the
  // contract is against them), so its penalty is only what keeps the system well posed.
  const double mu = R == 1 ? 1e-9 : 1e-4, ridge = 1e-12;
  const double d[3] = {1, -2, 1};
  for (uint32_t r = 0; r + 2 < P; ++r)
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) N[size_t(r + a) * P + (r + b)] += mu * d[a] * d[b];
  for (uint32_t i = 0; i < P; ++i) N[size_t(i) * P + i] += ridge;
  // Banded Cholesky N = L L^T (L in the lower triangle of N).
  for (uint32_t i = 0; i < P; ++i) {
    const uint32_t lo = i >= 3 ? i - 3 : 0;
    for (uint32_t j = lo; j <= i; ++j) {
      double sum = N[size_t(i) * P + j];
      for (uint32_t k = std::max(lo, j >= 3 ? j - 3 : 0); k < j; ++k)
        sum -= N[size_t(i) * P + k] * N[size_t(j) * P + k];
      N[size_t(i) * P + j] = j == i ? std::sqrt(std::max(sum, 1e-300)) : sum / N[size_t(j) * P + j];
    }
  }
  for (uint32_t i = 0; i < P; ++i) {  // forward: L y = b
    double* x = B.data() + size_t(i) * n;
    for (uint32_t k = i >= 3 ? i - 3 : 0; k < i; ++k) {
      const double l = N[size_t(i) * P + k];
      const double* y = B.data() + size_t(k) * n;
      for (size_t c = 0; c < n; ++c) x[c] -= l * y[c];
    }
    const double inv = 1 / N[size_t(i) * P + i];
    for (size_t c = 0; c < n; ++c) x[c] *= inv;
  }
  for (uint32_t i = P; i-- > 0;) {  // backward: L^T x = y
    double* x = B.data() + size_t(i) * n;
    for (uint32_t k = i + 1; k < std::min(P, i + 4); ++k) {
      const double l = N[size_t(k) * P + i];
      const double* y = B.data() + size_t(k) * n;
      for (size_t c = 0; c < n; ++c) x[c] -= l * y[c];
    }
    const double inv = 1 / N[size_t(i) * P + i];
    for (size_t c = 0; c < n; ++c) x[c] *= inv;
  }
  return B;
}

std::vector<uint8_t> assemble(uint32_t V, uint32_t F, const Basis& basis, uint32_t modes,
                              double cstep, const std::vector<int32_t>& q, uint32_t R, double rstep,
                              const std::vector<int32_t>& Q, int level) {
  const size_t n = size_t(V) * 3;
  const uint32_t P = R == 0 ? 0 : uint32_t(Q.size() / n);
  const size_t N = size_t(F) * modes + size_t(P) * n;
  std::vector<uint8_t> raw(4 * N);
  auto put = [&](size_t i, int32_t r) {
    const uint32_t z = zigzag(uint32_t(r));
    raw[i] = uint8_t(z);
    raw[N + i] = uint8_t(z >> 8);
    raw[2 * N + i] = uint8_t(z >> 16);
    raw[3 * N + i] = uint8_t(z >> 24);
  };
  for (uint32_t f = 0; f < F; ++f)
    for (uint32_t k = 0; k < modes; ++k) {
      const size_t i = size_t(f) * modes + k;
      const int32_t pred = f == 0 ? 0 : f == 1 ? q[i - modes] : 2 * q[i - modes] - q[i - 2 * modes];
      put(i, q[i] - pred);
    }
  const size_t base = size_t(F) * modes;
  // Control points by their difference from the previous one: measured smaller than the second
  // difference on the whole-motion skirt (2.9:1 against 3.1:1 overall), where the residual the
  // modes leave is noisy from frame to frame.
  for (size_t i = 0; i < size_t(P) * n; ++i) put(base + i, i < n ? Q[i] : Q[i] - Q[i - n]);
  std::vector<uint8_t> blob(kHeaderSize + ZSTD_compressBound(raw.size()));
  const size_t csize = ZSTD_compress(blob.data() + kHeaderSize, blob.size() - kHeaderSize,
                                     raw.data(), raw.size(), level);
  if (ZSTD_isError(csize))
    throw ClothdbError(Status::InvalidArgument,
                       std::string("encode_v3: zstd failed: ") + ZSTD_getErrorName(csize));
  blob.resize(kHeaderSize + csize);
  uint8_t* h = blob.data();
  std::memcpy(h, kMagic, 4);
  put_u16(h + 4, uint16_t(kFormatVersionV3));
  put_u16(h + 6, uint16_t(kHeaderSize));
  put_u32(h + 8, V);
  put_u32(h + 12, F);
  put_u32(h + 16, modes);
  put_u32(h + 20, R);
  put_u64(h + 24, uint64_t(basis.id));
  put_f64(h + 32, cstep);
  put_f64(h + 40, R == 0 ? 0.0 : rstep);
  put_u32(h + 48, P);
  put_u32(h + 52, uint32_t(raw.size()));
  put_u32(h + 56, uint32_t(csize));
  put_u32(h + 60, 0);
  v3::reseal(blob.data(), blob.size());
  return blob;
}

int32_t quantise(double x, double step, const char* what) {
  const double q = std::nearbyint(x / step);
  if (!(std::fabs(q) <= double(kMaxInt)))
    throw ClothdbError(Status::InvalidArgument,
                       std::string("encode_v3: ") + what + " does not fit its step");
  return int32_t(q);
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
  for (size_t i = 0; i < size_t(F) * n; ++i)
    if (!std::isfinite(frames[i]))
      throw ClothdbError(Status::InvalidArgument, "encode_v3: non-finite coordinate");
  const uint32_t M =
      settings.modes == 0 ? basis.mode_count : std::min(settings.modes, basis.mode_count);
  // Coefficients: a coefficient's error e reaches a coordinate as e x (the mode's entry, about
  // 1 / sqrt(3V)); a step of half the jitter cap keeps their jitter far below it.
  const double cstep = settings.coefficient_step > 0 ? settings.coefficient_step : 0.5 * cap.jitter;
  std::vector<int32_t> q(size_t(F) * M);
  std::vector<double> T(size_t(F) * n);  // what the (quantised) modes leave
  std::vector<float> y(n);
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
    subspace_frame(basis, M, q.data() + size_t(f) * M, cstep, y.data(), n);
    for (size_t i = 0; i < n; ++i) T[size_t(f) * n + i] = double(x[i]) - double(y[i]);
  }
  // Attempts, cheapest first: no residual; then knots every R frames at a coarse step (R^2 J / 4:
  // its quantisation then adds at most about J / 2 of jitter, see the file comment) and finer ones.
  struct Attempt {
    uint32_t R;
    double rstep;
  };
  std::vector<Attempt> attempts = {{0, 0}};
  for (uint32_t R : {16u, 8u, 4u, 2u, 1u}) {
    if (R > 1 && R >= 2 * F) continue;
    const double coarse = std::min(0.5 * cap.rms, 0.25 * double(R) * R * cap.jitter);
    for (double k : {1.0, 2.0, 4.0, 8.0}) attempts.push_back({R, coarse / k});
  }
  DecodeScratch scratch;
  std::vector<float> decoded(size_t(F) * n);
  std::vector<int32_t> Q;
  std::vector<uint8_t> best;
  int tried = 0;
  ContractFigures figures;
  uint32_t fitted_R = 0;
  std::vector<double> control;
  for (const Attempt& a : attempts) {
    ++tried;
    Q.clear();
    if (a.R > 0) {
      const uint32_t segments = std::max<uint32_t>(1, (F - 1 + a.R - 1) / a.R);
      const uint32_t P = segments + 3;
      if (fitted_R != a.R) {
        control = fit_bspline(T, F, n, a.R, P);
        fitted_R = a.R;
      }
      Q.resize(control.size());
      for (size_t i = 0; i < control.size(); ++i)
        Q[i] = quantise(control[i], a.rstep, "a residual control point");
    }
    std::vector<uint8_t> blob =
        assemble(V, F, basis, M, cstep, q, a.R, a.rstep, Q, settings.zstd_level);
    Error err;
    if (decode_frames(blob.data(), blob.size(), 0, F, decoded.data(), decoded.size(), scratch, &err,
                      &basis) != Status::Ok)
      throw ClothdbError(Status::Corrupt,
                         std::string("encode_v3: own blob does not decode: ") + err.message);
    figures = measure_contract(decoded.data(), frames, F, V);
    if (within(figures, cap)) {
      best = std::move(blob);
      if (stats) {
        stats->figures = figures;
        stats->residual_interval = a.R;
        stats->residual_step = a.rstep;
        stats->attempts = tried;
        stats->modes = M;
      }
      return best;
    }
  }
  throw ClothdbError(
      Status::InvalidArgument,
      "encode_v3: contract not met even with a residual every frame: " + describe(figures));
}

}  // namespace clothdb::codec
