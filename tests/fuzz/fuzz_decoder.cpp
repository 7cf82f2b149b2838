// libFuzzer target for the cloth frame decoder (docs/FUZZING.md). The first input byte picks a
// mode:
//   0: decode the rest as a blob, checksums as given (what a damaged file looks like);
//   1: the same after recomputing the checksums, so mutations reach the header and chunk parsers,
//      zstd and the reconstruction behind them;
//   2: build frames from the bytes, encode them, decode, and check the error bound;
//   3, 4: modes 0 and 1 for codec version 2 blobs, decoded with a made-up basis that fits the
//      blob's header (so mutations reach the subspace reconstruction);
//   5: mode 2 with codec version 2 and a made-up basis, with or without body frames (cloth
//      relative to the body, docs/DATABASE.md, "version 2") as the bytes say.
// Any crash, sanitizer report, bound violation or non-finite decoded value is a bug.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "database/codec/codec.hpp"

namespace {

using namespace clothdb;

void check(bool ok, const char* what) {
  if (!ok) {
    std::fprintf(stderr, "fuzz_decoder: %s\n", what);
    std::abort();
  }
}

// A deterministic basis of `modes` smooth modes over `vertices` vertices, named `id`.
codec::Basis made_up_basis(int64_t id, uint32_t vertices, uint32_t modes) {
  const size_t n = size_t(vertices) * 3;
  std::vector<float> mean(n), m(size_t(modes) * n);
  for (size_t i = 0; i < n; ++i) mean[i] = float(0.01 * double(i % 97));
  for (uint32_t k = 0; k < modes; ++k)
    for (size_t i = 0; i < n; ++i) m[k * n + i] = float(std::sin(0.37 * double((k + 1) * (i + 1))));
  return codec::make_basis(id, vertices, mean.data(), m.data(), modes);
}

void decode_blob(const uint8_t* blob, size_t size) {
  codec::BlobInfo info;
  Error err;
  if (codec::read_info(blob, size, &info, &err) != Status::Ok) {
    check(err.message[0] != '\0', "error without a message");
    return;
  }
  codec::Basis basis;
  if (info.version >= codec::kFormatVersionV2) {
    if (info.vertex_count > 256 || info.modes > 16) return;  // keep each run small
    basis = made_up_basis(info.basis_id, info.vertex_count, info.modes);
  }
  const codec::Basis* b = info.version >= codec::kFormatVersionV2 ? &basis : nullptr;
  codec::DecodeScratch scratch;
  const size_t n = size_t(info.vertex_count) * 3;
  // Bounded output so a large (valid) header cannot exhaust memory: one frame at a time.
  if (n > (size_t(1) << 20)) return;
  std::vector<float> frame(n);
  for (uint32_t f = 0; f < info.frame_count && f < 64; f += 1 + f / 4) {
    if (codec::decode_frames(blob, size, f, 1, frame.data(), frame.size(), scratch, &err, b) !=
        Status::Ok) {
      check(err.message[0] != '\0', "error without a message");
      return;
    }
    const uint32_t qlimit = std::max({info.qmax[0], info.qmax[1], info.qmax[2]});
    for (size_t i = 0; i < n; ++i) {
      check(std::isfinite(frame[i]), "non-finite decoded value");
      if (info.version >= codec::kFormatVersionV3) continue;  // a contract, no grid
      const double lo = info.origin[i % 3], hi = lo + double(qlimit) * info.step;
      check(frame[i] >= float(lo) - 1e-3f * float(1 + std::fabs(lo)) &&
                frame[i] <= float(hi) + 1e-3f * float(1 + std::fabs(hi)),
            "decoded value outside the declared range");
    }
  }
  // A damaged blob may fail verification; only crashes and sanitizer reports matter here.
  (void)codec::verify(blob, size, scratch, &err, b);
}

// Body transforms (codec::SubspaceSettings::body_frames): a turn about y and a drift per frame.
std::vector<float> turning(uint32_t frames, uint8_t seed) {
  std::vector<float> t(size_t(frames) * 12, 0.0f);
  for (uint32_t f = 0; f < frames; ++f) {
    const double a = 0.01 * double((f * (seed | 1u)) % 17);
    float* m = t.data() + size_t(f) * 12;
    m[0] = float(std::cos(a));
    m[2] = float(std::sin(a));
    m[4] = 1.0f;
    m[6] = float(-std::sin(a));
    m[8] = float(std::cos(a));
    m[9] = float(0.001 * f);
    m[11] = float(0.0005 * (seed % 7));
  }
  return t;
}

void roundtrip(const uint8_t* data, size_t size, bool v2) {
  if (size < 4) return;
  const double bounds[] = {1e-5, 1e-4, 5e-4, 2e-3, 0.05};
  codec::EncodeSettings s;
  s.bound = bounds[data[0] % 5];
  s.key_interval = data[1] % 20;
  s.zstd_level = 1 + data[2] % 5;
  s.predictor = codec::Predictor(data[3] % 4);
  const uint32_t vertices = 1 + data[3] / 4 % 40;
  const bool with_body = v2 && (data[2] / 5) % 2 == 1;
  const uint8_t body_seed = data[3];
  data += 4;
  size -= 4;
  const uint32_t frames = uint32_t(size / (vertices * 3 * 2));
  if (frames == 0) return;
  // Two input bytes per coordinate: a smooth ramp plus the bytes as noise, in metres.
  std::vector<float> x(size_t(frames) * vertices * 3);
  for (size_t i = 0; i < x.size(); ++i) {
    const int16_t v = int16_t(data[2 * i] | data[2 * i + 1] << 8);
    x[i] = float(0.001 * double(i / 3 % 97) + v * 1e-4);
  }
  std::vector<uint8_t> blob;
  const codec::Basis basis = made_up_basis(3, vertices, 1 + vertices % 5);
  codec::SubspaceSettings sub;
  std::vector<float> body;
  if (with_body) body = turning(frames, body_seed);
  sub.body_frames = body.empty() ? nullptr : body.data();
  try {
    blob = v2 ? codec::encode_v2(x.data(), frames, vertices, basis, s, sub)
              : codec::encode(x.data(), frames, vertices, s);
  } catch (const ClothdbError& e) {
    check(false, e.what());  // valid input must always encode
  }
  codec::DecodeScratch scratch;
  std::vector<float> y;
  Error err;
  check(codec::decode_all(blob.data(), blob.size(), y, scratch, &err, v2 ? &basis : nullptr) ==
            Status::Ok,
        err.message);
  for (size_t i = 0; i < x.size(); ++i)
    check(std::fabs(double(y[i]) - double(x[i])) <= s.bound, "error bound broken");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  // Modes 3-5 are 0-2 again; decode_blob handles both versions, so the v2 seeds (written with
  // modes 3 and 4) and mutations of v1 seeds into v2 headers both reach the v2 decoder.
  const uint8_t mode = data[0] % 6;
  ++data;
  --size;
  if (mode % 3 == 0) {
    decode_blob(data, size);
  } else if (mode % 3 == 1) {
    std::vector<uint8_t> copy(data, data + size);
    codec::detail::reseal(copy.data(), copy.size());
    decode_blob(copy.data(), copy.size());
  } else {
    roundtrip(data, size, mode == 5);
  }
  return 0;
}

#if defined(CLOTHDB_FUZZ_SEEDS) || defined(CLOTHDB_FUZZ_REPLAY)
// The seed corpus: valid blobs of both versions (modes 0/1 and 3/4) and two round-trip inputs
// (modes 2 and 5), each input with its mode byte first.
std::vector<std::pair<std::string, std::vector<uint8_t>>> seed_inputs() {
  std::vector<std::pair<std::string, std::vector<uint8_t>>> out;
  int count = 0;
  for (uint32_t k : {1u, 3u, 0u}) {
    for (codec::Predictor p : {codec::Predictor::Delta, codec::Predictor::Linear}) {
      const uint32_t side = 5, frames = 7;
      std::vector<float> x(size_t(frames) * side * side * 3);
      for (size_t i = 0; i < x.size(); ++i)
        x[i] = float(0.1 * std::sin(0.3 * double(i % 75) + 0.2 * double(i / 75)));
      codec::EncodeSettings s;
      s.key_interval = k;
      s.predictor = p;
      const auto blob = codec::encode(x.data(), frames, side * side, s);
      const auto blob2 =
          codec::encode_v2(x.data(), frames, side * side, made_up_basis(1, side * side, 4), s);
      codec::SubspaceSettings sub;
      const auto body = turning(frames, uint8_t(k + 3));
      sub.body_frames = body.data();
      const auto blob3 =
          codec::encode_v2(x.data(), frames, side * side, made_up_basis(1, side * side, 4), s, sub);
      for (int which = 0; which < 6; ++which) {
        const uint8_t mode = which < 2 ? uint8_t(which) : uint8_t(3 + which % 2);
        const auto& b = which < 2 ? blob : which < 4 ? blob2 : blob3;
        std::vector<uint8_t> input{mode};
        input.insert(input.end(), b.begin(), b.end());
        out.emplace_back("seed_" + std::to_string(count++), std::move(input));
      }
    }
  }
  // Version 3 (segments of 3 frames, with and without a residual), as stored and resealed.
  {
    const uint32_t side = 5, frames = 8;
    std::vector<float> x(size_t(frames) * side * side * 3);
    for (size_t i = 0; i < x.size(); ++i)
      x[i] = float(0.1 * std::sin(0.3 * double(i % 75) + 0.2 * double(i / 75)));
    for (double rms : {0.5, 0.0005}) {
      codec::V3Settings s;
      s.contract = {rms, 3 * rms, 0.0001};
      s.segment_frames = 3;
      const auto blob =
          codec::encode_v3(x.data(), frames, side * side, made_up_basis(1, side * side, 4), s);
      for (uint8_t mode : {uint8_t(0), uint8_t(1)}) {
        std::vector<uint8_t> input{mode};
        input.insert(input.end(), blob.begin(), blob.end());
        out.emplace_back("seed_" + std::to_string(count++), std::move(input));
      }
    }
  }
  std::vector<uint8_t> roundtrip = {2, 3, 4, 1, 7}, roundtrip_v2 = {5, 3, 4, 1, 7};
  for (int i = 0; i < 600; ++i) roundtrip.push_back(uint8_t(i * 37 % 251));
  for (int i = 0; i < 600; ++i) roundtrip_v2.push_back(uint8_t(i * 53 % 241));
  out.emplace_back("seed_roundtrip", std::move(roundtrip));
  out.emplace_back("seed_roundtrip_v2", std::move(roundtrip_v2));
  return out;
}
#endif

#ifdef CLOTHDB_FUZZ_SEEDS
// Writes the seed corpus into argv[1].
int main(int argc, char** argv) {
  if (argc != 2) return 2;
  for (const auto& [name, input] : seed_inputs()) {
    const std::string path = std::string(argv[1]) + "/" + name;
    FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) return 1;
    std::fwrite(input.data(), 1, input.size(), f);
    std::fclose(f);
  }
  return 0;
}
#endif

#ifdef CLOTHDB_FUZZ_REPLAY
// The default suite's sanitizer run (tests/CMakeLists.txt: codec_sanitized, built with
// -fsanitize=address,undefined): every seed, then the damaged-file cases of test_codec's
// DamagedBlob on every seed blob (each truncation, each byte flipped two ways, as stored and
// resealed so the damage gets past the checksums), through the same checks as the fuzzer. Extra
// arguments are corpus files (e.g. a long fuzz run's) replayed as well. Any sanitizer report or
// failed check aborts; the output counts the inputs run so a run that did nothing shows.
int main(int argc, char** argv) {
  long inputs = 0;
  auto run = [&inputs](const std::vector<uint8_t>& input) {
    LLVMFuzzerTestOneInput(input.data(), input.size());
    ++inputs;
  };
  for (const auto& [name, input] : seed_inputs()) {
    run(input);
    if (input[0] % 3 == 2) continue;  // round-trip inputs are frames, not blobs
    for (uint8_t mode : {uint8_t(input[0] % 3 == 0 ? input[0] : input[0] - 1),
                         uint8_t(input[0] % 3 == 0 ? input[0] + 1 : input[0])}) {
      std::vector<uint8_t> damaged = input;
      damaged[0] = mode;  // as stored (0, 3) or resealed (1, 4)
      for (size_t len = 1; len < input.size(); ++len)
        run(std::vector<uint8_t>(damaged.begin(), damaged.begin() + long(len)));
      for (size_t at = 1; at < input.size(); ++at)
        for (uint8_t flip : {uint8_t(0x01), uint8_t(0x5a)}) {
          damaged[at] ^= flip;
          run(damaged);
          damaged[at] ^= flip;
        }
    }
  }
  for (int a = 1; a < argc; ++a) {
    FILE* f = std::fopen(argv[a], "rb");
    if (!f) {
      std::fprintf(stderr, "codec_sanitized: cannot open %s\n", argv[a]);
      return 1;
    }
    std::vector<uint8_t> input;
    for (int c; (c = std::fgetc(f)) != EOF;) input.push_back(uint8_t(c));
    std::fclose(f);
    run(input);
  }
  std::printf("codec_sanitized: %ld inputs decoded under AddressSanitizer and UBSan\n", inputs);
  return inputs > 1000 ? 0 : 1;
}
#endif
