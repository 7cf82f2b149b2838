// The cloth frame codec: N frames x V vertices (x, y, z float32 each, frames contiguous) into one
// self-describing blob, with a hard per-coordinate error bound.
//
// Pipeline (docs/DATABASE.md has the byte layout):
//  1. Quantise every coordinate against a per-blob reference: q = round((x - origin[axis]) / step)
//     with step just under 2 * bound, then check each coordinate's dequantised value against the
//     input (shrinking the step if float rounding ever breaks the bound), so the bound is a
//     promise.
//  2. Split the frames into chunks of K frames (K = key interval). The first frame of a chunk is a
//     key frame, predicted only spatially (from the previous vertex); the second from the previous
//     frame (delta); the others by delta or linear extrapolation 2 q[f-1] - q[f-2], or none (every
//     frame coded like a key frame, when motion is noisier than the shape). Optionally the
//     temporal residual is predicted again from the previous vertex's (motion shared by
//     neighbours). The encoder picks the cheapest combination per chunk. Prediction runs on
//     integers, so decoding is exact and never drifts.
//  3. Zigzag the residuals, split their bytes into planes (as many planes as the chunk's largest
//     residual needs), compress each chunk with zstd.
//  4. XXH64 checksum over the header and chunk table, and one per chunk.
// Decoding frame f touches only its chunk: at most K frame reconstructions (random access cost).
//
// Format version 2 (encode_v2) predicts every frame from a per-garment subspace (a
// Basis: mean + modes, stored once per database) and codes only coefficients and a residual layer
// on the same grid, so the bound is kept exactly as in version 1 (docs/DATABASE.md, "version 2").
// Version 1 blobs decode exactly as before; decoding a version 2 blob needs its basis.
//
// Format version 3 (encode_v3) keeps an error contract in what a player sees (contract.hpp: RMS,
// max and jitter caps) instead of a per-coordinate bound: subspace coefficients plus a residual
// steered so the coding error stays smooth in time, in segments that decode on their own
// (docs/DATABASE.md, "version 3"). It needs its basis like version 2.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "database/codec/contract.hpp"
#include "database/format/status.hpp"

namespace clothdb::codec {

constexpr uint32_t kFormatVersion = 1;    // what encode() writes
constexpr uint32_t kFormatVersionV2 = 2;  // what encode_v2() writes
constexpr uint32_t kFormatVersionV3 = 3;  // what encode_v3() writes
// The newest frame format this build reads: blobs and files (meta codec.format_version) of a newer
// one are refused with Status::NewerVersion.
constexpr uint32_t kNewestFormatVersion = kFormatVersionV3;
constexpr double kDefaultPositionBound = 0.0005;  // m: 0.5 mm per coordinate
// A key frame every 4 frames: random access costs at most 4 frame reconstructions, and on
// simulated garments the ratio is within 1 % of K = 16 or 64 (docs/notebook/BENCHMARKS.md, Codec).
constexpr uint32_t kDefaultKeyInterval = 4;
// zstd level 9: about 12 % smaller than level 3 on simulated cloth and faster to decode; encoding
// (6 MB/s per core) stays several times faster than a solver produces frames.
constexpr int kDefaultZstdLevel = 9;

// Hard limits the decoder enforces before allocating anything, so a hostile header cannot ask for
// gigabytes: 4 M vertices, and 1 GiB of float output per chunk.
constexpr uint32_t kMaxVertices = 1u << 22;
constexpr uint64_t kMaxChunkFloats = uint64_t(1) << 28;
// Basis limits: at most 1024 modes and 2^28 mode values (512 MiB as int16) in one basis.
constexpr uint32_t kMaxBasisModes = 1024;
constexpr uint64_t kMaxBasisValues = uint64_t(1) << 28;

enum class Predictor : uint8_t {
  Auto = 0,    // per chunk, the cheaper of Delta and Linear (encoder setting only)
  Delta = 1,   // q[f] predicted by q[f-1]
  Linear = 2,  // q[f] predicted by 2 q[f-1] - q[f-2]
  None = 3,    // no temporal prediction: every frame coded from its own neighbours
};

enum class SpatialMode : uint8_t {
  Auto = 0,  // per chunk, whichever needs fewer bits
  Off = 1,
  On = 2,  // temporal residuals predicted by the previous vertex's residual
};

enum class GridMode : uint8_t {
  Auto = 0,   // encode with both grids, keep the smaller blob (twice the encode time)
  Plain = 1,  // step just under 2 * bound: one valid value per coordinate, nearest rounding
  Fine = 2,   // step just under bound: two or three valid values; each takes the one nearest
              // its prediction, so smooth motion leaves more zero residuals
};

struct EncodeSettings {
  double bound = kDefaultPositionBound;         // max |decoded - input| per coordinate, input units
  uint32_t key_interval = kDefaultKeyInterval;  // key frame every K frames; 0 = only frame 0
  int zstd_level = kDefaultZstdLevel;
  Predictor predictor = Predictor::Auto;
  SpatialMode spatial = SpatialMode::Auto;
  GridMode grid = GridMode::Auto;
  // Decode the finished blob and compare with the input (costs about one decode). The quantiser
  // already checks each value; this also guards the integer pipeline.
  bool verify = true;
};

struct EncodeStats {
  double max_error = 0;  // max |decoded - input| over all coordinates (the bound if !verify)
  double step = 0;       // quantisation step used
  int step_retries = 0;  // how often float rounding forced a smaller step
  size_t raw_bytes = 0;  // frames * vertices * 3 * 4
  size_t encoded_bytes = 0;
};

// Encodes frame_count frames of vertex_count vertices (3 floats each). Throws ClothdbError
// (InvalidArgument) on empty input, non-finite coordinates, a non-positive bound, or a bound too
// small for the coordinates' float precision or range.
std::vector<uint8_t> encode(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                            const EncodeSettings& settings, EncodeStats* stats = nullptr);

struct BlobInfo {
  uint32_t version = 0;
  uint32_t vertex_count = 0;
  uint32_t frame_count = 0;
  uint32_t key_interval = 0;  // effective K (1..frame_count)
  uint32_t chunk_count = 0;
  double bound = 0;
  double step = 0;
  double origin[3] = {0, 0, 0};
  uint32_t qmax[3] = {0, 0, 0};
  uint32_t row_stride = 0;  // vertices per mesh row for the Lorenzo predictor (0: not used)
  size_t size = 0;          // bytes of the whole blob
  // Version 2 only (0 for version 1): the basis the blob is predicted from, how many of its modes
  // it uses, the coefficient quantisation step and whether the basis mean is added (positions) or
  // not (velocities: the derivative of mean + modes * c is modes * dc/dt).
  int64_t basis_id = 0;
  uint32_t modes = 0;
  double coefficient_step = 0;
  bool uses_mean = false;
  bool body_frame = false;  // per-frame rigid transforms stored (SubspaceSettings::body_frames)
  // Version 3 only: 1 when the blob carries a residual on every frame (0: none); `step` is then
  // the residual's quantisation step and `bound` 0 (the blob keeps a contract, not a bound).
  uint32_t residual_interval = 0;
};

// A garment subspace (docs/DATABASE.md, "version 2"): x ~ mean + sum_k c_k modes[k], over 3V
// coordinates (x, y, z per vertex). Built by precompute/compress/subspace.hpp (PCA of the
// database's own frames); stored once per database (table codec_basis) as float32 mean and int16
// modes with one float scale per mode, so `modes` here holds exactly float(int16) * scale: the
// encoder and every decoder multiply by the same floats.
struct Basis {
  int64_t id = 0;  // the codec_basis row id that version 2 blobs name
  uint32_t vertex_count = 0;
  uint32_t mode_count = 0;
  std::vector<float> mean;   // 3V
  std::vector<float> scale;  // one per mode
  std::vector<float> modes;  // mode_count x 3V, mode-major
  size_t memory_bytes() const {
    return (mean.capacity() + scale.capacity() + modes.capacity()) * sizeof(float);
  }
};

// Cloth relative to the body (SubspaceSettings::body_frames): out = R^T (x - t) for the n
// coordinates (3 per vertex) of one frame, in double from the transform T as stored (12 floats:
// R row by row, then t). What encode_v2 projects onto the modes, and what a body-frame basis is
// built from (precompute/compress/body_frame.hpp).
void to_body_frame(const float* T, const float* x, size_t n, double* out);

// Quantises float modes (mode_count x 3V, mode-major) to int16 with one scale per mode and returns
// the basis as stored. Throws ClothdbError (InvalidArgument) on non-finite values or limits.
Basis make_basis(int64_t id, uint32_t vertex_count, const float* mean, const float* modes,
                 uint32_t mode_count);
// The stored form: "CLBS", u16 version 1, u16 header size 24, u32 V, u32 M, u64 XXH64 of bytes
// 0..15 and the payload; payload: mean (3V float32), scales (M float32), modes (M x 3V int16).
std::vector<uint8_t> serialize_basis(const Basis& basis);
// Parses a stored basis (limits checked before allocating, checksum verified); sets basis->id.
Status parse_basis(const uint8_t* data, size_t size, int64_t id, Basis* basis, Error* err);

struct SubspaceSettings {
  // Coefficients are quantised with step = factor x bound: the error this adds to a coordinate is
  // about step / sqrt(12) x sqrt(modes / 3V), far below the bound for a few hundred modes.
  double coefficient_step_factor = 2.0;
  uint32_t modes = 0;      // modes of the basis to use (0: all)
  bool use_mean = true;    // false for velocities
  int grid_divisions = 0;  // grid step just under 2 x bound / divisions (1 or 2, 0: try both)
  // Cloth relative to the body (docs/DATABASE.md, "version 2"): per frame a rigid transform, 12
  // floats (the rotation R row by row, then the translation t), from the basis's body frame to the
  // frames' space. The subspace then predicts R^T (x - t) and each frame's prediction is R s + t,
  // so what the body carries (the pinned band's bob and tilt) is not paid for in coefficients. The
  // transforms are stored in the blob (48 bytes a frame before zstd); the residual stays on the
  // frames' grid, so the bound holds as without. Positions only (use_mean). Null: no body frame.
  const float* body_frames = nullptr;
};

// Encodes like encode() (same bound, key interval, zstd level, verification) as a version 2 blob
// predicted from `basis`. Throws ClothdbError (InvalidArgument) like encode(), and when the basis
// does not fit the frames' vertex count.
std::vector<uint8_t> encode_v2(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                               const Basis& basis, const EncodeSettings& settings,
                               const SubspaceSettings& subspace = {}, EncodeStats* stats = nullptr);

struct V3Settings {
  Contract contract;            // every cap positive (m)
  uint32_t modes = 0;           // modes of the basis to use (0: all)
  double coefficient_step = 0;  // m per coefficient unit; 0: half the jitter cap
  // Frames per segment (each decodable on its own: what a player stages at a time).
  uint32_t segment_frames = 32;
  // Row P of the residual's spatial predictor (docs/DATABASE.md "version 3"): -1 chooses it from
  // the basis's mean shape; 0 predicts from the previous vertex alone (the layout of blobs written
  // before the row existed).
  int64_t residual_row = -1;
  int zstd_level = kDefaultZstdLevel;
};

struct V3Stats {
  ContractFigures figures;         // measured on the decoded blob against the input
  uint32_t modes = 0;              // used
  uint32_t residual_interval = 0;  // 0: no residual was needed; 1: a residual on every frame
  double residual_step = 0;
  double residual_band = 0;  // m: the error the residual's controller lets drift before steering
  int attempts = 0;          // encodings tried (each decoded and measured)
  // Where the bytes go: the blob's header and segment table, the coefficients' and the residual's
  // compressed bytes (each part compressed alone, so the two add up to about the payload).
  size_t header_bytes = 0, coefficient_bytes = 0, residual_bytes = 0;
  // Residual symbols (coordinate-frames after each segment's first two) that are not 0.
  uint64_t residual_symbols = 0, residual_nonzero = 0;
  uint32_t residual_row = 0;  // row P of the residual's spatial predictor (0: previous vertex)
};

// Encodes frame_count frames as a version 3 blob predicted from `basis` (positions; the mean is
// added) within settings.contract, measured on the decoded blob against `frames`. Throws
// ClothdbError (InvalidArgument) on bad input, a basis that does not fit, or a contract that even
// a residual on every frame cannot meet.
std::vector<uint8_t> encode_v3(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                               const Basis& basis, const V3Settings& settings,
                               V3Stats* stats = nullptr);

// Validates the header, the chunk table and their checksum (not the chunks' contents). Cheap.
Status read_info(const uint8_t* blob, size_t size, BlobInfo* info, Error* err);

// Where one chunk's compressed bytes lie in a blob (either version).
struct ChunkSpan {
  size_t offset = 0;  // from the blob's first byte
  uint32_t size = 0;  // compressed bytes
};
// The chunks of a blob whose header and chunk table validate (read_info), in order: for tools
// that measure the compressed chunks (bench runtime's zstd share, db check's per-chunk figures),
// so nothing outside the codec reads the header or the chunk table.
Status chunk_spans(const uint8_t* blob, size_t size, std::vector<ChunkSpan>* out, Error* err);

// An SQL condition true when the blob in column `column` is of format `version` (1..255), for
// counting blobs by version without reading them (db info).
std::string version_is_sql(const std::string& column, uint32_t version);

// Reusable decoder state: a zstd context and buffers. Once reserve() has been called for the
// largest blob (or after the first decode of it), decoding allocates nothing.
class DecodeScratch {
 public:
  DecodeScratch();
  ~DecodeScratch();
  DecodeScratch(const DecodeScratch&) = delete;
  DecodeScratch& operator=(const DecodeScratch&) = delete;
  DecodeScratch(DecodeScratch&& other) noexcept;
  DecodeScratch& operator=(DecodeScratch&& other) noexcept;

  void reserve(uint32_t vertex_count, uint32_t key_interval, uint32_t modes = 0);

  // Bytes the scratch's buffers hold (not the zstd context): what a player's decoder keeps.
  size_t memory_bytes() const;

  // Frames reconstructed by the last decode call (random-access cost, for tests and benchmarks).
  uint64_t frames_reconstructed() const { return frames_reconstructed_; }

 private:
  friend struct DecoderAccess;
  friend struct DecoderV2Access;
  friend struct DecoderV3Access;
  void* dctx_ = nullptr;  // ZSTD_DCtx*, kept opaque so zstd.h stays out of this header
  std::vector<uint8_t> bytes_;
  // Quantised frames (current, previous, the one before) and one frame of residuals.
  std::vector<uint32_t> q_[4];
  // Version 2: the subspace prediction of one frame and the coefficients of the last three.
  std::vector<float> subspace_;
  std::vector<int32_t> coefficients_;
  std::vector<float> body_;  // version 2: one chunk's body transforms
  // Version 3: the last segments decoded (up to two, consecutive: one pass over the basis makes
  // the frames of both), as integers (the coefficients of both, then their residuals), kept while
  // frames of the same segments of the same blob (header checksum, segments) are decoded again.
  std::vector<int32_t> v3_ints_;
  std::vector<int32_t> v3_lanes_;  // 8 frames of residual, interleaved, for the spatial pass
  uint64_t v3_key_ = 0;
  uint32_t v3_segment_ = 0;   // the first segment held
  uint32_t v3_segments_ = 0;  // how many are held
  bool v3_valid_ = false;
  uint64_t frames_reconstructed_ = 0;
};

// Decodes frames [first, first + count) into out (count * vertex_count * 3 floats, out_floats is
// its capacity). Touches only the chunks holding those frames. Every checksum on the way is
// verified; on any error out may be partly written and must not be used. A version 2 blob needs the
// basis it names (`basis`; without it, or with another, NotFound / Corrupt).
Status decode_frames(const uint8_t* blob, size_t size, uint32_t first, uint32_t count, float* out,
                     size_t out_floats, DecodeScratch& scratch, Error* err,
                     const Basis* basis = nullptr);

// Decodes every frame of the blob into `out`, resizing it (allocates: convenience for tools).
Status decode_all(const uint8_t* blob, size_t size, std::vector<float>& out, DecodeScratch& scratch,
                  Error* err, const Basis* basis = nullptr);

// Checks all checksums and decodes every chunk without writing output (for `clothdb db check`).
Status verify(const uint8_t* blob, size_t size, DecodeScratch& scratch, Error* err,
              const Basis* basis = nullptr);

// Frames reconstructed to decode [first, first + count): from the key frame of first's chunk.
uint64_t decode_cost(const BlobInfo& info, uint32_t first, uint32_t count);

namespace detail {
// Recomputes the header and chunk checksums in place after deliberate edits, so tests and the
// fuzzer can reach the decoder's deeper checks behind the checksums. No-op if the header cannot
// be parsed far enough to find the chunks.
void reseal(uint8_t* blob, size_t size);
}  // namespace detail

}  // namespace clothdb::codec
