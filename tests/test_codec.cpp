// The cloth frame codec: the error bound as a promise, exact integer round trips, random access
// through key frames, and clear errors (never a crash or garbage) on damaged blobs.
#include <gtest/gtest.h>
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <new>
#include <random>
#include <vector>

#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

// Counts heap allocations so a test can show decoding into caller buffers allocates nothing.
// GCC's mismatched-new-delete check cannot see that these replacements pair malloc with free.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
static thread_local long g_allocations = 0;
void* operator new(std::size_t size) {
  ++g_allocations;
  if (void* p = std::malloc(size ? size : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}

namespace clothdb::codec {
namespace {

// A waving sheet: smooth in space and time, like cloth, with per-vertex phase so it is not
// trivially predictable.
std::vector<float> waves(uint32_t frames, uint32_t side, double amplitude = 0.2) {
  std::vector<float> x(size_t(frames) * side * side * 3);
  for (uint32_t f = 0; f < frames; ++f) {
    const double t = f / 30.0;
    for (uint32_t i = 0; i < side; ++i) {
      for (uint32_t j = 0; j < side; ++j) {
        const double u = double(i) / side, w = double(j) / side;
        float* p = x.data() + (size_t(f) * side * side + size_t(i) * side + j) * 3;
        p[0] = float(u + 0.05 * std::sin(3 * t + 4 * w));
        p[1] = float(1.5 - w + amplitude * std::sin(2.1 * t + 6 * u) * w);
        p[2] = float(amplitude * std::cos(1.7 * t + 5 * u + 3 * w) * w);
      }
    }
  }
  return x;
}

std::vector<float> random_frames(uint32_t frames, uint32_t vertices, double lo, double hi,
                                 uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> d(lo, hi);
  std::vector<float> x(size_t(frames) * vertices * 3);
  for (auto& v : x) v = float(d(rng));
  return x;
}

double max_error(const std::vector<float>& a, const std::vector<float>& b) {
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, std::fabs(double(a[i]) - double(b[i])));
  return m;
}

std::vector<float> roundtrip(const std::vector<float>& x, uint32_t frames, uint32_t vertices,
                             const EncodeSettings& s, std::vector<uint8_t>* blob_out = nullptr) {
  std::vector<uint8_t> blob = encode(x.data(), frames, vertices, s);
  DecodeScratch scratch;
  std::vector<float> y;
  Error err;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err), Status::Ok) << err.message;
  if (blob_out) *blob_out = std::move(blob);
  return y;
}

TEST(Checksum, Xxh64MatchesKnownValueAndZstdFrameChecksum) {
  EXPECT_EQ(xxh64("", 0), 0xEF46DB3751D8E999ULL);
  // zstd's frame checksum is the low 32 bits of XXH64(content, seed 0): an independent reference
  // for every length class (< 4, < 8, < 32, >= 32 bytes, with and without tails).
  std::mt19937 rng(7);
  ZSTD_CCtx* cctx = ZSTD_createCCtx();
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_checksumFlag, 1);
  for (size_t len : {1, 3, 4, 7, 8, 15, 31, 32, 33, 63, 64, 100, 1000, 65537}) {
    std::vector<uint8_t> data(len);
    for (auto& b : data) b = uint8_t(rng());
    std::vector<uint8_t> out(ZSTD_compressBound(len));
    const size_t n = ZSTD_compress2(cctx, out.data(), out.size(), data.data(), len);
    ASSERT_FALSE(ZSTD_isError(n));
    uint32_t stored;
    std::memcpy(&stored, out.data() + n - 4, 4);
    EXPECT_EQ(stored, uint32_t(xxh64(data.data(), len))) << "length " << len;
  }
  ZSTD_freeCCtx(cctx);
}

TEST(Codec, BoundHoldsOnRandomData) {
  const uint32_t frames = 12, vertices = 300;
  uint32_t seed = 1;
  for (double bound : {1e-5, 1e-4, 5e-4, 2e-3, 1e-2, 0.3}) {
    for (auto [lo, hi] : {std::pair{-1.0, 1.0}, std::pair{-50.0, 50.0}, std::pair{99.0, 101.0}}) {
      const auto x = random_frames(frames, vertices, lo, hi, seed++);
      EncodeSettings s;
      s.bound = bound;
      s.key_interval = 5;
      EncodeStats stats;
      std::vector<uint8_t> blob = encode(x.data(), frames, vertices, s, &stats);
      DecodeScratch scratch;
      std::vector<float> y;
      ASSERT_EQ(decode_all(blob.data(), blob.size(), y, scratch, nullptr), Status::Ok);
      EXPECT_LE(max_error(x, y), bound) << "bound " << bound << " range " << lo << ".." << hi;
      EXPECT_DOUBLE_EQ(stats.max_error, max_error(x, y));
    }
  }
}

TEST(Codec, BoundHoldsOnSmoothMotionWithEveryPredictorAndKeyInterval) {
  const uint32_t frames = 40, side = 24, vertices = side * side;
  const auto x = waves(frames, side);
  for (double bound : {1e-4, 5e-4, 2e-3}) {
    for (uint32_t k : {0u, 1u, 2u, 7u, 16u}) {
      for (Predictor p : {Predictor::Auto, Predictor::Delta, Predictor::Linear, Predictor::None}) {
        for (GridMode g : {GridMode::Plain, GridMode::Fine}) {
          for (SpatialMode sp : {SpatialMode::Auto, SpatialMode::Off, SpatialMode::On}) {
            EncodeSettings s;
            s.bound = bound;
            s.key_interval = k;
            s.predictor = p;
            s.grid = g;
            s.spatial = sp;
            s.verify = false;  // the test checks the bound itself
            const auto y = roundtrip(x, frames, vertices, s);
            EXPECT_LE(max_error(x, y), bound) << "bound " << bound << " K " << k;
          }
        }
      }
    }
  }
}

TEST(Codec, BoundHoldsOnSimulatedCloth) {
  // Real solver output: the swung sheet (the liveliest hard case), 441 vertices, 90 frames.
  ClothScene scene = make_hard_case("swung-sheet");
  SolverSettings settings;
  settings.substeps = 10;
  settings.iterations = 2;
  auto solver = make_solver(SolverKind::Xpbd, scene.model, settings);
  const RunResult run = run_scene(scene, *solver, 90);
  ASSERT_TRUE(run.stable) << run.message;
  const uint32_t vertices = uint32_t(scene.model.mesh.rest.cols());
  const uint32_t frames = uint32_t(run.frames.size());
  std::vector<float> x(size_t(frames) * vertices * 3);
  for (uint32_t f = 0; f < frames; ++f)
    for (uint32_t v = 0; v < vertices; ++v)
      for (int a = 0; a < 3; ++a)
        x[(size_t(f) * vertices + v) * 3 + a] = float(run.frames[f](a, v));
  for (double bound : {5e-4, 2e-3}) {
    for (uint32_t k : {1u, 16u}) {
      EncodeSettings s;
      s.bound = bound;
      s.key_interval = k;
      EncodeStats stats;
      std::vector<uint8_t> blob;
      const auto y = roundtrip(x, frames, vertices, s, &blob);
      EXPECT_LE(max_error(x, y), bound) << "bound " << bound << " K " << k;
      EXPECT_LT(blob.size() * 4, x.size() * sizeof(float)) << "bound " << bound << " K " << k;
    }
  }
}

TEST(Codec, SmoothMotionCompresses) {
  const uint32_t frames = 60, side = 40;
  const auto x = waves(frames, side, 0.05);
  EncodeSettings s;
  s.bound = 2e-3;
  EncodeStats stats;
  encode(x.data(), frames, side * side, s, &stats);
  // Slow smooth motion at 2 mm: far below raw size (a loose sanity floor, not a benchmark).
  EXPECT_LT(stats.encoded_bytes * 8, stats.raw_bytes);
}

TEST(Codec, IntegerStreamRoundTripIsBitExact) {
  // Decoded frames lie on the quantisation grid, so encoding them again on the plain grid (one
  // valid value per coordinate) must reproduce them bit for bit: the integer pipeline
  // (prediction, zigzag, planes, zstd) is lossless. (On the fine grid the encoder may move a
  // value to a neighbour that is also within the bound, by design.)
  const uint32_t frames = 30, side = 20, vertices = side * side;
  const auto x = waves(frames, side);
  for (uint32_t k : {1u, 8u, 0u}) {
    EncodeSettings s;
    s.bound = 5e-4;
    s.key_interval = k;
    s.grid = GridMode::Plain;
    const auto y = roundtrip(x, frames, vertices, s);
    const auto z = roundtrip(y, frames, vertices, s);
    ASSERT_EQ(y.size(), z.size());
    EXPECT_EQ(std::memcmp(y.data(), z.data(), y.size() * sizeof(float)), 0) << "K " << k;
  }
}

TEST(Codec, RandomAccessEqualsSequentialAndCostsAtMostKFrames) {
  const uint32_t frames = 37, side = 12, vertices = side * side;
  const size_t n = size_t(vertices) * 3;
  const auto x = waves(frames, side);
  for (uint32_t k : {1u, 4u, 16u, 0u}) {
    EncodeSettings s;
    s.key_interval = k;
    std::vector<uint8_t> blob;
    const auto all = roundtrip(x, frames, vertices, s, &blob);
    BlobInfo info;
    ASSERT_EQ(read_info(blob.data(), blob.size(), &info, nullptr), Status::Ok);
    const uint32_t K = k == 0 ? frames : k;
    EXPECT_EQ(info.key_interval, K);
    DecodeScratch scratch;
    std::vector<float> one(n);
    for (uint32_t f = 0; f < frames; ++f) {
      ASSERT_EQ(
          decode_frames(blob.data(), blob.size(), f, 1, one.data(), one.size(), scratch, nullptr),
          Status::Ok);
      EXPECT_EQ(std::memcmp(one.data(), all.data() + f * n, n * sizeof(float)), 0);
      EXPECT_LE(scratch.frames_reconstructed(), K);
      EXPECT_EQ(scratch.frames_reconstructed(), decode_cost(info, f, 1));
    }
    // A range crossing chunk boundaries.
    std::vector<float> range(10 * n);
    ASSERT_EQ(decode_frames(blob.data(), blob.size(), 3, 10, range.data(), range.size(), scratch,
                            nullptr),
              Status::Ok);
    EXPECT_EQ(std::memcmp(range.data(), all.data() + 3 * n, range.size() * sizeof(float)), 0);
  }
}

TEST(Codec, DecodingIntoCallerBuffersDoesNotAllocate) {
  const uint32_t frames = 20, side = 16, vertices = side * side;
  const auto x = waves(frames, side);
  const std::vector<uint8_t> blob = encode(x.data(), frames, vertices, EncodeSettings{});
  DecodeScratch scratch;
  scratch.reserve(vertices, kDefaultKeyInterval);
  std::vector<float> out(size_t(frames) * vertices * 3);
  const long before = g_allocations;
  Error err;
  for (uint32_t f = 0; f < frames; ++f)
    ASSERT_EQ(decode_frames(blob.data(), blob.size(), f, 1, out.data(), out.size(), scratch, &err),
              Status::Ok);
  ASSERT_EQ(
      decode_frames(blob.data(), blob.size(), 0, frames, out.data(), out.size(), scratch, &err),
      Status::Ok);
  EXPECT_EQ(g_allocations, before);
}

class DamagedBlob : public ::testing::Test {
 protected:
  void SetUp() override {
    x_ = waves(frames_, side_);
    EncodeSettings s;
    s.key_interval = 4;
    blob_ = encode(x_.data(), frames_, side_ * side_, s);
    ASSERT_EQ(read_info(blob_.data(), blob_.size(), &info_, nullptr), Status::Ok);
  }
  // Decodes every frame; on success checks the values stay inside the range the header declares.
  Status decode(const std::vector<uint8_t>& b, Error* err) {
    std::vector<float> out(x_.size());
    DecodeScratch scratch;
    const Status st =
        decode_frames(b.data(), b.size(), 0, frames_, out.data(), out.size(), scratch, err);
    if (st == Status::Ok) {
      BlobInfo info;
      EXPECT_EQ(read_info(b.data(), b.size(), &info, nullptr), Status::Ok);
      for (size_t i = 0; i < out.size(); ++i) {
        const int a = int(i % 3);
        const uint32_t qlimit = std::max({info.qmax[0], info.qmax[1], info.qmax[2]});
        EXPECT_TRUE(std::isfinite(out[i]));
        EXPECT_GE(double(out[i]), float(info.origin[a]) - 1e-3);
        EXPECT_LE(double(out[i]), info.origin[a] + qlimit * info.step + 1e-3);
      }
    }
    return st;
  }
  const uint32_t frames_ = 10, side_ = 10;
  std::vector<float> x_;
  std::vector<uint8_t> blob_;
  BlobInfo info_;
};

TEST_F(DamagedBlob, EveryTruncationIsAnError) {
  for (size_t len = 0; len < blob_.size(); ++len) {
    std::vector<uint8_t> b(blob_.begin(), blob_.begin() + len);
    Error err;
    const Status st = decode(b, &err);
    EXPECT_NE(st, Status::Ok) << "length " << len;
    EXPECT_NE(err.message[0], '\0');
    if (len >= 4) {
      EXPECT_EQ(st, Status::Truncated) << "length " << len << ": " << err.message;
    }
  }
  // Trailing garbage too.
  std::vector<uint8_t> b = blob_;
  b.push_back(0);
  EXPECT_EQ(decode(b, nullptr), Status::Corrupt);
}

TEST_F(DamagedBlob, EveryByteFlipIsCaughtByAChecksum) {
  std::mt19937 rng(42);
  for (size_t pos = 0; pos < blob_.size(); ++pos) {
    std::vector<uint8_t> b = blob_;
    b[pos] ^= uint8_t(1 + rng() % 255);
    Error err;
    const Status st = decode(b, &err);
    EXPECT_NE(st, Status::Ok) << "flip at " << pos;
    if (pos >= 6) {
      EXPECT_TRUE(st == Status::ChecksumMismatch || st == Status::Truncated ||
                  st == Status::NewerVersion || st == Status::Corrupt)
          << err.message;
    }
  }
}

TEST_F(DamagedBlob, ResealedDamageIsAnErrorOrStaysInRange) {
  // With the checksums recomputed, damage reaches the parser and the reconstruction: the decoder
  // must still report an error or produce values inside the declared range, never crash.
  std::mt19937 rng(43);
  int errors = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    std::vector<uint8_t> b = blob_;
    const int flips = 1 + int(rng() % 3);
    for (int i = 0; i < flips; ++i) b[rng() % b.size()] ^= uint8_t(1 + rng() % 255);
    codec::detail::reseal(b.data(), b.size());
    errors += decode(b, nullptr) != Status::Ok;
  }
  EXPECT_GT(errors, 0);
}

TEST_F(DamagedBlob, NewerVersionAndForeignDataAreRefused) {
  std::vector<uint8_t> b = blob_;
  b[4] = uint8_t(kNewestFormatVersion + 1);  // newer than any format this build reads
  codec::detail::reseal(b.data(), b.size());
  Error err;
  EXPECT_EQ(decode(b, &err), Status::NewerVersion);
  EXPECT_NE(std::strstr(err.message, "newer"), nullptr) << err.message;

  const char sqlite[] = "SQLite format 3\0 and then some more bytes of a page";
  std::vector<uint8_t> foreign(sqlite, sqlite + sizeof sqlite);
  EXPECT_EQ(decode(foreign, &err), Status::NotClothdb);
  EXPECT_EQ(decode({}, &err), Status::NotClothdb);
  EXPECT_EQ(read_info(nullptr, 10, nullptr, &err), Status::InvalidArgument);
}

TEST_F(DamagedBlob, BadRequestsAreErrors) {
  DecodeScratch scratch;
  std::vector<float> out(x_.size());
  const size_t n = size_t(side_) * side_ * 3;
  EXPECT_EQ(decode_frames(blob_.data(), blob_.size(), frames_, 1, out.data(), out.size(), scratch,
                          nullptr),
            Status::InvalidArgument);
  EXPECT_EQ(decode_frames(blob_.data(), blob_.size(), 5, frames_, out.data(), out.size(), scratch,
                          nullptr),
            Status::InvalidArgument);
  EXPECT_EQ(decode_frames(blob_.data(), blob_.size(), 0, 2, out.data(), n, scratch, nullptr),
            Status::OutputTooSmall);
  EXPECT_EQ(decode_frames(blob_.data(), blob_.size(), 0, 1, nullptr, 0, scratch, nullptr),
            Status::InvalidArgument);
  EXPECT_EQ(verify(blob_.data(), blob_.size(), scratch, nullptr), Status::Ok);
}

TEST(Codec, EncoderRejectsImpossibleInput) {
  std::vector<float> x(30, 0.5f);
  EncodeSettings s;
  EXPECT_THROW(encode(x.data(), 0, 10, s), ClothdbError);
  EXPECT_THROW(encode(nullptr, 1, 10, s), ClothdbError);
  s.bound = 0;
  EXPECT_THROW(encode(x.data(), 1, 10, s), ClothdbError);
  s.bound = 1e-3;
  s.zstd_level = 1000;
  EXPECT_THROW(encode(x.data(), 1, 10, s), ClothdbError);
  s.zstd_level = 3;
  x[17] = std::nanf("");
  try {
    encode(x.data(), 1, 10, s);
    FAIL() << "NaN accepted";
  } catch (const ClothdbError& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 5"), std::string::npos) << e.what();
  }
  // A range too large for 2^28 steps of the bound.
  std::vector<float> wide = {0, 0, 0, 1e6f, 0, 0};
  s.bound = 1e-4;
  EXPECT_THROW(encode(wide.data(), 1, 2, s), ClothdbError);
}

TEST(Codec, ConstantAndSingleFrameClips) {
  std::vector<float> x(3 * 7, 0.25f);
  EncodeSettings s;
  const auto y = roundtrip(x, 1, 7, s);
  EXPECT_LE(max_error(x, y), s.bound);
  const auto z = roundtrip(std::vector<float>(3 * 7 * 5, -3.0f), 5, 7, s);
  for (float v : z) EXPECT_NEAR(v, -3.0f, s.bound);
}

}  // namespace
}  // namespace clothdb::codec
