// Speed against error: every solver over a range of settings on the hard-case scenes, each run
// measured against a reference (the Newton solver at a small step with a tight tolerance).
#pragma once

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "report/svg_plot.hpp"
#include "scenes/hard_cases.hpp"
#include "solvers/solver.hpp"

namespace clothdb {

struct SolverBenchOptions {
  std::vector<std::string> scenes;   // hard-case names, "large-sheet", "seed004-529"; empty: all
  std::vector<std::string> solvers;  // empty: all four
  int frames = 30;                   // simulated frames at 30 fps per run
  int resolution = 0;                // nodes per side for the hard cases (0: scene default)
  int large_vertices = 10000;        // vertex count of "large-sheet"
  std::vector<int> threads{1};       // thread counts to run (the speed-up is reported per row)
  bool quick = false;                // fewer settings per solver (for tests and a fast look)
};

struct BenchConfig {
  SolverKind kind;
  SolverSettings settings;
  std::string label;  // e.g. "substeps=20 iterations=1"
};

struct BenchRow {
  std::string scene;
  int vertices = 0;
  std::string solver;
  std::string settings;
  int threads = 1;
  int frames = 0;
  double ms_per_frame = 0;
  double rms_error_mm = 0;  // RMS over all frames and vertices of |x - x_ref|
  double max_error_mm = 0;  // max over all frames and vertices
  double max_strain = 0;    // max over frames of the max edge strain
  double max_penetration_mm = 0;
  int step_halvings = 0;
  bool stable = true;
  std::string message;
};

// Positions of a run against a reference run, frame by frame from frame `first` on (as many as
// both have): RMS and max over all frames and vertices of |x - x_ref|, and the largest per-frame
// RMS. Metres; NaN when nothing is compared.
struct FrameErrors {
  double rms = NAN, max = NAN, worst_frame_rms = NAN;
};
FrameErrors compare_frames(const std::vector<Eigen::Matrix3Xd>& run,
                           const std::vector<Eigen::Matrix3Xd>& reference, size_t first);

// The settings swept for one solver (fewer when quick).
std::vector<BenchConfig> bench_configs(SolverKind kind, bool quick);
// The reference configuration: Newton, LDLT, 8 sub-steps, tolerance 1e-9.
BenchConfig reference_config();

// Builds a benchmark scene by name (hard cases, "large-sheet", "seed004-529").
ClothScene make_bench_scene(const std::string& name, const SolverBenchOptions& options);

// Runs the sweep; `progress` gets one line per finished run.
std::vector<BenchRow> run_solver_bench(const SolverBenchOptions& options,
                                       const std::function<void(const std::string&)>& progress);

std::string bench_rows_csv(const std::vector<BenchRow>& rows);
std::string bench_rows_json(const std::vector<BenchRow>& rows);
std::string bench_rows_markdown(const std::vector<BenchRow>& rows);
// Error (RMS, mm) against ms per frame for one scene, one series per solver, Pareto front marked.
PlotSpec bench_plot(const std::vector<BenchRow>& rows, const std::string& scene);

}  // namespace clothdb
