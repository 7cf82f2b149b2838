// Codec version 3 and the error contract (docs/DATABASE.md, "version 3" and "The error
// contract"): every encoded clip is within its RMS, max and jitter caps when decoded, from any
// frame, one frame at a time as a player decodes; the measurement itself is right on known errors;
// damaged and newer blobs are refused.
#include <gtest/gtest.h>
#include <zstd.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <vector>

#include "compress/subspace.hpp"
#include "database/codec/bytes.hpp"
#include "database/codec/codec.hpp"
#include "database/codec/contract.hpp"
#include "database/format/checksum.hpp"
#include "support/allocation_counter.hpp"

namespace clothdb::codec {
namespace {

// A waving sheet of side_i x side_j vertices with some high-frequency detail no few modes hold
// (so the residual is needed).
std::vector<float> waves(uint32_t frames, uint32_t side_i, uint32_t side_j, double phase,
                         double detail) {
  std::vector<float> x(size_t(frames) * side_i * side_j * 3);
  for (uint32_t f = 0; f < frames; ++f)
    for (uint32_t i = 0; i < side_i; ++i)
      for (uint32_t j = 0; j < side_j; ++j) {
        const double t = f / 30.0 + phase, u = double(i) / side_i, w = double(j) / side_j;
        float* p = x.data() + (size_t(f) * side_i * side_j + size_t(i) * side_j + j) * 3;
        p[0] = float(u + 0.05 * std::sin(3 * t + 4 * w) +
                     detail * std::sin(1.3 * t + 23.0 * u * w + 11 * w));
        p[1] = float(1.5 - w + 0.2 * std::sin(2.1 * t + 6 * u) * w);
        p[2] = float(0.2 * std::cos(1.7 * t + 5 * u + 3 * w) * w +
                     detail * std::cos(2.3 * t + 17.0 * u - 9 * w * w));
      }
  return x;
}
std::vector<float> waves(uint32_t frames, uint32_t side, double phase, double detail) {
  return waves(frames, side, side, phase, detail);
}

Basis basis_of(const std::vector<float>& frames, uint32_t vertices, uint32_t modes) {
  const Subspace s = build_subspace(frames, vertices * 3, modes);
  return make_basis(5, vertices, s.mean.data(), s.basis.data(), s.modes);
}

TEST(Contract, MeasuresKnownErrors) {
  const uint32_t V = 4, F = 5;
  std::vector<float> a(size_t(F) * V * 3, 1.0f), b = a;
  // A constant offset of 3 mm along x on vertex 2: RMS sqrt(9/4) mm, max 3 mm, no jitter.
  for (uint32_t f = 0; f < F; ++f) b[(size_t(f) * V + 2) * 3] += 0.003f;
  ContractFigures m = measure_contract(b.data(), a.data(), F, V);
  EXPECT_NEAR(m.rms, 0.0015, 1e-7);
  EXPECT_NEAR(m.max, 0.003, 1e-7);
  EXPECT_NEAR(m.jitter, 0.0, 1e-7);
  // One frame's error flipping sign: second difference 2 x 1 mm + ... at frames 1..3.
  b = a;
  b[(size_t(2) * V + 1) * 3 + 1] += 0.001f;
  m = measure_contract(b.data(), a.data(), F, V);
  EXPECT_NEAR(m.jitter, 0.002, 1e-7);  // e[3] - 2 e[2] + e[1] = -2 mm
  EXPECT_NEAR(m.max, 0.001, 1e-7);
  EXPECT_TRUE(within(m, {0.001, 0.001, 0.002}, 1e-4));
  EXPECT_FALSE(within(m, {0.001, 0.001, 0.0019}));
}

struct Case {
  uint32_t frames, modes;
  double detail, rms, max, jitter;
};

TEST(CodecV3, EveryClipWithinItsCapsFromAnyFrame) {
  const uint32_t side = 12, V = side * side;
  std::vector<float> sample;
  for (double phase : {0.0, 0.7, 1.9}) {
    const auto w = waves(40, side, phase, 0.004);
    sample.insert(sample.end(), w.begin(), w.end());
  }
  for (const Case& c :
       {Case{30, 4, 0.004, 0.001, 0.003, 0.0001}, Case{11, 2, 0.004, 0.0005, 0.0015, 0.0001},
        Case{60, 8, 0.004, 0.002, 0.006, 0.00005}, Case{2, 4, 0.004, 0.001, 0.003, 0.0001},
        Case{25, 16, 0.0, 0.001, 0.003, 0.0001}}) {
    SCOPED_TRACE(std::to_string(c.frames) + " frames, " + std::to_string(c.modes) + " modes");
    const Basis basis = basis_of(sample, V, c.modes);
    const auto x = waves(c.frames, side, 0.35, c.detail);
    V3Settings s;
    s.contract = {c.rms, c.max, c.jitter};
    V3Stats stats;
    const auto blob = encode_v3(x.data(), c.frames, V, basis, s, &stats);
    BlobInfo info;
    Error err;
    ASSERT_EQ(read_info(blob.data(), blob.size(), &info, &err), Status::Ok) << err.message;
    EXPECT_EQ(info.version, kFormatVersionV3);
    EXPECT_EQ(info.basis_id, basis.id);
    EXPECT_EQ(info.frame_count, c.frames);
    EXPECT_EQ(info.residual_interval, stats.residual_interval);
    // Decoded frame by frame from the last one back (a player jumping in), against the input.
    DecodeScratch scratch;
    const size_t n = size_t(V) * 3;
    std::vector<float> y(x.size());
    for (uint32_t f = c.frames; f-- > 0;)
      ASSERT_EQ(
          decode_frames(blob.data(), blob.size(), f, 1, y.data() + f * n, n, scratch, &err, &basis),
          Status::Ok)
          << err.message;
    const ContractFigures m = measure_contract(y.data(), x.data(), c.frames, V);
    EXPECT_TRUE(within(m, s.contract)) << describe(m);
    EXPECT_EQ(m.rms, stats.figures.rms);
    EXPECT_EQ(m.jitter, stats.figures.jitter);
    EXPECT_EQ(verify(blob.data(), blob.size(), scratch, &err, &basis), Status::Ok) << err.message;
  }
}

TEST(CodecV3, ResidualOnlyWhereTheContractNeedsIt) {
  const uint32_t side = 10, V = side * side;
  const auto smooth = waves(30, side, 0.0, 0.0);
  const Basis basis = basis_of(smooth, V, 12);
  V3Settings s;
  s.contract = {0.001, 0.003, 0.0001};
  V3Stats stats;
  encode_v3(smooth.data(), 30, V, basis, s, &stats);
  EXPECT_EQ(stats.residual_interval, 0u) << "the modes hold these frames";
  const auto detailed = waves(30, side, 0.0, 0.01);
  const Basis few = basis_of(smooth, V, 2);
  encode_v3(detailed.data(), 30, V, few, s, &stats);
  EXPECT_GT(stats.residual_interval, 0u) << "two modes cannot hold 1 cm of detail";
}

// The residual's spatial predictor: on a sheet made of rows the encoder finds the row length in the
// basis's mean shape and predicts from the previous row too (fewer residual bytes than the previous
// vertex alone); row 0, the layout of blobs written before the row existed, still decodes within
// the caps; a row the blob's vertices cannot have is refused.
TEST(CodecV3, ResidualPredictorRowFoundFromTheBasisAndOldRowZeroStillDecodes) {
  const uint32_t side = 12, V = side * side;
  const auto x = waves(30, side, 0.0, 0.004);
  const Basis basis = basis_of(x, V, 3);
  V3Settings s;
  s.contract = {0.001, 0.003, 0.0001};
  V3Stats found, previous;
  const auto blob = encode_v3(x.data(), 30, V, basis, s, &found);
  EXPECT_EQ(found.residual_row, side);
  V3Settings old = s;
  old.residual_row = 0;
  const auto old_blob = encode_v3(x.data(), 30, V, basis, old, &previous);
  EXPECT_EQ(previous.residual_row, 0u);
  EXPECT_LT(found.residual_bytes, previous.residual_bytes);
  DecodeScratch scratch;
  Error err;
  for (const auto* b : {&blob, &old_blob}) {
    std::vector<float> y;
    ASSERT_EQ(decode_all(b->data(), b->size(), y, scratch, &err, &basis), Status::Ok)
        << err.message;
    EXPECT_TRUE(within(measure_contract(y.data(), x.data(), 30, V), s.contract));
  }
  // The row lives at byte 52 of the header (docs/DATABASE.md "version 3"); V or more is refused.
  auto bad = blob;
  bad[52] = uint8_t(V & 0xff);
  bad[53] = uint8_t(V >> 8);
  detail::reseal(bad.data(), bad.size());
  BlobInfo info;
  EXPECT_EQ(read_info(bad.data(), bad.size(), &info, &err), Status::Corrupt);
  EXPECT_NE(std::string(err.message).find("row"), std::string::npos) << err.message;
  V3Settings too_far = s;
  too_far.residual_row = V;
  EXPECT_THROW(encode_v3(x.data(), 30, V, basis, too_far), ClothdbError);
}

// A player decodes a clip one segment at a time (BlobInfo::key_interval frames, as the runtime
// stages it): the decoder then holds one segment, however long the clip, and allocates nothing
// once it has seen a segment of the largest size.
TEST(CodecV3, DecodingHoldsTwoSegmentsAndAllocatesNothingWhenWarm) {
  const uint32_t side = 12, V = side * side;
  const size_t n = size_t(V) * 3;
  const auto sample = waves(60, side, 0.0, 0.004);
  const Basis basis = basis_of(sample, V, 4);
  V3Settings s;
  s.contract = {0.001, 0.003, 0.0001};
  s.segment_frames = 16;
  std::vector<std::vector<uint8_t>> blobs;
  std::vector<std::vector<float>> inputs;
  for (uint32_t frames : {40u, 300u, 290u}) {
    inputs.push_back(waves(frames, side, 0.2 * frames, 0.004));
    V3Stats stats;
    blobs.push_back(encode_v3(inputs.back().data(), frames, V, basis, s, &stats));
    EXPECT_EQ(stats.residual_interval, 1u);
  }
  DecodeScratch scratch;
  Error err;
  std::vector<float> out(size_t(300) * n);
  auto play = [&](size_t b) {
    BlobInfo info;
    ASSERT_EQ(read_info(blobs[b].data(), blobs[b].size(), &info, &err), Status::Ok);
    ASSERT_EQ(info.key_interval, s.segment_frames);
    for (uint32_t f = 0; f < info.frame_count; f += info.key_interval) {
      const uint32_t count = std::min(info.key_interval, info.frame_count - f);
      ASSERT_EQ(decode_frames(blobs[b].data(), blobs[b].size(), f, count, out.data(), out.size(),
                              scratch, &err, &basis),
                Status::Ok)
          << err.message;
      EXPECT_EQ(scratch.frames_reconstructed(), count);
    }
    // The whole clip in one call, as the runtime decodes it: two segments per pass over the basis.
    ASSERT_EQ(decode_frames(blobs[b].data(), blobs[b].size(), 0, info.frame_count, out.data(),
                            out.size(), scratch, &err, &basis),
              Status::Ok)
        << err.message;
    EXPECT_EQ(scratch.frames_reconstructed(), info.frame_count);
  };
  play(0);
  const size_t short_clip = scratch.memory_bytes();
  play(1);
  // Two segments of integers (4 bytes x 2K x (3V + M)) and one of their bytes (4 x K x (3V + M)),
  // and eight frames of the residual for the spatial pass, not the clip's.
  EXPECT_LE(scratch.memory_bytes(), 12 * size_t(s.segment_frames) * (n + 4) + 4 * 8 * n);
  EXPECT_EQ(scratch.memory_bytes(), short_clip);
  const uint64_t before = g_allocations.load();
  play(2);
  play(0);
  EXPECT_EQ(g_allocations.load(), before) << "decoding allocated once warm";
  // And the segments decode to the clip within its contract.
  std::vector<float> y;
  ASSERT_EQ(decode_all(blobs[1].data(), blobs[1].size(), y, scratch, &err, &basis), Status::Ok);
  EXPECT_TRUE(within(measure_contract(y.data(), inputs[1].data(), 300, V), s.contract));
}

// The decoder as it was before it was blocked for speed (commit 78b73c7) and the decoder now give
// the same frames to the bit. tests/data/codec_v3_pinned.bin holds a basis and five blobs that
// commit's encoder wrote (the row predictor and row 0, no residual, segments of 32 and 16 frames,
// vertex and mode counts that fill no register block or cache chunk evenly), and kPinned the XXH64
// of every frame that commit's decoder made of each. The file and the hashes were made by this
// test at that commit with CLOTHDB_WRITE_V3_PINNED=FILE (the branch below, which writes instead of
// checking). Each blob is decoded whole, segment by segment as the runtime stages it, and one
// frame at a time backwards: every way must give the same bits.
TEST(CodecV3, DecodesBitForBitAsBeforeTheFastDecoder) {
  struct Spec {
    uint32_t side_i, side_j, frames, modes, segment;
    int64_t row;
    double detail;
  };
  const Spec specs[] = {{13, 11, 70, 7, 32, -1, 0.004},
                        {13, 11, 70, 7, 32, 0, 0.004},
                        {13, 11, 43, 12, 32, -1, 0.0},
                        {24, 24, 45, 21, 16, -1, 0.003},
                        {7, 5, 9, 3, 4, -1, 0.006}};
  const uint64_t kPinned[] = {0x20fe4dde3df4be17ull, 0x40fb38e2d020e2ccull, 0xcfc1566a21956d52ull,
                              0x831a5555f8b7d988ull, 0x23891bf63de05f8aull};
  std::vector<std::vector<uint8_t>> items;  // for each spec: basis, blob
  if (const char* path = std::getenv("CLOTHDB_WRITE_V3_PINNED")) {
    for (const Spec& sp : specs) {
      const uint32_t V = sp.side_i * sp.side_j;
      auto grid = [&](uint32_t frames, double phase, double detail) {
        return waves(frames, sp.side_i, sp.side_j, phase, detail);
      };
      std::vector<float> sample = grid(sp.frames, 0.0, 0.0);
      const auto more = grid(sp.frames, 1.1, 0.0);
      sample.insert(sample.end(), more.begin(), more.end());
      const Subspace sub = build_subspace(sample, V * 3, sp.modes);
      const Basis basis = make_basis(7, V, sub.mean.data(), sub.basis.data(), sub.modes);
      const auto x = grid(sp.frames, 0.4, sp.detail);
      V3Settings s;
      s.contract = {0.001, 0.003, 0.0001};
      s.segment_frames = sp.segment;
      s.residual_row = sp.row;
      items.push_back(serialize_basis(basis));
      items.push_back(encode_v3(x.data(), sp.frames, V, basis, s));
    }
    std::ofstream out(path, std::ios::binary);
    for (const auto& item : items) {
      const uint32_t size = uint32_t(item.size());
      out.write(reinterpret_cast<const char*>(&size), 4);
      out.write(reinterpret_cast<const char*>(item.data()), std::streamsize(item.size()));
    }
    ASSERT_TRUE(out.good());
  } else {
    std::ifstream in(std::string(CLOTHDB_SOURCE_DIR) + "/tests/data/codec_v3_pinned.bin",
                     std::ios::binary);
    ASSERT_TRUE(in);
    uint32_t size = 0;
    while (in.read(reinterpret_cast<char*>(&size), 4)) {
      items.emplace_back(size);
      ASSERT_TRUE(in.read(reinterpret_cast<char*>(items.back().data()), size));
    }
    ASSERT_EQ(items.size(), 2 * std::size(specs));
  }
  DecodeScratch scratch;
  Error err;
  bool residual = false, none = false;
  for (size_t b = 0; b < std::size(specs); ++b) {
    SCOPED_TRACE("blob " + std::to_string(b));
    const auto& blob = items[2 * b + 1];
    Basis basis;
    ASSERT_EQ(parse_basis(items[2 * b].data(), items[2 * b].size(), 7, &basis, &err), Status::Ok)
        << err.message;
    BlobInfo info;
    ASSERT_EQ(read_info(blob.data(), blob.size(), &info, &err), Status::Ok) << err.message;
    residual |= info.residual_interval > 0;
    none |= info.residual_interval == 0;
    std::vector<float> all;
    ASSERT_EQ(decode_all(blob.data(), blob.size(), all, scratch, &err, &basis), Status::Ok)
        << err.message;
    const uint64_t hash = xxh64(all.data(), all.size() * sizeof(float));
    if (std::getenv("CLOTHDB_WRITE_V3_PINNED")) {
      std::printf("blob %zu: %zu bytes, %u frames, residual %u, decoded XXH64 0x%016llxull\n", b,
                  blob.size(), info.frame_count, info.residual_interval, (unsigned long long)hash);
      continue;
    }
    EXPECT_EQ(hash, kPinned[b]);
    const size_t n = size_t(info.vertex_count) * 3;
    std::vector<float> y(all.size(), -1.0f);
    for (uint32_t f = 0; f < info.frame_count; f += info.key_interval) {
      const uint32_t count = std::min(info.key_interval, info.frame_count - f);
      ASSERT_EQ(decode_frames(blob.data(), blob.size(), f, count, y.data() + f * n, count * n,
                              scratch, &err, &basis),
                Status::Ok);
    }
    EXPECT_EQ(std::memcmp(y.data(), all.data(), all.size() * sizeof(float)), 0);
    std::fill(y.begin(), y.end(), -1.0f);
    for (uint32_t f = info.frame_count; f-- > 0;)
      ASSERT_EQ(
          decode_frames(blob.data(), blob.size(), f, 1, y.data() + f * n, n, scratch, &err, &basis),
          Status::Ok);
    EXPECT_EQ(std::memcmp(y.data(), all.data(), all.size() * sizeof(float)), 0);
  }
  EXPECT_TRUE(residual && none) << "the pinned blobs cover both kinds";
}

// A residual value the payload makes too large for the integers (its top byte plane set, the blob
// re-compressed and resealed so every checksum holds) is refused by the range check of the
// residual's time pass, whether it falls in one of integrate_lanes8's 8-value register blocks or in
// the values after the last whole block (7 x 5 vertices: 105 values, 13 blocks and 1 more), and
// whichever frame of a group of eight it is. The blob rebuilt without the damage decodes as before.
TEST(CodecV3, ResidualOutOfRangeRefusedInBlocksAndTail) {
  const uint32_t si = 7, sj = 5, V = si * sj, F = 20;
  // A basis of smooth waves, frames with detail it does not hold: the residual carries it.
  const Basis basis = basis_of(waves(F, si, sj, 0.0, 0.0), V, 3);
  const auto x = waves(F, si, sj, 0.4, 0.006);
  V3Settings s;
  s.contract = {0.001, 0.003, 0.0001};
  s.segment_frames = 32;  // one segment
  const auto blob = encode_v3(x.data(), F, V, basis, s);
  BlobInfo info;
  Error err;
  ASSERT_EQ(read_info(blob.data(), blob.size(), &info, &err), Status::Ok);
  ASSERT_EQ(info.chunk_count, 1u);
  ASSERT_GT(info.residual_interval, 0u) << "the test needs a blob with a residual";
  // Layout (codec_v3.cpp): 64-byte header, one 16-byte table entry {XXH64, compressed, raw}, the
  // zstd frame; before zstd the coefficients' 4 planes (F x modes), then the residual's (F x 3V).
  const size_t table = 64, payload = table + 16;
  const uint32_t raw_size = bytes::get_u32(blob.data() + table + 12);
  std::vector<uint8_t> raw(raw_size);
  ASSERT_EQ(ZSTD_decompress(raw.data(), raw.size(), blob.data() + payload, blob.size() - payload),
            raw.size());
  auto rebuilt = [&](const std::vector<uint8_t>& r) {
    std::vector<uint8_t> out(blob.begin(), blob.begin() + ptrdiff_t(payload));
    out.resize(payload + ZSTD_compressBound(r.size()));
    const size_t csize =
        ZSTD_compress(out.data() + payload, out.size() - payload, r.data(), r.size(), 3);
    EXPECT_FALSE(ZSTD_isError(csize));
    out.resize(payload + csize);
    bytes::put_u32(out.data() + table + 8, uint32_t(csize));
    detail::reseal(out.data(), out.size());
    return out;
  };
  DecodeScratch scratch;
  std::vector<float> before, after;
  ASSERT_EQ(decode_all(blob.data(), blob.size(), before, scratch, &err, &basis), Status::Ok);
  const auto same = rebuilt(raw);
  ASSERT_EQ(decode_all(same.data(), same.size(), after, scratch, &err, &basis), Status::Ok)
      << err.message;
  EXPECT_EQ(after, before);
  const size_t n = size_t(V) * 3, N = size_t(F) * n, residual = 4 * size_t(F) * info.modes;
  for (const auto& [frame, value] : {std::pair{0u, 17u}, {10u, 40u}, {19u, 104u}, {9u, 104u}}) {
    SCOPED_TRACE("frame " + std::to_string(frame) + ", value " + std::to_string(value));
    auto bad = raw;
    bad[residual + 3 * N + size_t(frame) * n + value] = 0x7f;  // about 1e9 after unzigzag
    const auto damaged = rebuilt(bad);
    DecodeScratch fresh;
    EXPECT_EQ(decode_all(damaged.data(), damaged.size(), after, fresh, &err, &basis),
              Status::Corrupt);
    EXPECT_NE(std::strstr(err.message, "residual out of range"), nullptr) << err.message;
  }
}

TEST(CodecV3, RefusesBadInputAndDamagedOrNewerBlobs) {
  const uint32_t side = 8, V = side * side;
  const auto x = waves(20, side, 0.0, 0.003);
  const Basis basis = basis_of(x, V, 3);
  V3Settings s;
  s.contract = {0.001, 0.003, 0.0001};
  EXPECT_THROW(encode_v3(x.data(), 20, V + 1, basis, s), ClothdbError);
  V3Settings no_jitter = s;
  no_jitter.contract.jitter = 0;
  EXPECT_THROW(encode_v3(x.data(), 20, V, basis, no_jitter), ClothdbError);
  const auto blob = encode_v3(x.data(), 20, V, basis, s);
  DecodeScratch scratch;
  Error err;
  std::vector<float> y;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err), Status::NotFound);
  Basis other = basis;
  other.id = 9;
  EXPECT_EQ(decode_all(blob.data(), blob.size(), y, scratch, &err, &other), Status::NotFound);
  // Every byte flipped: refused (checksums), never a crash.
  for (size_t i = 0; i < blob.size(); i += std::max<size_t>(1, blob.size() / 97)) {
    auto bad = blob;
    bad[i] ^= 0x5a;
    DecodeScratch fresh;
    EXPECT_NE(verify(bad.data(), bad.size(), fresh, &err, &basis), Status::Ok) << "byte " << i;
  }
  // Truncated.
  EXPECT_NE(verify(blob.data(), blob.size() - 1, scratch, &err, &basis), Status::Ok);
  // Resealed payload damage reaches the decoder's own checks: refused or decoded, never a crash.
  auto resealed = blob;
  resealed[resealed.size() / 2] ^= 0xff;
  detail::reseal(resealed.data(), resealed.size());
  DecodeScratch fresh;
  (void)verify(resealed.data(), resealed.size(), fresh, &err, &basis);
  // A newer version than this build reads.
  auto newer = blob;
  newer[4] = uint8_t(kNewestFormatVersion + 1);
  BlobInfo info;
  EXPECT_EQ(read_info(newer.data(), newer.size(), &info, &err), Status::NewerVersion);
}

}  // namespace
}  // namespace clothdb::codec
