// `clothdb bench codec`: compression ratio, measured error and single-core encode/decode
// throughput of the cloth frame codec on simulated frames
// (docs/RESULTS.md#codec-size-of-the-frames), plus the random-access cost of the key-frame
// interval.
#include <zstd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "cli_util.hpp"
#include "commands.hpp"
#include "compress/body_frame.hpp"
#include "compress/predictability.hpp"
#include "compress/subspace.hpp"
#include "database/codec/codec.hpp"
#include "database/store/writer.hpp"
#include "exchange/point_cache.hpp"
#include "hard_cases/hard_cases.hpp"
#include "report/cpu_time.hpp"

#ifdef CLOTHDB_HAVE_MESHOPTIMIZER
#include <meshoptimizer.h>
#endif

namespace clothdb::cli {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

struct Frames {
  std::string source;
  uint32_t vertices = 0, frames = 0;
  std::vector<float> x;
  std::vector<uint32_t> clip_starts;  // with --db: the frame where each clip begins
  std::vector<float> rest;            // with --db: the garment's rest shape (else frame 0)
};

// Smooth synthetic waves (development aid; the benchmark's figures come from simulations).
Frames make_waves(int vertices, int frames) {
  const int side = std::max(2, int(std::lround(std::sqrt(double(vertices)))));
  Frames f;
  f.source = "synthetic waves, " + std::to_string(side * side) + " vertices";
  f.vertices = uint32_t(side * side);
  f.frames = uint32_t(frames);
  f.x.resize(size_t(frames) * f.vertices * 3);
  for (int k = 0; k < frames; ++k) {
    const double t = k / 30.0;
    for (int i = 0; i < side; ++i)
      for (int j = 0; j < side; ++j) {
        const double u = double(i) / side, w = double(j) / side;
        float* p = f.x.data() + (size_t(k) * f.vertices + size_t(i) * side + j) * 3;
        p[0] = float(u + 0.05 * std::sin(3 * t + 4 * w));
        p[1] = float(1.5 - w + 0.2 * std::sin(2.1 * t + 6 * u) * w);
        p[2] = float(0.2 * std::cos(1.7 * t + 5 * u + 3 * w) * w);
      }
  }
  return f;
}

Frames simulate(const std::string& scene_name, int vertices, int frames,
                const SolverOptions& solver_options) {
  const int resolution = std::max(2, int(std::lround(std::sqrt(double(vertices)))));
  ClothScene scene = scene_name == "large-sheet" ? make_large_sheet(vertices)
                                                 : make_hard_case(scene_name, resolution);
  auto solver = make_solver(solver_options.kind(), scene.model, solver_options.resolved());
  std::fprintf(stderr, "simulating %s: %d vertices, %d frames with %s ...\n", scene.name.c_str(),
               int(scene.model.mesh.rest.cols()), frames, solver->describe().c_str());
  const auto start = Clock::now();
  RunResult run = run_scene(scene, *solver, frames - 1);
  if (!run.stable)
    throw std::runtime_error("simulation of " + scene.name + " became unstable: " + run.message);
  Frames f;
  f.vertices = uint32_t(scene.model.mesh.rest.cols());
  f.frames = uint32_t(run.frames.size());
  f.x.resize(size_t(f.frames) * f.vertices * 3);
  for (size_t k = 0; k < run.frames.size(); ++k)
    for (uint32_t v = 0; v < f.vertices; ++v)
      for (int a = 0; a < 3; ++a) f.x[(k * f.vertices + v) * 3 + a] = float(run.frames[k](a, v));
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "%s (%s), %u vertices, %u frames at 30 fps, %s, simulated in %.0f s",
                scene.name.c_str(), scene.description.c_str(), f.vertices, f.frames,
                solver->describe().c_str(), seconds_since(start));
  f.source = buf;
  return f;
}

struct Row {
  double bound_mm = 0;
  uint32_t key_interval = 0;
  double ratio = 0, max_error_mm = 0, encode_mbs = 0, decode_mbs = 0;
  double random_us = 0, random_frames_mean = 0;
  uint64_t random_frames_max = 0;
  double bits_per_coordinate = 0;
};

Row measure(const Frames& f, double bound_mm, uint32_t key_interval, int level, int repeat) {
  codec::EncodeSettings s;
  s.bound = bound_mm * 1e-3;
  s.key_interval = key_interval;
  s.zstd_level = level;
  const double mb = double(f.x.size()) * sizeof(float) / 1e6;
  Row row;
  row.bound_mm = bound_mm;
  std::vector<uint8_t> blob;
  double best = 1e300;
  for (int r = 0; r < repeat; ++r) {
    const double t = thread_cpu_seconds();
    blob = codec::encode(f.x.data(), f.frames, f.vertices, s);
    best = std::min(best, thread_cpu_seconds() - t);
  }
  row.encode_mbs = mb / best;
  codec::BlobInfo info;
  Error err;
  if (codec::read_info(blob.data(), blob.size(), &info, &err) != Status::Ok)
    throw std::runtime_error(err.message);
  row.key_interval = info.key_interval;
  row.ratio = mb * 1e6 / double(blob.size());
  row.bits_per_coordinate = 8.0 * double(blob.size()) / double(f.x.size());

  codec::DecodeScratch scratch;
  scratch.reserve(f.vertices, info.key_interval);
  std::vector<float> out(f.x.size());
  best = 1e300;
  for (int r = 0; r < std::max(10, repeat * 5); ++r) {
    const double t = thread_cpu_seconds();
    if (codec::decode_frames(blob.data(), blob.size(), 0, f.frames, out.data(), out.size(), scratch,
                             &err) != Status::Ok)
      throw std::runtime_error(err.message);
    best = std::min(best, thread_cpu_seconds() - t);
  }
  row.decode_mbs = mb / best;
  double max_error = 0;
  for (size_t i = 0; i < out.size(); ++i)
    max_error = std::max(max_error, std::fabs(double(out[i]) - double(f.x[i])));
  row.max_error_mm = max_error * 1e3;
  if (max_error > s.bound)
    throw std::runtime_error("decoded error " + std::to_string(max_error) + " exceeds the bound");

  // Random access: single frames in random order, as a player jumping into clips would.
  std::mt19937 rng(1);
  const int lookups = 200;
  uint64_t reconstructed = 0;
  const double t = thread_cpu_seconds();
  for (int i = 0; i < lookups; ++i) {
    const uint32_t frame = uint32_t(rng() % f.frames);
    if (codec::decode_frames(blob.data(), blob.size(), frame, 1, out.data(), out.size(), scratch,
                             &err) != Status::Ok)
      throw std::runtime_error(err.message);
    reconstructed += scratch.frames_reconstructed();
    row.random_frames_max = std::max(row.random_frames_max, scratch.frames_reconstructed());
  }
  row.random_us = (thread_cpu_seconds() - t) / lookups * 1e6;
  row.random_frames_mean = double(reconstructed) / lookups;
  return row;
}

// ---- v1, v2 and meshoptimizer side by side (docs/notebook/BENCHMARKS.md, "Codec version 2") ----

struct Compared {
  std::string codec;
  double bound_mm = 0;  // 0: no per-coordinate bound (v3, Kim-style PCA)
  size_t bytes = 0;     // clip data plus any basis
  double ratio = 0, bits_per_vertex_frame = 0, max_error_mm = 0, decode_gbs = 0;
  codec::ContractFigures contract;  // worst over clips (codec/contract.hpp)
};

// The error contract of decoded frames, clip by clip (jitter does not run across clip ends): the
// worst figure of each kind over the clips.
codec::ContractFigures contract_per_clip(const Frames& f, const std::vector<float>& out) {
  std::vector<uint32_t> starts = f.clip_starts;
  if (starts.empty()) starts.push_back(0);
  codec::ContractFigures worst;
  const size_t n = size_t(f.vertices) * 3;
  for (size_t c = 0; c < starts.size(); ++c) {
    const uint32_t end = c + 1 < starts.size() ? starts[c + 1] : f.frames;
    const auto m = codec::measure_contract(out.data() + starts[c] * n, f.x.data() + starts[c] * n,
                                           end - starts[c], f.vertices);
    worst.rms = std::max(worst.rms, m.rms);
    worst.max = std::max(worst.max, m.max);
    worst.jitter = std::max(worst.jitter, m.jitter);
  }
  return worst;
}

Compared finish(const Frames& f, const std::string& name, double bound_mm, size_t bytes,
                const std::vector<float>& out, double decode_seconds) {
  Compared c;
  c.contract = contract_per_clip(f, out);
  c.codec = name;
  c.bound_mm = bound_mm;
  c.bytes = bytes;
  const double raw = double(f.x.size()) * sizeof(float);
  c.ratio = raw / double(bytes);
  c.bits_per_vertex_frame = 8.0 * double(bytes) / (double(f.vertices) * f.frames);
  double max_error = 0;
  for (size_t i = 0; i < out.size(); ++i)
    max_error = std::max(max_error, std::fabs(double(out[i]) - double(f.x[i])));
  c.max_error_mm = max_error * 1e3;
  if (bound_mm > 0 && max_error > bound_mm * 1e-3)
    throw std::runtime_error(name + ": decoded error " + std::to_string(max_error) +
                             " exceeds the bound");
  c.decode_gbs = raw / decode_seconds / 1e9;
  return c;
}

// Best CPU time of `repeat` runs of fn.
template <typename Fn>
double best_time(int repeat, Fn&& fn) {
  double best = 1e300;
  for (int r = 0; r < repeat; ++r) {
    const double t = thread_cpu_seconds();
    fn();
    best = std::min(best, thread_cpu_seconds() - t);
  }
  return best;
}

Compared compare_v1(const Frames& f, double bound_mm, uint32_t key_interval, int level,
                    int repeat) {
  codec::EncodeSettings s;
  s.bound = bound_mm * 1e-3;
  s.key_interval = key_interval;
  s.zstd_level = level;
  const auto blob = codec::encode(f.x.data(), f.frames, f.vertices, s);
  codec::DecodeScratch scratch;
  std::vector<float> out(f.x.size());
  Error err;
  const double t = best_time(repeat, [&] {
    if (codec::decode_frames(blob.data(), blob.size(), 0, f.frames, out.data(), out.size(), scratch,
                             &err) != Status::Ok)
      throw std::runtime_error(err.message);
  });
  return finish(f, "v1", bound_mm, blob.size(), out, t);
}

// transforms: per-frame body frames (v2 with a body frame), or empty.
Compared compare_v2(const Frames& f, const codec::Basis& basis, double bound_mm,
                    uint32_t key_interval, int level, int repeat,
                    const std::vector<float>& transforms) {
  codec::EncodeSettings s;
  s.bound = bound_mm * 1e-3;
  s.key_interval = key_interval;
  s.zstd_level = level;
  codec::SubspaceSettings sub;
  if (!transforms.empty()) sub.body_frames = transforms.data();
  const auto blob = codec::encode_v2(f.x.data(), f.frames, f.vertices, basis, s, sub);
  codec::DecodeScratch scratch;
  std::vector<float> out(f.x.size());
  Error err;
  const double t = best_time(repeat, [&] {
    if (codec::decode_frames(blob.data(), blob.size(), 0, f.frames, out.data(), out.size(), scratch,
                             &err, &basis) != Status::Ok)
      throw std::runtime_error(err.message);
  });
  return finish(f,
                "v2, " + std::to_string(basis.mode_count) + " modes" +
                    (transforms.empty() ? "" : ", body frame") + " (+ basis)",
                bound_mm, blob.size() + codec::serialize_basis(basis).size(), out, t);
}

// Codec version 3 within a contract, clip by clip (as `db recode --codec v3` encodes them), its
// bytes counting the basis once. Prints where the bytes go.
Compared compare_v3(const Frames& f, const codec::Basis& basis, const codec::Contract& contract,
                    uint32_t segment_frames, int level, int repeat) {
  std::vector<uint32_t> starts = f.clip_starts;
  if (starts.empty()) starts.push_back(0);
  const size_t n = size_t(f.vertices) * 3;
  codec::V3Settings s;
  s.contract = contract;
  s.zstd_level = level;
  s.segment_frames = segment_frames;
  std::vector<std::vector<uint8_t>> blobs;
  const size_t basis_bytes = codec::serialize_basis(basis).size();
  size_t bytes = basis_bytes, header = 0, coefficients = 0, residual = 0;
  uint64_t symbols = 0, nonzero = 0;
  uint32_t with_residual = 0;
  const double t0 = thread_cpu_seconds();
  for (size_t c = 0; c < starts.size(); ++c) {
    const uint32_t end = c + 1 < starts.size() ? starts[c + 1] : f.frames;
    codec::V3Stats stats;
    blobs.push_back(codec::encode_v3(f.x.data() + starts[c] * n, end - starts[c], f.vertices, basis,
                                     s, &stats));
    bytes += blobs.back().size();
    header += stats.header_bytes;
    coefficients += stats.coefficient_bytes;
    residual += stats.residual_bytes;
    symbols += stats.residual_symbols;
    nonzero += stats.residual_nonzero;
    with_residual += stats.residual_interval > 0;
  }
  const double encode_s = thread_cpu_seconds() - t0;
  const double vf = double(f.vertices) * f.frames;
  std::printf(
      "v3, %u modes: bits per vertex-frame: basis %.3f, headers %.3f, coefficients %.3f, residual "
      "%.3f; residual symbols not 0: %.1f %%; encoded in %.1f CPU s\n",
      basis.mode_count, 8.0 * basis_bytes / vf, 8.0 * header / vf, 8.0 * coefficients / vf,
      8.0 * residual / vf, symbols ? 100.0 * double(nonzero) / double(symbols) : 0.0, encode_s);
  codec::DecodeScratch scratch;
  std::vector<float> out(f.x.size());
  Error err;
  // One segment at a time, as the runtime stages a clip (BlobInfo::key_interval frames).
  const double t = best_time(repeat, [&] {
    for (size_t c = 0; c < starts.size(); ++c) {
      const uint32_t end = c + 1 < starts.size() ? starts[c + 1] : f.frames;
      codec::BlobInfo info;
      if (codec::read_info(blobs[c].data(), blobs[c].size(), &info, &err) != Status::Ok)
        throw std::runtime_error(err.message);
      for (uint32_t k = starts[c]; k < end; k += info.key_interval) {
        const uint32_t count = std::min(info.key_interval, end - k);
        if (codec::decode_frames(blobs[c].data(), blobs[c].size(), k - starts[c], count,
                                 out.data() + k * n, size_t(count) * n, scratch, &err,
                                 &basis) != Status::Ok)
          throw std::runtime_error(err.message);
      }
    }
  });
  char name[160];
  std::snprintf(name, sizeof name, "v3, %u modes (+ basis), residual in %u of %zu clips",
                basis.mode_count, with_residual, starts.size());
  return finish(f, name, 0, bytes, out, t);
}

// Kim et al. 2013's storage: the first `modes` modes of the basis (int16 as stored) and float32
// coefficients per frame, no residual; decoded as mean + modes * c. coefficients: frames x
// basis.mode_count, projections of each frame (kim_coefficients).
std::vector<float> kim_coefficients(const Frames& f, const codec::Basis& basis) {
  const size_t n = size_t(f.vertices) * 3;
  const uint32_t M = basis.mode_count;
  std::vector<float> c(size_t(f.frames) * M);
  for (uint32_t m = 0; m < M; ++m) {
    const float* u = basis.modes.data() + size_t(m) * n;
    double uu = 0;
    for (size_t i = 0; i < n; ++i) uu += double(u[i]) * double(u[i]);
    for (uint32_t k = 0; k < f.frames; ++k) {
      const float* x = f.x.data() + k * n;
      double dot = 0;
      for (size_t i = 0; i < n; ++i) dot += double(u[i]) * (double(x[i]) - double(basis.mean[i]));
      c[size_t(k) * M + m] = float(uu > 0 ? dot / uu : 0.0);
    }
  }
  return c;
}

Compared compare_kim(const Frames& f, const codec::Basis& basis, const std::vector<float>& c,
                     uint32_t modes) {
  const size_t n = size_t(f.vertices) * 3;
  std::vector<float> out(f.x.size());
  const double t = thread_cpu_seconds();
  for (uint32_t k = 0; k < f.frames; ++k) {
    float* o = out.data() + k * n;
    std::copy(basis.mean.begin(), basis.mean.end(), o);
    for (uint32_t m = 0; m < modes; ++m) {
      const float* u = basis.modes.data() + size_t(m) * n;
      const float w = c[size_t(k) * basis.mode_count + m];
      for (size_t i = 0; i < n; ++i) o[i] += w * u[i];
    }
  }
  const double seconds = thread_cpu_seconds() - t;
  const size_t bytes = n * 4 + size_t(modes) * (4 + n * 2) + size_t(f.frames) * modes * 4;
  return finish(f, "Kim-style PCA, " + std::to_string(modes) + " modes (+ basis), no residual", 0,
                bytes, out, seconds);
}

#ifdef CLOTHDB_HAVE_MESHOPTIMIZER
// meshoptimizer's vertex codec on the same grid as codec v1's plain quantisation (step just under
// 2 x bound from the minimum, so every value is within the bound), as 16-bit x, y, z plus 2 bytes
// of padding (vertex size must be a multiple of 4), like glTF's KHR_mesh_quantization.
// frame_major: one buffer per frame (meshopt's deltas run between neighbouring vertices, its
// intended use); otherwise one buffer over the whole sequence laid out vertex by vertex, so its
// deltas run in time. zstd (level) on top when level > 0. Decode time includes dequantising to
// float (what the other codecs output).
std::vector<Compared> compare_meshopt(const Frames& f, double bound_mm, int level, int repeat) {
  const double bound = bound_mm * 1e-3;
  const double step = 2 * bound * (1.0 - 1.0 / 1024);
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = f.x[size_t(a)];
  for (size_t i = 0; i < f.x.size(); ++i) {
    lo[i % 3] = std::min(lo[i % 3], double(f.x[i]));
    hi[i % 3] = std::max(hi[i % 3], double(f.x[i]));
  }
  for (int a = 0; a < 3; ++a)
    if ((hi[a] - lo[a]) / step > 65535) return {};  // does not fit 16 bits at this bound
  const size_t V = f.vertices, F = f.frames;
  auto dequantise = [&](uint16_t q, int a) { return float(lo[a] + double(q) * step); };
  std::vector<uint16_t> grid(V * F * 4, 0);  // frame-major: frame, vertex, (x, y, z, pad)
  for (size_t k = 0; k < F; ++k)
    for (size_t v = 0; v < V; ++v)
      for (int a = 0; a < 3; ++a) {
        const double x = f.x[(k * V + v) * 3 + size_t(a)];
        grid[(k * V + v) * 4 + size_t(a)] = uint16_t(std::lround((x - lo[a]) / step));
      }
  std::vector<Compared> rows;
  for (bool frame_major : {true, false}) {
    std::vector<uint16_t> layout = grid;
    if (!frame_major)
      for (size_t k = 0; k < F; ++k)
        for (size_t v = 0; v < V; ++v)
          for (int a = 0; a < 4; ++a)
            layout[(v * F + k) * 4 + size_t(a)] = grid[(k * V + v) * 4 + size_t(a)];
    const size_t buffers = frame_major ? F : 1, per = frame_major ? V : V * F;
    std::vector<std::vector<uint8_t>> enc(buffers);
    size_t mesh_bytes = 0;
    for (size_t b = 0; b < buffers; ++b) {
      enc[b].resize(meshopt_encodeVertexBufferBound(per, 8));
      enc[b].resize(meshopt_encodeVertexBuffer(enc[b].data(), enc[b].size(),
                                               layout.data() + b * per * 4, per, 8));
      mesh_bytes += enc[b].size();
    }
    std::vector<std::vector<uint8_t>> z(buffers);
    size_t z_bytes = 0;
    for (size_t b = 0; b < buffers; ++b) {
      z[b].resize(ZSTD_compressBound(enc[b].size()));
      z[b].resize(ZSTD_compress(z[b].data(), z[b].size(), enc[b].data(), enc[b].size(), level));
      z_bytes += z[b].size();
    }
    std::vector<uint16_t> decoded(V * F * 4);
    std::vector<uint8_t> unz;
    std::vector<float> out(f.x.size());
    for (bool with_zstd : {false, true}) {
      const double t = best_time(repeat, [&] {
        for (size_t b = 0; b < buffers; ++b) {
          const uint8_t* src = enc[b].data();
          size_t size = enc[b].size();
          if (with_zstd) {
            unz.resize(enc[b].size());
            size = ZSTD_decompress(unz.data(), unz.size(), z[b].data(), z[b].size());
            src = unz.data();
          }
          if (meshopt_decodeVertexBuffer(decoded.data() + b * per * 4, per, 8, src, size) != 0)
            throw std::runtime_error("meshoptimizer: decode failed");
        }
        for (size_t k = 0; k < F; ++k)
          for (size_t v = 0; v < V; ++v) {
            const uint16_t* q = decoded.data() + (frame_major ? k * V + v : v * F + k) * 4;
            float* o = out.data() + (k * V + v) * 3;
            o[0] = dequantise(q[0], 0);
            o[1] = dequantise(q[1], 1);
            o[2] = dequantise(q[2], 2);
          }
      });
      const std::string name = std::string("meshopt ") + (frame_major ? "per frame" : "in time") +
                               (with_zstd ? " + zstd " + std::to_string(level) : "");
      rows.push_back(finish(f, name, bound_mm, with_zstd ? z_bytes : mesh_bytes, out, t));
    }
  }
  return rows;
}
#endif

// Frames of a database's clips (decoded), in id order, up to `limit` frames: what `db recode`
// and the runtime see.
Frames frames_from_db(const std::string& path, uint32_t limit) {
  db::Reader reader;
  Error err;
  if (reader.open(path, &err) != Status::Ok) throw std::runtime_error(err.message);
  std::vector<db::ClothClip> clips;
  if (reader.cloth_clips(&clips, &err) != Status::Ok) throw std::runtime_error(err.message);
  Frames f;
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob;
  std::vector<float> x;
  size_t used = 0;
  for (const auto& c : clips) {
    if (f.frames >= limit) break;
    if (reader.clip_blob(c.id, &blob, &err) != Status::Ok ||
        reader.decode_all(blob, &x, scratch, &err) != Status::Ok)
      throw std::runtime_error(err.message);
    const uint32_t take = std::min<uint32_t>(uint32_t(c.frame_count), limit - f.frames);
    f.clip_starts.push_back(f.frames);
    f.vertices = uint32_t(x.size() / 3 / uint32_t(c.frame_count));
    f.x.insert(f.x.end(), x.begin(), x.begin() + ptrdiff_t(size_t(take) * f.vertices * 3));
    f.frames += take;
    ++used;
  }
  if (f.frames == 0) throw std::runtime_error(path + ": no cloth frames");
  db::Garment garment;
  if (reader.garment(&garment, &err) == Status::Ok && garment.vertex_count() == f.vertices)
    f.rest = garment.rest_positions;
  f.source = path + ": the first " + std::to_string(f.frames) + " frames of " +
             std::to_string(used) + " clips, " + std::to_string(f.vertices) +
             " vertices (as stored, decoded)";
  return f;
}

// The comparison table: every codec asked for at every bound, on the same frames.
void compare_codecs(const Frames& f, const std::vector<std::string>& codecs,
                    const std::vector<std::string>& bounds, const std::vector<std::string>& modes,
                    uint32_t key_interval, int level, int repeat, uint32_t basis_frames,
                    const codec::Contract& contract, uint32_t segment_frames) {
  auto wants = [&](const char* name) {
    return std::find(codecs.begin(), codecs.end(), name) != codecs.end();
  };
  // v2 bases, each with the body frames it is used with (empty: character space).
  std::vector<std::pair<codec::Basis, std::vector<float>>> bases;
  const bool subspace_rows = wants("v3") || wants("kim");
  for (const bool body : {false, true}) {
    if (!wants(body ? "v2-body" : "v2") && (body || !subspace_rows)) continue;
    const size_t n = size_t(f.vertices) * 3;
    const size_t stride = std::max<size_t>(1, f.frames / std::max<uint32_t>(1, basis_frames));
    std::vector<float> transforms;
    std::vector<float> sample;
    if (body) {
      // The garment's highest 5 % at rest (frame 0 without a database) carry the body frame.
      const BodyAnchors anchors = body_anchors(
          f.rest.empty() ? std::vector<float>(f.x.begin(), f.x.begin() + ptrdiff_t(n)) : f.rest);
      transforms = fit_body_frames(f.x.data(), f.frames, f.vertices, anchors);
    }
    for (size_t k = 0; k < f.frames; k += stride) {
      sample.insert(sample.end(), f.x.begin() + ptrdiff_t(k * n),
                    f.x.begin() + ptrdiff_t((k + 1) * n));
      if (body)
        to_body_frame(sample.data() + sample.size() - n, 1, f.vertices, transforms.data() + 12 * k);
    }
    for (const auto& m : modes) {
      const double t = thread_cpu_seconds();
      const Subspace s = build_subspace(sample, uint32_t(n), uint32_t(std::stoul(m)));
      bases.emplace_back(codec::make_basis(1, f.vertices, s.mean.data(), s.basis.data(), s.modes),
                         transforms);
      std::printf(
          "v2 basis%s: %u modes from %zu frames in %.1f CPU s, %.2f MB stored as int16; "
          "sample RMS %.2f mm, RMS left by the modes %.2f mm\n",
          body ? " (body frame)" : "", s.modes, sample.size() / n, thread_cpu_seconds() - t,
          double(codec::serialize_basis(bases.back().first).size()) / 1e6, s.sample_rms * 1e3,
          s.residual_rms * 1e3);
    }
  }
  std::printf(
      "\n| codec | bound (mm) | ratio vs float32 | bits/vertex/frame | max coordinate error (mm) | "
      "RMS, worst frame (mm) | max vertex distance (mm) | jitter (mm) | decode (GB/s) |\n"
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  auto print = [](const Compared& c) {
    std::printf("| %s | %s | %.1f:1 | %.3f | %.3f | %.3f | %.3f | %.3f | %.2f |\n", c.codec.c_str(),
                c.bound_mm > 0 ? std::to_string(c.bound_mm).substr(0, 5).c_str() : "contract",
                c.ratio, c.bits_per_vertex_frame, c.max_error_mm, c.contract.rms * 1e3,
                c.contract.max * 1e3, c.contract.jitter * 1e3, c.decode_gbs);
    std::fflush(stdout);
  };
  if (subspace_rows)
    std::printf(
        "(v3 and Kim-style rows: contract RMS %g mm, max %g mm, jitter %g mm; bytes include "
        "the basis)\n",
        contract.rms * 1e3, contract.max * 1e3, contract.jitter * 1e3);
  for (const auto& [basis, transforms] : bases) {
    if (!transforms.empty()) continue;
    if (wants("v3")) print(compare_v3(f, basis, contract, segment_frames, level, repeat));
    if (wants("kim")) {
      // The fewest modes (of this basis, in steps of 8) whose worst-frame RMS is within the
      // contract's: Kim et al.'s PCA at the same RMS, with whatever max and jitter that leaves.
      // Bisection over the mode count (the RMS falls as modes are added).
      const std::vector<float> coefficients = kim_coefficients(f, basis);
      Compared best = compare_kim(f, basis, coefficients, basis.mode_count);
      uint32_t lo = 0, hi = basis.mode_count;  // hi within the cap (or all modes)
      while (hi - lo > 1 && best.contract.rms <= contract.rms) {
        const uint32_t mid = (lo + hi) / 2;
        Compared c = compare_kim(f, basis, coefficients, mid);
        if (c.contract.rms <= contract.rms) {
          best = c;
          hi = mid;
        } else {
          lo = mid;
        }
      }
      print(best);
    }
  }
  for (const auto& b : bounds) {
    const double bound_mm = std::stod(b);
    if (wants("v1")) print(compare_v1(f, bound_mm, key_interval, level, repeat));
    for (const auto& [basis, transforms] : bases)
      if (wants(transforms.empty() ? "v2" : "v2-body"))
        print(compare_v2(f, basis, bound_mm, key_interval, level, repeat, transforms));
#ifdef CLOTHDB_HAVE_MESHOPTIMIZER
    if (wants("meshopt"))
      for (const auto& c : compare_meshopt(f, bound_mm, level, repeat)) print(c);
#else
    if (wants("meshopt"))
      std::printf("| meshopt | %g | not built (no libmeshoptimizer-dev) | | | |\n", bound_mm);
#endif
  }
  std::printf(
      "(Kim et al. 2013: 0.18 bits per vertex per frame, lossy PCA without a hard bound.)\n");
}

// `--predictability`: the table of analyse_predictability (compress/predictability.hpp).
void print_predictability(const Frames& f, const std::vector<std::string>& mode_list,
                          const std::vector<std::string>& bound_list) {
  std::vector<uint32_t> modes;
  for (const auto& m : mode_list) modes.push_back(uint32_t(std::stoul(m)));
  std::vector<double> bounds;
  for (const auto& b : bound_list) bounds.push_back(std::stod(b) * 1e-3);
  const double t = thread_cpu_seconds();
  const PredictabilityReport r =
      analyse_predictability(f.x, f.vertices, f.frames, f.clip_starts, modes, bounds);
  std::printf(
      "body frame: Kabsch fit per frame to the %u vertices that move least (largest rotation "
      "%.1f degrees); %zu clip starts; %.1f CPU s\n\n",
      r.anchors, r.max_rotation_deg, f.clip_starts.size(), thread_cpu_seconds() - t);
  std::printf("| space | modes | RMS left (mm per coordinate) |");
  for (double b : bounds) std::printf(" within %g mm: as is / - previous / linear |", b * 1e3);
  std::printf("\n|---|---:|---:|");
  for (std::size_t i = 0; i < bounds.size(); ++i) std::printf("---|");
  std::printf("\n");
  for (const auto& row : r.rows) {
    std::printf("| %s | %u | %.2f |", row.space.c_str(), row.modes, row.rms_left * 1e3);
    for (std::size_t i = 0; i < bounds.size(); ++i)
      std::printf(" %.1f / %.1f / %.1f %% |", 100 * row.within_as_is[i], 100 * row.within_delta[i],
                  100 * row.within_linear[i]);
    std::printf("\n");
  }
}

}  // namespace

void register_bench_codec(CLI::App& bench) {
  struct Args {
    int vertices = 10000, frames = 300, repeat = 3;
    std::string bounds = "0.5,2", key_intervals = "16",
                levels = std::to_string(codec::kDefaultZstdLevel);
    std::string scene = "swung-sheet", input, save, db;
    std::string codecs = "v1,v2,meshopt", modes = "64";
    double rms_mm = 1, max_mm = 3, jitter_mm = codec::kDefaultJitterCap * 1e3;
    uint32_t segment_frames = codec::V3Settings{}.segment_frames;
    uint32_t basis_frames = 3000, db_frames = 3000;
    bool skip_v1_table = false, predictability = false;
    SolverOptions solver;
  };
  auto args = std::make_shared<Args>();
  args->solver.settings.substeps = 10;
  args->solver.settings.iterations = 2;
  CLI::App* cmd = bench.add_subcommand(
      "codec",
      "Cloth frame codec on simulated frames: compression ratio against raw float32, maximum "
      "error after decoding, single-core encode and decode throughput (MB of float output per "
      "second), and the cost of random access to one frame for each key-frame interval. Prints "
      "a Markdown table.");
  cmd->add_option("--input", args->input,
                  "Frames to compress from a PC2 point cache (skips the simulation)");
  cmd->add_option("--scene", args->scene,
                  "Scene to simulate: a hard case (`clothdb scene list`), large-sheet, or waves "
                  "(synthetic, for development only)")
      ->capture_default_str();
  cmd->add_option("--vertices", args->vertices, "Approximate vertex count of the simulated sheet")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--frames", args->frames, "Frames to simulate at 30 fps")
      ->capture_default_str()
      ->check(number_in(2, 100000));
  cmd->add_option("--bounds", args->bounds, "Comma-separated error bounds in mm")
      ->capture_default_str();
  cmd->add_option("--key-intervals", args->key_intervals,
                  "Comma-separated key-frame intervals K (0: only frame 0 is a key frame)")
      ->capture_default_str();
  cmd->add_option("--levels", args->levels, "Comma-separated zstd compression levels (1..22)")
      ->capture_default_str();
  cmd->add_option("--repeat", args->repeat, "Timing repetitions (best is reported)")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--save-frames", args->save,
                  "Write the frames to this PC2 file, to rerun with --input");
  cmd->add_option("--db", args->db,
                  "Frames from this clothdb database's clips (decoded, in id order; skips the "
                  "simulation)");
  cmd->add_option("--db-frames", args->db_frames, "With --db: frames to take")
      ->capture_default_str()
      ->check(CLI::Range(2u, 10000000u));
  cmd->add_option(
         "--codecs", args->codecs,
         "Codecs for the comparison table: v1, v2 (subspace + residual), v2-body (v2 relative to "
         "a rigid frame of the garment's highest 5 %), meshopt "
         "(meshoptimizer's vertex codec on the same quantised frames; if built with it), v3 "
         "(subspace + a residual steered so the coding error stays within the "
         "--rms-mm/--max-mm/--jitter-mm "
         "contract, clip by clip), kim (Kim et al.'s PCA without a residual, the fewest modes "
         "within --rms-mm)")
      ->capture_default_str();
  cmd->add_option("--rms-mm", args->rms_mm,
                  "v3 and kim: contract cap on each frame's RMS vertex distance (mm)")
      ->capture_default_str()
      ->check(positive_number(1e3));
  cmd->add_option("--max-mm", args->max_mm, "v3: contract cap on any vertex distance (mm)")
      ->capture_default_str()
      ->check(positive_number(1e3));
  cmd->add_option("--jitter-mm", args->jitter_mm,
                  "v3: contract cap on the second difference in time of the coding error (mm)")
      ->capture_default_str()
      ->check(positive_number(1e3));
  cmd->add_option("--segment-frames", args->segment_frames,
                  "v3: frames per segment (each decodes on its own; what a player stages)")
      ->capture_default_str()
      ->check(CLI::Range(1, 4096));
  cmd->add_option("--modes", args->modes,
                  "Comma-separated basis sizes for v2 (PCA of the frames themselves, as `db "
                  "recode` builds it from a database's own frames)")
      ->capture_default_str();
  cmd->add_option("--basis-frames", args->basis_frames,
                  "Frames sampled evenly to build the v2 basis")
      ->capture_default_str();
  cmd->add_flag("--comparison-only", args->skip_v1_table,
                "Skip the v1 table (key intervals, random access); print only the comparison");
  cmd->add_flag("--predictability", args->predictability,
                "Instead of coding: how much of the frames a subspace of --modes modes leaves, in "
                "character space and relative to a rigid body frame fitted to the 5 % of vertices "
                "that move least, and how often that residual is within each of --bounds as is, "
                "minus the previous frame's, or extrapolated linearly in time (what a subspace "
                "codec with a hard bound can hope for)");
  args->solver.add_to(*cmd);
  cmd->callback([args] {
    // Every list is checked before anything is simulated or read.
    number_list("--bounds", args->bounds, 1e-6, 1e6, false);
    number_list("--modes", args->modes, 0, 1024, true);
    number_list("--key-intervals", args->key_intervals, 0, 1 << 20, true);
    number_list("--levels", args->levels, 1, 22, true);
    // A misspelt codec would otherwise drop its rows from the table without a word.
    for (const std::string& c : split_list(args->codecs))
      if (c != "v1" && c != "v2" && c != "v2-body" && c != "meshopt" && c != "v3" && c != "kim")
        throw std::runtime_error("--codecs: unknown codec '" + c +
                                 "' (known: v1, v2, v2-body, meshopt, v3, kim)");
    Frames f;
    if (!args->db.empty()) {
      f = frames_from_db(args->db, args->db_frames);
    } else if (!args->input.empty()) {
      PointCache pc = read_pc2(args->input);
      f.source = args->input + ", " + std::to_string(pc.vertex_count) + " vertices, " +
                 std::to_string(pc.frame_count) + " frames";
      f.vertices = uint32_t(pc.vertex_count);
      f.frames = uint32_t(pc.frame_count);
      f.x = std::move(pc.positions);
    } else if (args->scene == "waves") {
      f = make_waves(args->vertices, args->frames);
    } else {
      f = simulate(args->scene, args->vertices, args->frames, args->solver);
    }
    if (!args->save.empty()) {
      PointCache pc;
      pc.vertex_count = int(f.vertices);
      pc.frame_count = int(f.frames);
      pc.positions = f.x;
      write_pc2(args->save, pc);
      std::fprintf(stderr, "wrote %s\n", args->save.c_str());
    }
    std::printf("frames: %s\n", f.source.c_str());
    std::printf("raw float32: %.1f MB; CPU: %s; one thread, CPU time\n",
                double(f.x.size()) * 4 / 1e6, cpu_model().c_str());
    if (args->predictability) {
      print_predictability(f, split_list(args->modes), split_list(args->bounds));
      return;
    }
    if (!args->skip_v1_table)
      std::printf(
          "\n| bound (mm) | zstd | K | ratio | bits/coord | max error (mm) | encode (MB/s) | "
          "decode (MB/s) | 1 frame: µs | frames decoded (mean/max) |\n"
          "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (const auto& b : split_list(args->skip_v1_table ? std::string() : args->bounds)) {
      for (const auto& level : split_list(args->levels)) {
        for (const auto& k : split_list(args->key_intervals)) {
          const Row r =
              measure(f, std::stod(b), uint32_t(std::stoul(k)), std::stoi(level), args->repeat);
          std::printf(
              "| %g | %d | %u | %.1f:1 | %.2f | %.3f | %.1f | %.0f | %.0f | %.1f / %llu |\n",
              r.bound_mm, std::stoi(level), r.key_interval, r.ratio, r.bits_per_coordinate,
              r.max_error_mm, r.encode_mbs, r.decode_mbs, r.random_us, r.random_frames_mean,
              (unsigned long long)r.random_frames_max);
          std::fflush(stdout);
        }
      }
    }
    compare_codecs(
        f, split_list(args->codecs), split_list(args->bounds), split_list(args->modes),
        uint32_t(std::stoul(split_list(args->key_intervals).front())),
        std::stoi(split_list(args->levels).front()), std::max(3, args->repeat), args->basis_frames,
        codec::Contract{args->rms_mm * 1e-3, args->max_mm * 1e-3, args->jitter_mm * 1e-3},
        args->segment_frames);
  });
}

}  // namespace clothdb::cli
