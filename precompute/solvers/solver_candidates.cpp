#include "solvers/solver_candidates.hpp"

#include <algorithm>
#include <cstdio>

namespace clothdb {

SolverCandidate candidate(SolverKind kind, int substeps, int iterations, double tolerance,
                          LinearSolverKind linear) {
  SolverCandidate c{kind, SolverSettings{}, ""};
  c.settings.substeps = substeps;
  c.settings.iterations =
      std::max(1, iterations);  // unused by mass-spring and Newton; the record needs >= 1
  c.settings.newton_tolerance = tolerance;
  c.settings.linear_solver = linear;
  char buf[96] = "";
  switch (kind) {
    case SolverKind::MassSpring:
      std::snprintf(buf, sizeof buf, "substeps=%d", substeps);
      break;
    case SolverKind::Pbd:
    case SolverKind::Xpbd:
      std::snprintf(buf, sizeof buf, "substeps=%d iterations=%d", substeps, iterations);
      break;
    case SolverKind::Newton:
      std::snprintf(buf, sizeof buf, "%s substeps=%d tol=%.0e", linear_solver_name(linear),
                    substeps, tolerance);
      break;
  }
  c.label = buf;
  return c;
}

FrameErrors compare_frames(const std::vector<Eigen::Matrix3Xd>& run,
                           const std::vector<Eigen::Matrix3Xd>& reference, size_t first) {
  FrameErrors out;
  double sum2 = 0, worst = 0, worst_frame = 0;
  long count = 0;
  const size_t compared = std::min(run.size(), reference.size());
  for (size_t f = first; f < compared; ++f) {
    const Eigen::Matrix3Xd d = run[f] - reference[f];
    const double frame2 = d.colwise().squaredNorm().sum();
    sum2 += frame2;
    worst = std::max(worst, d.colwise().norm().maxCoeff());
    worst_frame = std::max(worst_frame, std::sqrt(frame2 / std::max<Eigen::Index>(1, d.cols())));
    count += d.cols();
  }
  if (count > 0) out = {std::sqrt(sum2 / count), worst, worst_frame};
  return out;
}

std::vector<SolverCandidate> solver_candidates(SolverKind kind, bool quick) {
  using L = LinearSolverKind;
  switch (kind) {
    case SolverKind::MassSpring: {
      // Explicit integration is stable only below mass_spring_critical_dt (the stiffest spring
      // mode with Rayleigh damping, mass_spring.cpp), which depends on the scene's mesh and
      // material: the sub-steps are multiples of the count it asks for, so every row is stable
      // by construction (the solver's own check still runs).
      std::vector<SolverCandidate> out;
      for (double multiple : quick ? std::vector<double>{1} : std::vector<double>{1, 2}) {
        out.push_back(candidate(kind, 1, 1));
        out.back().critical_multiple = multiple;
      }
      return out;
    }
    case SolverKind::Pbd:
      if (quick) return {candidate(kind, 1, 10), candidate(kind, 4, 20)};
      return {candidate(kind, 1, 10), candidate(kind, 1, 50), candidate(kind, 4, 10),
              candidate(kind, 4, 20), candidate(kind, 10, 20)};
    case SolverKind::Xpbd:
      if (quick) return {candidate(kind, 1, 20), candidate(kind, 20, 1)};
      return {candidate(kind, 1, 10), candidate(kind, 1, 50), candidate(kind, 5, 4),
              candidate(kind, 10, 1), candidate(kind, 20, 1), candidate(kind, 40, 1),
              candidate(kind, 80, 1)};
    case SolverKind::Newton:
      if (quick)
        return {candidate(kind, 1, 0, 1e-4), candidate(kind, 1, 0, 1e-6, L::ConjugateGradient)};
      return {candidate(kind, 1, 0, 1e-3), candidate(kind, 1, 0, 1e-5), candidate(kind, 2, 0, 1e-5),
              candidate(kind, 4, 0, 1e-5), candidate(kind, 1, 0, 1e-5, L::Cholmod),
              // With an optimised BLAS (OpenBLAS) the fastest direct solver on both the 1,587-
              // and the 8,900-unknown systems measured (docs/notebook/BENCHMARKS.md), so that
              // --auto picks it where it wins; the reference stays on SimplicialLDLT.
              candidate(kind, 1, 0, 1e-5, L::CholmodSupernodal),
              candidate(kind, 1, 0, 1e-5, L::ConjugateGradient),
              candidate(kind, 1, 0, 1e-5, L::ConjugateGradientIC)};
  }
  return {};
}

SolverCandidate reference_candidate() {
  SolverCandidate c = candidate(SolverKind::Newton, 8, 0, 1e-9, LinearSolverKind::SimplicialLDLT);
  // Tight: converged on the force residual only, never kept unconverged.
  c.settings.newton_velocity_tolerance = 0.0;
  c.settings.newton_accept_decrease = false;
  return c;
}

}  // namespace clothdb
