// The candidate settings of each solver, from cheap to accurate, and the reference setting: the
// table that `clothdb bench solvers` sweeps and `precompute --auto` chooses from
// (explore/auto_solver.hpp). It lives with the solvers so that neither depends on the other.
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "solvers/solver.hpp"

namespace clothdb {

struct SolverCandidate {
  SolverKind kind;
  SolverSettings settings;
  std::string label;  // e.g. "substeps=20 iterations=1"
  // Mass-spring: when > 0, the sub-steps are this multiple of the scene's stability count,
  // ceil(frame dt / mass_spring_critical_dt(model)), so that the setting is stable by construction
  // (resolved per scene by the benchmark's resolve_config).
  double critical_multiple = 0;
};

// A candidate with these settings (the others default) and its label.
SolverCandidate candidate(SolverKind kind, int substeps, int iterations, double tolerance = 1e-6,
                          LinearSolverKind linear = LinearSolverKind::SimplicialLDLT);
// The settings tried for one solver (fewer when quick).
std::vector<SolverCandidate> solver_candidates(SolverKind kind, bool quick);
// The reference: Newton, LDLT, 8 sub-steps, tolerance 1e-9.
SolverCandidate reference_candidate();

// Variations of a scene's own solver setting (`precompute --auto`, explore/auto_solver.hpp): each
// is a copy of `own` (so every field of the scene's solver block, whatever fields the solver has,
// is inherited) with the sub-steps and the iterations scaled, cheaper and costlier; the first is
// `own` itself. Sub-steps x 1/4, 1/2, 3/4, 1, 3/2, 2 and, at x 1/2 and x 1, iterations x 2 (XPBD:
// also its stretch sweeps); Newton: sub-steps x 1, 2 and tolerance x 10, 1, 1/10. Mass-spring:
// only costlier sub-steps (fewer would cross its stability limit). Fewer when quick. Equal
// settings appear once; labels name the sub-steps and iterations, "(scene)" marks `own`.
std::vector<SolverCandidate> scene_variations(SolverKind kind, const SolverSettings& own,
                                              bool quick);
// A converged run of the same model: `own` at 8 times the sub-steps (Newton: also force tolerance
// 1e-9 without the update stop, never kept unconverged).
SolverCandidate scene_reference(SolverKind kind, const SolverSettings& own);
// "substeps=15 iterations=1 stretch=2" (Newton: "ldlt substeps=1 tol=1e-6").
std::string variation_label(SolverKind kind, const SolverSettings& s);

// Positions of a run against a reference run, frame by frame from frame `first` on (as many as
// both have): RMS and max over all frames and vertices of |x - x_ref|, and the largest per-frame
// RMS. Metres; NaN when nothing is compared.
struct FrameErrors {
  double rms = NAN, max = NAN, worst_frame_rms = NAN;
};
FrameErrors compare_frames(const std::vector<Eigen::Matrix3Xd>& run,
                           const std::vector<Eigen::Matrix3Xd>& reference, size_t first);

}  // namespace clothdb
