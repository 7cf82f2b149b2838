// `clothdb precompute --auto`: the cheapest solver setting whose error on this scene's garment is
// within a stated fraction of epsilon. Honest by measurement rather than by a table from other
// scenes: a short calibration simulates the garment along the start of one primary edge with each
// candidate setting of the solver layer's candidate table (solvers/solver_candidates.hpp, also the
// benchmark's sweep) and with a reference at high accuracy (calibration_reference), all from the
// same settled state, and measures each candidate against the reference.
//
// Error of a candidate: the largest over the calibration frames of the RMS over vertices of
// |x - x_ref| (compare_frames), or, if larger, the state distance of Kim et al.'s epsilon
// at the last frame (positions and velocities, database/cloth_graph.hpp state_distance). Cost: its
// thread CPU time per frame on this machine. A candidate is accepted when it is stable and its
// error is at most fraction * epsilon; the choice is the accepted one of least cost. The cost is a
// timing, so two candidates of nearly equal cost may swap between machines or loads; the database
// records the choice and a resumed --auto run reuses it instead of calibrating again.
#pragma once

#include <string>
#include <vector>

#include "character_scene/character_scene.hpp"
#include "solvers/solver_candidates.hpp"

namespace clothdb {

struct AutoSolverOptions {
  std::vector<SolverKind> kinds;  // candidate solvers (empty: the scene's own)
  bool quick = false;             // the benchmark's quick sweep (fewer settings per solver)
  int frames = 15;                // frames of the calibration clip
  double epsilon = 0.005;         // m, the precompute's error bound
  double fraction = 0.5;          // accept error <= fraction * epsilon
  // The reference: false, the first candidate solver at its finest sweep setting with 4 times the
  // sub-steps (the error is then what the setting's discretisation costs within that solver's
  // model); true, the benchmark's Newton reference (reference_candidate), which also counts how far
  // the solver's material model is from Newton's: on the 192-vertex skirt XPBD and PBD are 90-130
  // mm from it at every setting of the sweep, and on the 2,958-vertex demo skirt Newton did not
  // finish the settle and 10 frames in 12 minutes.
  bool newton_reference = false;
};

// The reference for a list of candidate solvers (see AutoSolverOptions::newton_reference).
SolverCandidate calibration_reference(SolverKind first_kind, bool newton_reference);

struct AutoCandidate {
  SolverCandidate config;  // kind and settings (the scene's settings with the sweep's overrides)
  bool stable = true;
  std::string message;  // why unstable
  double error = NAN;   // m (see the top of this file)
  double cpu_ms_per_frame = 0;
};

struct AutoCalibration {
  SolverCandidate reference;
  double reference_cpu_ms_per_frame = 0;
  int frames = 0;
  int vertices = 0;
  std::vector<AutoCandidate> candidates;  // in sweep order
};

// Runs the calibration on `poses` (the start of a primary edge; the first frames+1 are used).
AutoCalibration calibrate_solvers(const CharacterScene& scene,
                                  const std::vector<std::vector<JointPose>>& poses, double rate,
                                  const AutoSolverOptions& options);

// Index of the cheapest accepted candidate, -1 if none is accepted.
int pick_solver(const AutoCalibration& calibration, double epsilon, double fraction);

// The table it chose from (markdown), the chosen row marked, and why each other row lost.
std::string auto_table(const AutoCalibration& calibration, int chosen, double epsilon,
                       double fraction);

}  // namespace clothdb
