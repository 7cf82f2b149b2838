// `clothdb bench solvers` (docs/GUIDE.md#the-solvers): how accurate each solver setting is,
// separated into what can be told apart. Per scene:
//  - the chaos floor: the reference against itself started 1 um away. A long-run error at or
//    under that floor is divergence of a chaotic motion, not a measurable solver error;
//  - the short-horizon error: every `restart_every` frames each setting is restarted from the
//    reference's state and run `horizon` frames, against the reference (Newton with uniform
//    sub-steps, no halvings, a force tolerance above its rounding floor), whose own time error is
//    estimated against the same reference at twice its sub-steps. The headline accuracy figure;
//  - self-convergence: the same windows at `refine` times the sub-steps, so that a setting's
//    discretisation error (1x against refined) is separate from its model mismatch (refined
//    against the reference: converged XPBD against converged Newton);
//  - for chaotic scenes, ensemble statistics (sag, p99 strain, kinetic-energy decay, penetration)
//    of each setting against the spread of a perturbed reference ensemble;
//  - the cost in CPU-seconds per simulated second at a fixed short-horizon error, interpolated
//    along each solver's settings, and a Pareto plot (cost against short-horizon error).
// And static cases with analytic answers (membrane elongation F L / (E t w), cantilever tip
// q L^4 / (8 D), catenary sag), where every setting's equilibrium is compared with the formula.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "hard_cases/hard_cases.hpp"
#include "report/svg_plot.hpp"
#include "solvers/solver.hpp"
#include "solvers/solver_candidates.hpp"

namespace clothdb {

struct AccuracyOptions {
  std::vector<std::string> scenes;   // bench scene names (make_bench_scene); empty: the default set
  std::vector<std::string> solvers;  // empty: all four
  bool quick = false;                // the candidates' quick sweep (two settings per solver)
  // Settings run after the sweep (e.g. XPBD with a strain limit, Chebyshev-accelerated sweeps or
  // tethers off: fields the sweep leaves at their defaults), each with its own label.
  std::vector<SolverCandidate> extra;
  int frames = 30;                    // length of the reference and of every continuous run
  int resolution = 0;                 // nodes per side of the hard cases (0: scene default)
  int restart_every = 5;              // k: a short-horizon window starts every k frames
  int horizon = 2;                    // frames run in each window (1-3)
  int refine = 4;                     // self-convergence: sub-steps x refine
  int reference_substeps = 16;        // the reference's uniform sub-steps per frame
  double reference_tolerance = 1e-7;  // Newton force tolerance (x max vertex weight)
  double perturbation = 1e-6;         // m, the chaos floor's start perturbation
  int ensemble = 4;                   // members of the perturbed reference ensemble (>= 2)
  double chaotic_floor_mm = 1.0;      // a scene whose floor reaches this (RMS) is chaotic
  std::vector<double> target_errors_mm{1.0, 10.0};  // cost is read at these short-horizon RMS
  bool statics = true;                              // run the static analytic cases
  int static_frames = 150;  // frames (1/30 s) each setting gets to settle a static case
  int max_mass_spring_substeps = 200000;
  uint64_t seed = 1;
};

// RMS and largest vertex distance, mm (NaN when nothing was compared).
struct ErrorMm {
  double rms = NAN, max = NAN;
};

// A run kept as full states, from output frame `first` on (states[0] is the start).
struct Trajectory {
  std::vector<ClothState> states;
  bool stable = true;
  std::string message;
  int step_halvings = 0;
  double cpu_seconds = 0;  // process CPU time in solver steps
};

// The reference every setting is measured against: Newton, LDLT, `substeps` uniform sub-steps,
// force tolerance `tolerance`, no velocity stop and no unconverged step kept (so a step that does
// not converge is halved, and counted: a uniform reference has none).
SolverCandidate accuracy_reference(int substeps, double tolerance);

// Runs `frames` frames with a fresh solver of `candidate` from `start` at output frame `first`
// (colliders and pins follow the scene's paths from that time on). Stops at an unstable step.
Trajectory simulate_from(const ClothScene& scene, const SolverCandidate& candidate,
                         const ClothState& start, int first, int frames);

// `start` with every free vertex moved by `distance` metres in a seeded random direction.
ClothState perturbed_state(const ClothScene& scene, const ClothState& start, double distance,
                           uint64_t seed);

// Per-frame RMS and max distance (mm) between two runs, as many frames as both have.
std::vector<ErrorMm> frame_errors(const Trajectory& a, const Trajectory& b);
// Pooled over all frames from `first` on.
ErrorMm pooled_error(const Trajectory& a, const Trajectory& b, size_t first = 1);

// Short-horizon windows: a run of `horizon` frames from the reference's state at each start.
struct Windows {
  std::vector<int> starts;                          // output frame of each window's start
  std::vector<std::vector<Eigen::Matrix3Xd>> runs;  // [window][0..horizon-1]: frames start+1..
  bool stable = true;
  std::string message;
  int step_halvings = 0;
  double cpu_seconds = 0;
};
// Window starts 0, k, 2k, ... with start + horizon <= reference frames.
std::vector<int> window_starts(int reference_frames, int restart_every, int horizon);
// Runs `candidate` in every window from the reference's states.
Windows run_windows(const ClothScene& scene, const SolverCandidate& candidate,
                    const Trajectory& reference, int restart_every, int horizon);
// The reference's own frames cut into the same windows (what the windows are measured against).
Windows reference_windows(const Trajectory& reference, int restart_every, int horizon);
// Pooled over every window and frame; NaN if either is unstable or the windows differ.
ErrorMm windows_error(const Windows& a, const Windows& b);

// Statistics that do not depend on one trajectory, for the chaotic scenes.
struct EnsembleStats {
  double sag_mm = NAN;          // mean vertical drop of free vertices from the start, mean over the
                                // second half of the frames
  double strain_p99 = NAN;      // 99th percentile of edge strain (l - l0) / l0, second half
  double kinetic_decay = NAN;   // mean kinetic energy of the last quarter / peak kinetic energy
  double penetration_mm = NAN;  // max penetration over the run
};
EnsembleStats ensemble_stats(const ClothScene& scene, const Trajectory& run);
// Per statistic: min, max, mean and standard deviation over the members.
struct EnsembleSpread {
  EnsembleStats min, max, mean, sd;
  int members = 0;
};
EnsembleSpread ensemble_spread(const std::vector<EnsembleStats>& members);
// How many of the four statistics of `s` lie within [min, max] widened to mean +- 2 sd.
int stats_within_spread(const EnsembleStats& s, const EnsembleSpread& spread);

struct AccuracyRow {
  std::string scene, solver, settings;
  int vertices = 0;
  bool run = true;  // false: not simulated (mass-spring over the sub-step cap); see message
  bool stable = true;
  std::string message;
  // The continuous run of `frames` frames from the scene's start.
  double cpu_s_per_sim_s = NAN;  // CPU-seconds per simulated second
  double long_run_rms_mm = NAN;  // against the reference over the whole run
  double long_run_final_rms_mm = NAN;
  bool long_run_within_floor = false;  // final RMS <= the chaos floor's final RMS: divergence
  int step_halvings = 0;
  // The most edge-triangle crossings in one frame of the run (cloth/self_intersection.hpp; XPBD
  // runs with the scene's self_collision_mm); -1: not run.
  int self_intersections = -1;
  // Short-horizon windows against the reference (the headline).
  double short_rms_mm = NAN, short_max_mm = NAN;
  // Self-convergence: the same windows at `refine` x sub-steps.
  int refine = 0;
  double self_convergence_rms_mm = NAN;  // 1x against refined: discretisation error
  double model_mismatch_rms_mm = NAN;    // refined against the reference
  EnsembleStats stats;
  int stats_within = -1;  // of 4, within the ensemble spread (-1: scene not chaotic)
};

struct CostAtError {
  std::string solver;
  double target_mm = NAN;
  double cpu_s_per_sim_s = NAN;  // NaN: not reached
  std::string how;               // interpolated between which settings, or why not
};
// Interpolates log cost against log error along the Pareto front of one solver's rows to
// `target_mm`: between the cheapest setting at or under the target and the next cheaper one above
// it. If the cheapest setting is already under the target its cost is given ("at most").
CostAtError cost_at_error(const std::vector<AccuracyRow>& rows, const std::string& solver,
                          double target_mm);

struct SceneAccuracy {
  std::string name, description;
  int vertices = 0, frames = 0;
  std::string reference;
  int reference_halvings = 0;  // 0 for a uniform reference; flagged otherwise
  bool reference_stable = true;
  std::string reference_message;
  double reference_cpu_s_per_sim_s = NAN;
  double reference_time_error_rms_mm = NAN;  // windows at 2x its sub-steps against it
  std::vector<ErrorMm> chaos_floor;          // per frame, reference against perturbed reference
  double chaos_floor_final_rms_mm = NAN, chaos_floor_peak_rms_mm = NAN,
         chaos_floor_peak_max_mm = NAN;
  bool chaotic = false;
  std::string chaos_floor_message;      // why the perturbed run stopped early, if it did
  std::vector<EnsembleStats> ensemble;  // members (reference first)
  EnsembleSpread spread;
  std::vector<AccuracyRow> rows;
  std::vector<CostAtError> cost;  // per solver and target error
};

// The static cases.
struct StaticCase {
  std::string name, quantity;  // e.g. "membrane-strip", "elongation"
  std::string formula;         // e.g. "F L / (E t w)"
  ClothScene scene;
  double analytic_mm = 0;
  // The measured quantity (mm) from a settled state.
  std::function<double(const Eigen::Matrix3Xd&)> measure_mm;
};
// A strip 0.1 m wide, about 0.3 m long, hanging from its pinned top row, a weight of 1 % strain at
// its bottom row (tributary shares): elongation = (F + W/2) L / (E t w), W the strip's own weight.
// Equilateral triangles (where the edge-spring membranes have Young's modulus E t), or the quad
// grid with alternating diagonals (`quad_grid`; there an edge-spring lattice with
// k_s = E t A_adj / l0 has 1.2 E t in uniaxial stress: energy density
// E t / 2 [ex^2 + ey^2 + (ex + ey)^2 / 4], free ex = -ey / 5).
StaticCase membrane_strip_case(bool quad_grid = false);
// Seed 004's equilateral plate 0.1 m long clamped by two rows, 1 % gravity: tip deflection
// q L^4 / (8 D), L from half a row spacing behind the last clamped row.
StaticCase cantilever_plate_case(int rows = 21);
// A 1 m strip hung from its two end columns 0.8 m apart: catenary sag a (cosh(S / 2a) - 1) with
// l = 2 a sinh(S / 2a).
StaticCase catenary_strip_case();
std::vector<std::string> static_case_names();
StaticCase make_static_case(const std::string& name);
// Catenary parameter a for a chain of length `length` between supports `span` apart.
double catenary_parameter(double length, double span);

struct StaticRow {
  std::string name, quantity, formula, solver, settings;
  double analytic_mm = NAN, measured_mm = NAN, relative_error = NAN;
  double final_kinetic_energy = NAN;  // J: the settle check
  double max_strain = NAN;
  bool run = true, stable = true;
  std::string message;
};
StaticRow measure_static(const StaticCase& c, const SolverCandidate& candidate, int frames);

struct AccuracyReport {
  AccuracyOptions options;
  std::vector<SceneAccuracy> scenes;
  std::vector<StaticRow> statics;
};

// The settings swept for `options` (per solver, resolved per scene for mass-spring).
std::vector<SolverCandidate> accuracy_candidates(const AccuracyOptions& options);
// `candidate` with sub-steps x factor (its label says so).
SolverCandidate refined_candidate(const SolverCandidate& candidate, int factor);

// Measures one scene; `progress` gets a line per finished piece of work.
SceneAccuracy measure_scene_accuracy(const ClothScene& scene, const AccuracyOptions& options,
                                     const std::function<void(const std::string&)>& progress);
// The whole benchmark. `progress(line, done, total)`: one call per finished unit of work.
AccuracyReport run_accuracy_bench(
    const AccuracyOptions& options,
    const std::function<void(const std::string&, int, int)>& progress);

std::string accuracy_json(const AccuracyReport& report);
std::string accuracy_rows_csv(const AccuracyReport& report);
std::string accuracy_statics_csv(const AccuracyReport& report);
std::string accuracy_markdown(const AccuracyReport& report);
// CPU-seconds per simulated second against short-horizon RMS error, one series per solver, the
// Pareto front dashed, the reference's own time error as a line.
PlotSpec accuracy_plot(const SceneAccuracy& scene);

}  // namespace clothdb
