// The shared hard cloth scenes, used by tests and by `clothdb bench solvers` alike.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <string>
#include <vector>

#include "cloth/collision.hpp"
#include "cloth/model.hpp"
#include "solvers/solver.hpp"

namespace clothdb {

struct ClothScene {
  std::string name;
  std::string description;
  ClothModel model;
  Environment env;
  ClothState initial;
  double frame_dt = 1.0 / 30.0;  // output rate
  int frames = 60;               // default length
  // Positions of model.kinematic at time t (3 x kinematic.size()); empty function: pins stay.
  std::function<Eigen::Matrix3Xd(double t)> kinematic_path;
  // Moves colliders to time t (sets start/end poses for the step ending at t); empty: static.
  std::function<void(double t_start, double t_end, Environment& env)> collider_path;
  // Self-collision thickness (mm) the scene is meant for: `bench solvers` runs its XPBD settings
  // with it (the other solvers have none, and show their crossings). 0: none.
  double self_collision_mm = 0.0;
};

// Names: "hanging-sheet", "sphere-drape", "swung-sheet", "stiff-large-step", "slivers",
// "stretched-start", "light-stiff-fabric", "cantilever", and for self-collision "folding-sheet"
// and "twisted-skirt". `resolution` is the nodes per side
// (0 = the scene's default, small enough for tests).
std::vector<std::string> hard_case_names();
ClothScene make_hard_case(const std::string& name, int resolution = 0);
// A hanging sheet with about `vertices` vertices (for the 10,000-vertex benchmark).
ClothScene make_large_sheet(int vertices);
// Seed 004's grid: an equilateral-triangle sheet of 23 x 23 = 529 nodes (side 22 edges, 1 m),
// hanging from its two top corners; the Newton solver's speed target is measured on it.
ClothScene make_seed004_grid();
// The same grid laid flat (horizontal) and pinned at the two corners of one edge, so that it
// falls and swings for its first second: the moving case, where Newton needs several iterations
// per frame (the hanging grid above settles and then costs one gradient per frame).
// Seed 004's equilateral plate, kCantileverLength long (x) and 0.15 m wide (z), normal along y,
// `rows` rows along its length, clamped by the first two rows, under 1 % of gravity (the linear
// regime); E 1e7 Pa, t 1 mm, Poisson 0, plate bending rigidity D = E t^3 / 12. The cantilever of
// `bench solvers`' static cases and of the Newton solver's test. The tip is the middle pair of
// nodes of the last row: grid_index(model.mesh, grid_columns / 2 (- 1), rows - 1).
constexpr double kCantileverLength = 0.1;
ClothScene make_cantilever_plate(int rows = 21);

// nodes_per_side: 23 is seed 004's grid; smaller grids of the same 1 m sheet for quick tests.
ClothScene make_seed004_fall(int nodes_per_side = 23);

// Per-frame diagnostics of a run.
struct FrameMetrics {
  double max_strain = 0;        // max (l - l0) / l0 over edges
  double max_penetration = 0;   // m
  double mean_penetration = 0;  // m
  double kinetic_energy = 0;    // J
  double total_energy = 0;      // kinetic + gravity potential (relative to the start), J
  int step_halvings = 0;
  int iterations = 0;      // the solver's StepReport::iterations for the frame
  int factorizations = 0;  // Newton's StepReport::factorizations for the frame
  // XPBD's StepReport::strain_limit_passes and strain_limit_capped for the frame.
  long strain_limit_passes = 0;
  int strain_limit_capped = 0;
  // Edges crossing a triangle they do not touch (cloth/self_intersection.hpp).
  int self_intersections = 0;
  bool stable = true;
};

struct RunResult {
  std::vector<Eigen::Matrix3Xd> frames;  // positions per output frame (frame 0 = initial)
  std::vector<FrameMetrics> metrics;     // one per frame
  bool stable = true;                    // false if any step blew up (the run stops there)
  std::string message;                   // the first instability message
  double seconds = 0;                    // wall time spent in solver steps
  double cpu_seconds = 0;                // process CPU time spent in solver steps (all threads)
};

// Runs `scene` for `frames` output frames (0 = scene.frames) with `solver`, one solver step per
// output frame (the solver sub-steps internally). Stops at the first unstable step.
RunResult run_scene(const ClothScene& scene, Solver& solver, int frames = 0,
                    bool keep_frames = true);

}  // namespace clothdb
