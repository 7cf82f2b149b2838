// `clothdb bench codec`: compression ratio, measured error and single-core encode/decode
// throughput of the cloth frame codec on simulated frames (issue 4), plus the random-access cost
// of the key-frame interval.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "cli_util.hpp"
#include "commands.hpp"
#include "database/codec.hpp"
#include "exchange/point_cache.hpp"
#include "hard_cases/hard_cases.hpp"

namespace clothdb::cli {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Throughput is per core: timed in this thread's CPU time, so other processes sharing the
// machine's cores do not count against the codec.
double thread_cpu_seconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

struct Frames {
  std::string source;
  uint32_t vertices = 0, frames = 0;
  std::vector<float> x;
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

}  // namespace

void register_bench_codec(CLI::App& bench) {
  struct Args {
    int vertices = 10000, frames = 300, repeat = 3;
    std::string bounds = "0.5,2", key_intervals = "16",
                levels = std::to_string(codec::kDefaultZstdLevel);
    std::string scene = "swung-sheet", input, save;
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
  args->solver.add_to(*cmd);
  cmd->callback([args] {
    Frames f;
    if (!args->input.empty()) {
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
    std::printf(
        "\n| bound (mm) | zstd | K | ratio | bits/coord | max error (mm) | encode (MB/s) | "
        "decode (MB/s) | 1 frame: µs | frames decoded (mean/max) |\n"
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (const auto& b : split_list(args->bounds)) {
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
  });
}

}  // namespace clothdb::cli
