// One sheet scene run with Jan Bender's PositionBasedDynamics XPBD constraint kernels (for
// docs/notebook/BENCHMARKS.md, "Against Bender's PositionBasedDynamics at equal sub-steps"). Built
// only with -DCLOTHDB_BENDER_PBD_DIR (reference/CMakeLists.txt); compiled once with Bender's Real =
// float (as it ships) and once with USE_DOUBLE.
#pragma once

#include "hard_cases/hard_cases.hpp"

namespace clothdb {

struct BenderSheetRun {
  double cpu_seconds = 0;  // this thread's CPU time in the sub-step loops
  double max_strain = 0;   // max (l - l0) / l0 over edges and frames 1..frames
  double last_strain = 0;  // at the last frame
  bool finite = true;      // false if a position became NaN or infinite (the run stops there)
  int frames = 0;          // frames run
};

// Runs `scene` (pins that stay, no colliders: the hanging sheets) for `frames` frames of
// scene.frame_dt with `substeps` sub-steps of one sweep each, as Bender's TimeStepController does
// (semi-implicit Euler, constraints in colour groups, first-order velocity update), on the same
// mesh, masses and pins, with XPBD::solve_DistanceConstraint per edge (stiffness k = 1 / our
// compliance) and XPBD::solve_IsometricBendingConstraint per hinge (stiffness: the bending
// rigidity D), bending first and stretch last like ours, and our explicit air drag.
BenderSheetRun bender_sheet_float(const ClothScene& scene, int frames, int substeps);
BenderSheetRun bender_sheet_double(const ClothScene& scene, int frames, int substeps);

}  // namespace clothdb
