// The solver benchmarks' shared pieces: the bench scenes by name, mass-spring's sub-steps from its
// stability limit, one measured row against a reference run, and the Newton study (`clothdb bench
// newton`). `clothdb bench solvers` itself is bench/solver_accuracy.hpp
// (docs/GUIDE.md#the-solvers).
#pragma once

#include <cmath>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "hard_cases/hard_cases.hpp"
#include "report/svg_plot.hpp"
#include "solvers/solver.hpp"
#include "solvers/solver_candidates.hpp"

namespace clothdb {

struct SolverBenchOptions {
  std::vector<std::string> scenes;   // hard-case names, "large-sheet", "seed004-529"; empty: all
  std::vector<std::string> solvers;  // empty: all four
  int frames = 30;                   // simulated frames at 30 fps per run
  int resolution = 0;                // nodes per side for the hard cases (0: scene default)
  int large_vertices = 10000;        // vertex count of "large-sheet"
  std::vector<int> threads{1};       // thread counts to run (the speed-up is reported per row)
  bool quick = false;                // fewer settings per solver (for tests and a fast look)
  // Mass-spring rows whose stable sub-step count exceeds this are listed as not run (with the
  // count they need) instead of being simulated.
  int max_mass_spring_substeps = 200000;
};

// A setting of the sweep: the solver layer's candidate table (solvers/solver_candidates.hpp),
// which `precompute --auto` chooses from too.
using BenchConfig = SolverCandidate;

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
  double cpu_ms_per_frame = 0;          // process CPU time (all threads) per frame
  double iterations_per_frame = 0;      // StepReport::iterations, mean over frames
  double factorizations_per_frame = 0;  // Newton's StepReport::factorizations, mean
  // The Newton study only: the last frame against the same scene run at a tight tolerance
  // (newton_tight_config), RMS and max over vertices of |x - x_tight|; NaN elsewhere.
  double end_vs_tight_rms_mm = NAN;
  double end_vs_tight_max_mm = NAN;
  bool stable = true;
  bool run = true;  // false: not simulated (mass-spring needing more sub-steps than allowed)
  std::string message;
};

// The settings swept for one solver (fewer when quick), and the reference configuration.
inline std::vector<BenchConfig> bench_configs(SolverKind kind, bool quick) {
  return solver_candidates(kind, quick);
}
inline BenchConfig reference_config() {
  return reference_candidate();
}
// A configuration's settings for one scene: resolves mass-spring's critical multiple into
// sub-steps (and the label). Returns false when that exceeds options.max_mass_spring_substeps,
// with `why` saying how many it would need.
bool resolve_config(BenchConfig& config, const ClothScene& scene, const SolverBenchOptions& options,
                    std::string& why);
// Runs one configuration on `scene` and measures it against `reference` (the reference run's
// frames).
// With `tight`, also the last frame against that run's (BenchRow::end_vs_tight_*).
BenchRow measure_config(const ClothScene& scene, const BenchConfig& config, int frames,
                        const RunResult& reference, const RunResult* tight = nullptr);

// Builds a benchmark scene by name (hard cases, "large-sheet", "seed004-529").
ClothScene make_bench_scene(const std::string& name, const SolverBenchOptions& options);

// The Newton study (`clothdb bench newton`): the same scene under Newton variants, from the
// original loop (start at x_n, a factorisation every iteration, tight tolerance) through the
// predicted start, chord iterations, a looser tolerance, CHOLMOD and PCG with warm starts.
std::vector<BenchConfig> newton_study_configs();
// The Newton study's tight-tolerance run, whose last frame every variant's is measured against:
// Newton, LDLT, one sub-step (the variants' time discretisation, so what is left is what their
// stopping rule leaves), force tolerance 1e-8 only, never kept unconverged (halved instead).
BenchConfig newton_tight_config();
// RMS and max over vertices of |a - b|, mm.
std::pair<double, double> end_state_distance_mm(const Eigen::Matrix3Xd& a,
                                                const Eigen::Matrix3Xd& b);
// Runs every study configuration `repeat` times and keeps the fastest (by CPU time) of each.
// `only`: when not empty, only the variants whose label contains one of these strings.
std::vector<BenchRow> run_newton_study(const std::vector<std::string>& scenes, int frames,
                                       int repeat, const std::vector<std::string>& only,
                                       const std::function<void(const std::string&)>& progress);
// Markdown table with Newton iterations and factorisations per frame.
std::string newton_study_markdown(const std::vector<BenchRow>& rows);

std::string bench_rows_csv(const std::vector<BenchRow>& rows);
std::string bench_rows_json(const std::vector<BenchRow>& rows);

}  // namespace clothdb
