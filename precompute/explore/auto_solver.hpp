// `clothdb precompute --auto`: the cheapest solver setting whose error on this scene's garment is
// within a stated fraction of epsilon. Honest by measurement rather than by a table from other
// scenes: a short calibration simulates the garment along the start of one primary edge with each
// candidate setting of the solver layer's candidate table (solvers/solver_candidates.hpp, also the
// benchmark's sweep) and with a reference at high accuracy (calibration_reference), all from the
// same settled state, and measures each candidate against the reference.
//
// The candidates of the scene's own solver are variations of its own setting (scene_variations:
// the setting itself, fewer and more sub-steps and iterations, every other field of the scene's
// solver block kept), and the reference is that setting at 8x the sub-steps (scene_reference): a
// converged run of the same model. Other solvers named with --auto-solvers get the benchmark's
// table with the scene's settings under it (on_scene).
//
// The chaos floor: a garment's motion can be chaotic, so that two runs of the reference itself,
// one from a start perturbed by 1 um, drift apart over the calibration clip; no candidate can be
// expected closer to the reference than that. The comparison window is the leading frames where
// this floor stays within a quarter of the bound (at least one frame); candidates are simulated
// and compared over those frames only, and the table says how many that was.
//
// Error of a candidate: the largest over the window's frames of the RMS over vertices of
// |x - x_ref| (compare_frames), or, if larger, the state distance of Kim et al.'s epsilon
// at the window's last frame (positions and velocities, database/cloth_graph.hpp
// state_distance). Cost: its
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
  std::string message;          // why unstable
  double error = NAN;           // m (see the top of this file): the larger of the two below
  double position_error = NAN;  // m: the largest per-frame RMS of |x - x_ref| over the window
  double state_error = NAN;     // m: the state distance at the window's last frame
  double cpu_ms_per_frame = 0;
};

struct AutoCalibration {
  SolverCandidate reference;
  double reference_cpu_ms_per_frame = 0;
  int frames = 0;  // frames of the calibration clip
  int window = 0;  // leading frames the candidates are compared over (see the chaos floor above)
  // Per frame 1..frames: RMS over vertices between the reference and the reference from the
  // perturbed start, m.
  std::vector<double> floor;
  double bound = 0;  // m: fraction x epsilon
  int vertices = 0;
  std::vector<AutoCandidate> candidates;  // in sweep order
  int scene = -1;                         // index of the scene's own setting among them, or -1
};

// Runs the calibration on `poses` (the start of a primary edge; the first frames+1 are used).
AutoCalibration calibrate_solvers(const CharacterScene& scene,
                                  const std::vector<std::vector<JointPose>>& poses, double rate,
                                  const AutoSolverOptions& options);

// Index of the cheapest accepted candidate: stable, with an error within fraction x epsilon.
// When none is, but the scene's own setting is a stable candidate (scene_index), the cheapest
// stable candidate whose error is at most the scene's own: the accuracy the scene's setting was
// made with, at no more cost (auto_table says which rule chose). -1 if neither finds one.
int pick_solver(const AutoCalibration& calibration, double epsilon, double fraction);
// Index of the candidate that is the scene's own setting, -1 if it is not one.
int scene_index(const AutoCalibration& calibration);

// The table it chose from (markdown), the chosen row marked, and why each other row lost.
std::string auto_table(const AutoCalibration& calibration, int chosen, double epsilon,
                       double fraction);

}  // namespace clothdb
