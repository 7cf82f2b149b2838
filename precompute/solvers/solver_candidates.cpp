#include "solvers/solver_candidates.hpp"

#include <algorithm>
#include <cmath>
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
  c.label = variation_label(kind, c.settings);
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

std::string variation_label(SolverKind kind, const SolverSettings& s) {
  char buf[160] = "";
  switch (kind) {
    case SolverKind::MassSpring:
      std::snprintf(buf, sizeof buf, "substeps=%d", s.substeps);
      break;
    case SolverKind::Pbd:
      std::snprintf(buf, sizeof buf, "substeps=%d iterations=%d", s.substeps, s.iterations);
      break;
    case SolverKind::Xpbd:
      if (s.stretch_iterations > 0)
        std::snprintf(buf, sizeof buf, "substeps=%d iterations=%d stretch=%d", s.substeps,
                      s.iterations, s.stretch_iterations);
      else
        std::snprintf(buf, sizeof buf, "substeps=%d iterations=%d", s.substeps, s.iterations);
      break;
    case SolverKind::Newton:
      std::snprintf(buf, sizeof buf, "%s substeps=%d tol=%.0e", linear_solver_name(s.linear_solver),
                    s.substeps, s.newton_tolerance);
      break;
  }
  return buf;
}

std::vector<SolverCandidate> scene_variations(SolverKind kind, const SolverSettings& own,
                                              bool quick) {
  std::vector<SolverCandidate> out;
  auto add = [&](const SolverSettings& s) {
    for (const SolverCandidate& c : out)
      if (c.settings.substeps == s.substeps && c.settings.iterations == s.iterations &&
          c.settings.stretch_iterations == s.stretch_iterations &&
          c.settings.newton_tolerance == s.newton_tolerance)
        return;
    SolverCandidate c{kind, s, variation_label(kind, s)};
    if (out.empty()) c.label += " (scene)";
    out.push_back(c);
  };
  auto scaled = [&](double substeps, int iteration_factor) {
    SolverSettings s = own;
    s.substeps = std::max(1, static_cast<int>(std::lround(substeps * own.substeps)));
    s.iterations = own.iterations * iteration_factor;
    s.stretch_iterations = own.stretch_iterations * iteration_factor;
    return s;
  };
  add(own);
  switch (kind) {
    case SolverKind::MassSpring:
      for (double f : quick ? std::vector<double>{2} : std::vector<double>{1.5, 2})
        add(scaled(f, 1));
      break;
    case SolverKind::Pbd:
    case SolverKind::Xpbd: {
      const std::vector<double> factors =
          quick ? std::vector<double>{0.5, 2} : std::vector<double>{0.25, 0.5, 0.75, 1.5, 2};
      for (double f : factors) add(scaled(f, 1));
      if (!quick)
        for (double f : {0.5, 1.0}) add(scaled(f, 2));
      break;
    }
    case SolverKind::Newton:
      for (int substeps : quick ? std::vector<int>{1} : std::vector<int>{1, 2})
        for (double t : {10.0, 1.0, 0.1}) {
          SolverSettings s = scaled(substeps, 1);
          s.newton_tolerance = own.newton_tolerance * t;
          add(s);
        }
      break;
  }
  return out;
}

SolverCandidate scene_reference(SolverKind kind, const SolverSettings& own) {
  // 8x the sub-steps of the scene's own setting, every other field kept: what the setting
  // converges to as the step shrinks, i.e. the motion of the same model (the same constraints,
  // strain limit, contact rounds and tethers for XPBD; the same energies for Newton). Measured
  // against it, a candidate's error is what its discretisation costs, not how far one solver's
  // model is from another's (XPBD and PBD are 90-130 mm from Newton on the small skirt; see
  // explore/auto_solver.hpp). 8x is the factor the solver benchmark's reference uses.
  SolverCandidate c{kind, own, ""};
  c.settings.substeps = own.substeps * 8;
  // The garment itself, not a coarse copy driving it (SolverSettings::coarse_vertices): the
  // reference is the converged motion of the model the scene shows.
  c.settings.coarse_vertices = 0;
  if (kind == SolverKind::Newton) {
    c.settings.newton_tolerance = std::min(own.newton_tolerance, 1e-9);
    c.settings.newton_velocity_tolerance = 0.0;
    c.settings.newton_accept_decrease = false;
  }
  c.label = variation_label(kind, c.settings);
  return c;
}

SolverCandidate reference_candidate() {
  SolverCandidate c = candidate(SolverKind::Newton, 8, 0, 1e-9, LinearSolverKind::SimplicialLDLT);
  // Tight: converged on the force residual only, never kept unconverged.
  c.settings.newton_velocity_tolerance = 0.0;
  c.settings.newton_accept_decrease = false;
  return c;
}

}  // namespace clothdb
