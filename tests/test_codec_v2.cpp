// Codec version 2 (docs/DATABASE.md, "version 2"): the subspace + residual format keeps the hard
// per-coordinate bound on random and adversarial frames, refuses non-finite input, decodes exactly
// from any frame, rejects damaged blobs and bases with clear errors; version 1 blobs made before
// version 2 existed still decode bit for bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <vector>

#include "compress/body_frame.hpp"
#include "compress/predictability.hpp"
#include "compress/subspace.hpp"
#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"

namespace clothdb::codec {
namespace {

// A waving sheet with a little high-frequency noise: most of it lies in a few modes.
std::vector<float> waves(uint32_t frames, uint32_t side, double phase = 0) {
  std::vector<float> x(size_t(frames) * side * side * 3);
  for (uint32_t f = 0; f < frames; ++f)
    for (uint32_t i = 0; i < side; ++i)
      for (uint32_t j = 0; j < side; ++j) {
        const double t = f / 30.0 + phase, u = double(i) / side, w = double(j) / side;
        float* p = x.data() + (size_t(f) * side * side + size_t(i) * side + j) * 3;
        p[0] = float(u + 0.05 * std::sin(3 * t + 4 * w) +
                     0.0007 * std::sin(97.0 * (i * 31 + j * 7 + f)));
        p[1] = float(1.5 - w + 0.2 * std::sin(2.1 * t + 6 * u) * w);
        p[2] = float(0.2 * std::cos(1.7 * t + 5 * u + 3 * w) * w);
      }
  return x;
}

Basis basis_of(const std::vector<float>& frames, uint32_t vertices, uint32_t modes,
               int64_t id = 7) {
  const Subspace s = build_subspace(frames, vertices * 3, modes);
  return make_basis(id, vertices, s.mean.data(), s.basis.data(), s.modes);
}

double max_error(const std::vector<float>& a, const std::vector<float>& b) {
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, std::fabs(double(a[i]) - double(b[i])));
  return m;
}

std::vector<float> decode(const std::vector<uint8_t>& blob, const Basis& basis) {
  DecodeScratch scratch;
  std::vector<float> y;
  Error err;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err, &basis), Status::Ok)
      << err.message;
  return y;
}

// Every coordinate of every frame, checked independently of the encoder's own verification.
void expect_bound(const std::vector<float>& x, uint32_t frames, uint32_t vertices,
                  const Basis& basis, const EncodeSettings& s, const SubspaceSettings& sub = {}) {
  EncodeSettings no_verify = s;
  no_verify.verify = false;  // the test checks, not the encoder
  const auto blob = encode_v2(x.data(), frames, vertices, basis, no_verify, sub);
  BlobInfo info;
  Error err;
  ASSERT_EQ(read_info(blob.data(), blob.size(), &info, &err), Status::Ok) << err.message;
  EXPECT_EQ(info.version, kFormatVersionV2);
  EXPECT_EQ(info.basis_id, basis.id);
  const auto y = decode(blob, basis);
  ASSERT_EQ(y.size(), x.size());
  size_t over = 0;
  for (size_t i = 0; i < x.size(); ++i)
    over += !(std::fabs(double(y[i]) - double(x[i])) <= s.bound);
  EXPECT_EQ(over, 0u) << "bound " << s.bound << ", K " << s.key_interval << ", max error "
                      << max_error(x, y);
}

TEST(CodecV2, BoundHoldsOnSubspaceFramesForEverySetting) {
  const uint32_t side = 10, V = side * side, F = 40;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 12);
  for (double bound : {1e-4, 5e-4, 2e-3, 1e-2})
    for (uint32_t K : {1u, 4u, 0u})
      for (int grid : {0, 1, 2}) {
        EncodeSettings s;
        s.bound = bound;
        s.key_interval = K;
        SubspaceSettings sub;
        sub.grid_divisions = grid;
        expect_bound(x, F, V, basis, s, sub);
      }
}

TEST(CodecV2, BoundHoldsOnRandomFramesTheBasisKnowsNothingAbout) {
  const uint32_t side = 8, V = side * side, F = 25;
  const Basis basis = basis_of(waves(30, side), V, 8);
  std::mt19937 rng(3);
  for (double range : {0.01, 1.0, 50.0}) {
    std::uniform_real_distribution<double> d(-range, range);
    std::vector<float> x(size_t(F) * V * 3);
    for (auto& v : x) v = float(d(rng));
    for (double bound : {5e-4, 1e-3}) {
      EncodeSettings s;
      s.bound = bound;
      expect_bound(x, F, V, basis, s);
    }
  }
}

TEST(CodecV2, BoundHoldsWithOutliersFarFromTheSubspace) {
  const uint32_t side = 10, V = side * side, F = 30;
  auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 10);
  // Vertices thrown far off the garment in some frames (a solver blow-up, a pinned vertex torn
  // off), single coordinates at the far end of the range, and a whole frame shifted by 3 m.
  std::mt19937 rng(11);
  for (int k = 0; k < 40; ++k) x[rng() % x.size()] += (k % 2 ? 1.f : -1.f) * float(0.5 + k * 0.1);
  for (size_t i = 0; i < size_t(V) * 3; ++i) x[size_t(17) * V * 3 + i] += 3.0f;
  for (double bound : {2.5e-4, 1e-3}) {
    EncodeSettings s;
    s.bound = bound;
    s.key_interval = 4;
    expect_bound(x, F, V, basis, s);
  }
}

TEST(CodecV2, VelocitiesWithoutTheMeanKeepTheirBound) {
  const uint32_t side = 9, V = side * side, F = 31;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 10);
  std::vector<float> v(size_t(F - 1) * V * 3);
  for (size_t i = 0; i < v.size(); ++i) v[i] = (x[i + size_t(V) * 3] - x[i]) * 30.0f;
  for (uint32_t f = 0; f < F - 1; ++f) {
    EncodeSettings s;
    s.bound = 0.001;  // 1 mm/s
    SubspaceSettings sub;
    sub.use_mean = false;
    std::vector<float> one(v.begin() + ptrdiff_t(size_t(f) * V * 3),
                           v.begin() + ptrdiff_t(size_t(f + 1) * V * 3));
    expect_bound(one, 1, V, basis, s, sub);
  }
}

TEST(CodecV2, SubspaceFramesCostLessThanVersion1) {
  const uint32_t side = 16, V = side * side, F = 60;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 16);
  EncodeSettings s;
  s.bound = 0.001;
  const auto v1 = encode(x.data(), F, V, s);
  const auto v2 = encode_v2(x.data(), F, V, basis, s);
  EXPECT_LT(v2.size(), v1.size());
}

TEST(CodecV2, NonFiniteFramesAreRefusedAtEncode) {
  const uint32_t side = 6, V = side * side, F = 5;
  const auto good = waves(F, side);
  const Basis basis = basis_of(good, V, 4);
  EncodeSettings s;
  for (float bad :
       {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(), -3e38f}) {
    auto x = good;
    x[size_t(2) * V * 3 + 13] = bad;
    try {
      encode_v2(x.data(), F, V, basis, s);
      ADD_FAILURE() << "encoded a frame holding " << bad;
    } catch (const ClothdbError& e) {
      EXPECT_EQ(e.status(), Status::InvalidArgument);
      EXPECT_NE(std::string(e.what()).find("frame 2"), std::string::npos) << e.what();
    }
  }
  // A whole frame of NaN.
  auto x = good;
  std::fill(x.begin(), x.begin() + V * 3, std::numeric_limits<float>::quiet_NaN());
  EXPECT_THROW(encode_v2(x.data(), F, V, basis, s), ClothdbError);
}

TEST(CodecV2, BasisMustFitTheFramesAndTheBlob) {
  const uint32_t side = 6, V = side * side, F = 8;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 4);
  EncodeSettings s;
  const Basis other = basis_of(waves(F, 5), 25, 4);
  EXPECT_THROW(encode_v2(x.data(), F, V, other, s), ClothdbError);
  SubspaceSettings too_many;
  too_many.modes = basis.mode_count + 1;
  EXPECT_THROW(encode_v2(x.data(), F, V, basis, s, too_many), ClothdbError);
  Basis unstored = basis;
  unstored.id = 0;
  EXPECT_THROW(encode_v2(x.data(), F, V, unstored, s), ClothdbError);

  const auto blob = encode_v2(x.data(), F, V, basis, s);
  DecodeScratch scratch;
  std::vector<float> y;
  Error err;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err), Status::NotFound);
  EXPECT_NE(std::string(err.message).find("basis 7"), std::string::npos) << err.message;
  Basis renamed = basis;
  renamed.id = 8;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err, &renamed), Status::NotFound);
  Basis other_id7 = other;
  other_id7.id = 7;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err, &other_id7), Status::Corrupt);
}

TEST(CodecV2, RandomAccessDecodesTheSameValuesAsAFullDecode) {
  const uint32_t side = 10, V = side * side, F = 23;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 8);
  for (uint32_t K : {1u, 4u, 0u}) {
    EncodeSettings s;
    s.key_interval = K;
    s.bound = 0.0005;
    const auto blob = encode_v2(x.data(), F, V, basis, s);
    const auto all = decode(blob, basis);
    DecodeScratch scratch;
    std::vector<float> one(size_t(V) * 3);
    for (uint32_t f = 0; f < F; ++f) {
      ASSERT_EQ(decode_frames(blob.data(), blob.size(), f, 1, one.data(), one.size(), scratch,
                              nullptr, &basis),
                Status::Ok);
      EXPECT_TRUE(std::equal(one.begin(), one.end(), all.begin() + ptrdiff_t(size_t(f) * V * 3)))
          << "frame " << f << ", K " << K;
      EXPECT_LE(scratch.frames_reconstructed(), uint64_t(K ? K : F));
    }
    std::vector<float> range(size_t(7) * V * 3);
    ASSERT_EQ(decode_frames(blob.data(), blob.size(), 9, 7, range.data(), range.size(), scratch,
                            nullptr, &basis),
              Status::Ok);
    EXPECT_TRUE(std::equal(range.begin(), range.end(), all.begin() + ptrdiff_t(size_t(9) * V * 3)));
    EXPECT_EQ(decode_frames(blob.data(), blob.size(), F, 1, one.data(), one.size(), scratch,
                            nullptr, &basis),
              Status::InvalidArgument);
    EXPECT_EQ(decode_frames(blob.data(), blob.size(), 0, 2, one.data(), one.size(), scratch,
                            nullptr, &basis),
              Status::OutputTooSmall);
  }
}

TEST(CodecV2, DamagedBlobsFailWithAStatusNeverACrash) {
  const uint32_t side = 7, V = side * side, F = 9;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 6);
  EncodeSettings s;
  s.key_interval = 4;
  // With and without body transforms (whose stored values the decoder range-checks).
  std::vector<float> turn(size_t(F) * 12, 0.0f);
  for (uint32_t f = 0; f < F; ++f) {
    float* t = turn.data() + size_t(f) * 12;
    t[0] = t[8] = float(std::cos(0.05 * f));
    t[2] = float(std::sin(0.05 * f));
    t[6] = -t[2];
    t[4] = 1.0f;
    t[9] = 0.002f * float(f);
  }
  SubspaceSettings body;
  body.body_frames = turn.data();
  for (const auto& blob :
       {encode_v2(x.data(), F, V, basis, s), encode_v2(x.data(), F, V, basis, s, body)}) {
    DecodeScratch scratch;
    std::vector<float> y;
    Error err;
    // Every single-byte change is caught by a checksum or a field check.
    for (size_t i = 0; i < blob.size(); ++i) {
      auto b = blob;
      b[i] ^= 0x5a;
      EXPECT_NE(decode_all(b.data(), b.size(), y, scratch, &err, &basis), Status::Ok)
          << "byte " << i;
      EXPECT_NE(err.message[0], '\0');
    }
    for (size_t cut : {size_t(0), size_t(5), size_t(50), size_t(111), blob.size() - 1}) {
      std::vector<uint8_t> b(blob.begin(), blob.begin() + ptrdiff_t(cut));
      const Status st = decode_all(b.data(), b.size(), y, scratch, &err, &basis);
      EXPECT_TRUE(st == Status::Truncated || st == Status::NotClothdb)
          << cut << ": " << err.message;
    }
    auto longer = blob;
    longer.push_back(0);
    EXPECT_EQ(decode_all(longer.data(), longer.size(), y, scratch, &err, &basis), Status::Corrupt);
    // Past the checksums (resealed): random damage must still give a status or in-range values.
    std::mt19937 rng(5);
    for (int trial = 0; trial < 300; ++trial) {
      auto b = blob;
      for (int k = 0; k < 3; ++k) b[rng() % b.size()] = uint8_t(rng());
      detail::reseal(b.data(), b.size());
      BlobInfo info;
      if (read_info(b.data(), b.size(), &info, &err) != Status::Ok) continue;
      if (decode_all(b.data(), b.size(), y, scratch, &err, &basis) != Status::Ok) continue;
      for (size_t i = 0; i < y.size(); ++i) {
        const double lo = info.origin[i % 3], hi = lo + info.qmax[i % 3] * info.step;
        ASSERT_TRUE(std::isfinite(y[i]) && y[i] >= float(lo) - 1e-6f && y[i] <= float(hi) + 1e-6f);
      }
    }
  }
}

TEST(CodecV2, BasisRoundTripsAndRejectsDamage) {
  const uint32_t side = 5, V = side * side;
  const Basis basis = basis_of(waves(20, side), V, 5, 3);
  const auto data = serialize_basis(basis);
  Basis back;
  Error err;
  ASSERT_EQ(parse_basis(data.data(), data.size(), 3, &back, &err), Status::Ok) << err.message;
  EXPECT_EQ(back.mean, basis.mean);
  EXPECT_EQ(back.modes, basis.modes);  // the exact floats both sides multiply by
  EXPECT_EQ(back.scale, basis.scale);
  auto bad = data;
  bad[100] ^= 1;
  EXPECT_EQ(parse_basis(bad.data(), bad.size(), 3, &back, &err), Status::ChecksumMismatch);
  EXPECT_EQ(parse_basis(data.data(), data.size() - 1, 3, &back, &err), Status::Truncated);
  EXPECT_EQ(parse_basis(data.data(), 3, 3, &back, &err), Status::NotClothdb);
  // A header asking for a huge basis is refused before anything is allocated.
  auto huge = data;
  huge[12] = 0xff;
  huge[13] = 0xff;
  EXPECT_EQ(parse_basis(huge.data(), huge.size(), 3, &back, &err), Status::Corrupt);
  std::vector<float> nan_mode(size_t(V) * 3, std::numeric_limits<float>::quiet_NaN());
  EXPECT_THROW(make_basis(1, V, basis.mean.data(), nan_mode.data(), 1), ClothdbError);
}

// tests/data/codec_v1_waves.blob was written by the codec as it was before version 2 existed
// (commit 5bc4d0a): the same frames, and the XXH64 of what that build decoded.
TEST(CodecV2, Version1BlobsStillDecodeBitForBit) {
  std::ifstream in(std::string(CLOTHDB_SOURCE_DIR) + "/tests/data/codec_v1_waves.blob",
                   std::ios::binary);
  ASSERT_TRUE(in);
  const std::vector<uint8_t> blob((std::istreambuf_iterator<char>(in)),
                                  std::istreambuf_iterator<char>());
  ASSERT_EQ(blob.size(), 8513u);
  DecodeScratch scratch;
  std::vector<float> y;
  Error err;
  ASSERT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err), Status::Ok) << err.message;
  EXPECT_EQ(xxh64(y.data(), y.size() * sizeof(float)), 0x331576f70e599e1dull);
  // The version 1 encoder is unchanged too: the same frames give the same bytes.
  const uint32_t side = 12, frames = 37;
  std::vector<float> x(size_t(frames) * side * side * 3);
  for (uint32_t f = 0; f < frames; ++f)
    for (uint32_t i = 0; i < side; ++i)
      for (uint32_t j = 0; j < side; ++j) {
        const double t = f / 30.0, u = double(i) / side, w = double(j) / side;
        float* p = x.data() + (size_t(f) * side * side + size_t(i) * side + j) * 3;
        p[0] = float(u + 0.05 * std::sin(3 * t + 4 * w) +
                     0.001 * std::sin(97.0 * (i * 31 + j * 7 + f)));
        p[1] = float(1.5 - w + 0.2 * std::sin(2.1 * t + 6 * u) * w);
        p[2] = float(0.2 * std::cos(1.7 * t + 5 * u + 3 * w) * w);
      }
  ASSERT_EQ(xxh64(x.data(), x.size() * sizeof(float)), 0xc9e88ae8af3c468dull);
  EncodeSettings s;
  s.bound = 0.0005;
  EXPECT_EQ(encode(x.data(), frames, side * side, s), blob);
}

}  // namespace
}  // namespace clothdb::codec

// compress/predictability.hpp: what `bench codec --predictability` reports.
namespace {

// A fixed random shape of V vertices, turned about y by angle[f] and moved by shift[f] per frame.
std::vector<float> turning_shape(uint32_t vertices, const std::vector<double>& angle,
                                 const std::vector<double>& shift) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::vector<double> shape(3 * std::size_t(vertices));
  for (double& s : shape) s = u(rng);
  std::vector<float> frames;
  for (std::size_t f = 0; f < angle.size(); ++f) {
    const double c = std::cos(angle[f]), s = std::sin(angle[f]);
    for (uint32_t v = 0; v < vertices; ++v) {
      const double x = shape[3 * v], y = shape[3 * v + 1], z = shape[3 * v + 2];
      frames.push_back(float(c * x + s * z + shift[f]));
      frames.push_back(float(y));
      frames.push_back(float(-s * x + c * z));
    }
  }
  return frames;
}

// The shape swinging about y by up to 0.6 rad and sliding by up to 5 cm over `frames` frames.
std::vector<float> swinging_shape(uint32_t vertices, uint32_t frames) {
  std::vector<double> angle, shift;
  for (uint32_t f = 0; f < frames; ++f) {
    angle.push_back(0.6 * std::sin(0.3 * f));
    shift.push_back(0.05 * std::cos(0.2 * f));
  }
  return turning_shape(vertices, angle, shift);
}

}  // namespace

namespace clothdb::codec {

// Cloth relative to the body (docs/DATABASE.md, "version 2"): a garment carried rigidly by the body
// (the turning shape) is, in the body frame of its anchors, one shape: version 2 with a body frame
// codes it as the basis mean plus 12 floats a frame, where without one the subspace must code the
// turn. The bound holds either way, on every coordinate.
TEST(CodecV2, BodyFrameKeepsTheBoundAndCodesWhatTheBodyCarriesInItsTransforms) {
  const uint32_t vertices = 400, frames = 48;
  std::vector<float> x = swinging_shape(vertices, frames);
  // A little noise that no subspace predicts, so the residual layer has work on both sides.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> noise(-0.0003f, 0.0003f);
  for (float& v : x) v += noise(rng);
  const std::vector<float> rest = turning_shape(vertices, {0.0}, {0.0});
  const clothdb::BodyAnchors anchors = clothdb::body_anchors(rest);
  EXPECT_EQ(anchors.vertices.size(), 20u);  // 5 % of 400
  const std::vector<float> transforms =
      clothdb::fit_body_frames(x.data(), frames, vertices, anchors);
  std::vector<float> in_body = x;
  clothdb::to_body_frame(in_body.data(), frames, vertices, transforms.data());
  const Basis body_basis = basis_of(in_body, vertices, 2, 11);
  const Basis plain_basis = basis_of(x, vertices, 2, 12);
  for (double bound : {0.0005, 0.002}) {
    EncodeSettings s;
    s.bound = bound;
    s.key_interval = 8;
    SubspaceSettings body;
    body.body_frames = transforms.data();
    expect_bound(x, frames, vertices, body_basis, s, body);
    expect_bound(x, frames, vertices, plain_basis, s);
    const auto with = encode_v2(x.data(), frames, vertices, body_basis, s, body);
    const auto without = encode_v2(x.data(), frames, vertices, plain_basis, s);
    BlobInfo info;
    Error err;
    ASSERT_EQ(read_info(with.data(), with.size(), &info, &err), Status::Ok);
    EXPECT_TRUE(info.body_frame);
    ASSERT_EQ(read_info(without.data(), without.size(), &info, &err), Status::Ok);
    EXPECT_FALSE(info.body_frame);
    EXPECT_LT(3 * with.size(), without.size()) << "bound " << bound;
  }
}

TEST(CodecV2, BadBodyTransformsAreRefusedAtEncode) {
  const uint32_t side = 6, V = side * side, F = 5;
  const auto x = waves(F, side);
  const Basis basis = basis_of(x, V, 3);
  std::vector<float> t(size_t(F) * 12, 0.0f);
  for (uint32_t f = 0; f < F; ++f) t[12 * f] = t[12 * f + 4] = t[12 * f + 8] = 1.0f;
  SubspaceSettings sub;
  sub.body_frames = t.data();
  EXPECT_NO_THROW(encode_v2(x.data(), F, V, basis, EncodeSettings{}, sub));
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), 1.5f}) {
    auto u = t;
    u[12 * 3 + 4] = bad;  // a rotation entry of frame 3
    sub.body_frames = u.data();
    EXPECT_THROW(encode_v2(x.data(), F, V, basis, EncodeSettings{}, sub), ClothdbError) << bad;
  }
  auto u = t;
  u[12 * 2 + 10] = std::numeric_limits<float>::infinity();  // a translation
  sub.body_frames = u.data();
  EXPECT_THROW(encode_v2(x.data(), F, V, basis, EncodeSettings{}, sub), ClothdbError);
  // Velocities have no body frame (the derivative of R s + t is not R ds/dt).
  sub.body_frames = t.data();
  sub.use_mean = false;
  EXPECT_THROW(encode_v2(x.data(), F, V, basis, EncodeSettings{}, sub), ClothdbError);
}

}  // namespace clothdb::codec

TEST(Predictability, TheBodyFrameRemovesARigidMotionThatCharacterSpaceMustCode) {
  const uint32_t vertices = 200, frames = 40;
  const auto x = swinging_shape(vertices, frames);
  const auto r = clothdb::analyse_predictability(x, vertices, frames, {}, {0}, {1e-3});
  ASSERT_EQ(r.rows.size(), 2u);
  EXPECT_EQ(r.rows[0].space, "character");
  EXPECT_EQ(r.rows[1].space, "body");
  // A rigid shape: the fit is exact up to float rounding, and turns by up to the 0.6 rad swing
  // from the anchors' mean pose (about the middle of the swing).
  EXPECT_NEAR(r.max_rotation_deg, 0.6 * 180 / 3.14159265358979, 2.0);
  EXPECT_LT(r.rows[1].rms_left, 1e-5);
  EXPECT_DOUBLE_EQ(r.rows[1].within_as_is[0], 1.0);
  // In character space only y (a third of the coordinates, never moved) stays within 1 mm.
  EXPECT_GT(r.rows[0].rms_left, 0.03);
  EXPECT_LT(r.rows[0].within_as_is[0], 0.4);
}

TEST(Predictability, TemporalColumnsSkipFramesThatReachBackAcrossAClipStart) {
  // Without modes the residual is x - mean. Each clip moves its shape at a constant 3 mm per
  // frame: the previous frame's residual misses by 3 mm (never within 1 mm), linear extrapolation
  // is exact, and the jump between clips would break both if it were not skipped.
  const uint32_t vertices = 50, frames = 30;
  std::vector<double> angle(frames, 0.0), shift;
  for (uint32_t f = 0; f < frames; ++f) shift.push_back(f < 15 ? 0.003 * f : 0.5 + 0.003 * f);
  const auto x = turning_shape(vertices, angle, shift);
  const auto r = clothdb::analyse_predictability(x, vertices, frames, {0, 15}, {0}, {1e-3});
  const auto& character = r.rows[0];
  EXPECT_DOUBLE_EQ(character.within_linear[0], 1.0);
  // Only x moves; y and z are constant, so two thirds of the coordinates are exact.
  EXPECT_NEAR(character.within_delta[0], 2.0 / 3.0, 1e-9);
  // Told nothing of the second clip, the two frames after the jump miss in x.
  const auto blind = clothdb::analyse_predictability(x, vertices, frames, {}, {0}, {1e-3});
  EXPECT_LT(blind.rows[0].within_linear[0], 1.0);
}

TEST(Predictability, BadInputIsRefused) {
  std::vector<float> x(3 * 10 * 5, 0.0f);
  EXPECT_THROW(clothdb::analyse_predictability(x, 10, 4, {}, {0}, {1e-3}), std::invalid_argument);
  EXPECT_THROW(clothdb::analyse_predictability(x, 10, 5, {}, {}, {1e-3}), std::invalid_argument);
  x[7] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(clothdb::analyse_predictability(x, 10, 5, {}, {0}, {1e-3}), std::invalid_argument);
}

namespace clothdb::codec {

// predict() (codec_v2.cpp) is built for AVX2 and for the baseline and picked at load time. Both
// must round every operation alike, or a file written on one machine would decode differently on
// another. The hashes were recorded with the build before the AVX2 version existed (plain SSE2):
// on an AVX2 machine this test runs the new version against them.
TEST(CodecV2, PredictionsAreBitIdenticalWhicheverInstructionSetRuns) {
  const uint32_t side = 12, frames = 24, vertices = side * side, n = vertices * 3;
  std::vector<float> x(size_t(frames) * n);
  for (uint32_t f = 0; f < frames; ++f)
    for (uint32_t i = 0; i < side; ++i)
      for (uint32_t j = 0; j < side; ++j) {
        const double t = f / 30.0, u = double(i) / side, w = double(j) / side;
        float* p = x.data() + (size_t(f) * vertices + size_t(i) * side + j) * 3;
        p[0] = float(u + 0.05 * std::sin(3 * t + 4 * w) +
                     0.0007 * std::sin(97.0 * (i * 31 + j * 7 + f)));
        p[1] = float(1.5 - w + 0.2 * std::sin(2.1 * t + 6 * u) * w);
        p[2] = float(0.2 * std::cos(1.7 * t + 5 * u + 3 * w) * w);
      }
  ASSERT_EQ(xxh64(x.data(), x.size() * sizeof(float)), 0x5388b8aac75cb7e2ull)
      << std::hex << xxh64(x.data(), x.size() * sizeof(float));
  // An analytic basis (no SVD, whose rounding is Eigen's): frame 0 as the mean and six sine
  // patterns over the coordinates.
  const uint32_t modes = 6;
  std::vector<float> u(size_t(modes) * n);
  for (uint32_t k = 0; k < modes; ++k)
    for (uint32_t i = 0; i < n; ++i)
      u[size_t(k) * n + i] = float(std::sin(0.37 * (k + 1) * i + 0.5 * k) / std::sqrt(n / 2.0));
  const Basis basis = make_basis(3, vertices, x.data(), u.data(), modes);
  EncodeSettings s;
  s.bound = 0.0005;
  s.key_interval = 4;
  const auto blob = encode_v2(x.data(), frames, vertices, basis, s);
  EXPECT_EQ(xxh64(blob.data(), blob.size()), 0xa75d9e536d89f9bdull)
      << std::hex << xxh64(blob.data(), blob.size());
  const auto y = decode(blob, basis);
  EXPECT_EQ(xxh64(y.data(), y.size() * sizeof(float)), 0x13c9df87374e1c16ull)
      << std::hex << xxh64(y.data(), y.size() * sizeof(float));
}

}  // namespace clothdb::codec
