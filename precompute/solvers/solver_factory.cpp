#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <thread>

#include "solvers/solver.hpp"

namespace clothdb {

int max_solver_threads() {
  const int hw = int(std::max(1u, std::thread::hardware_concurrency()));
  return std::min(1024, 4 * hw);
}

void validate_solver_settings(const SolverSettings& s, const std::string& prefix) {
  auto range = [&](const char* name, int v, int lo, int hi) {
    if (v < lo || v > hi)
      throw std::invalid_argument(prefix + name + ": " + std::to_string(v) + " is outside [" +
                                  std::to_string(lo) + ", " + std::to_string(hi) + "]");
  };
  range("threads", s.threads, 1, max_solver_threads());
  range("substeps", s.substeps, 1, kMaxSubsteps);
  range("iterations", s.iterations, 1, kMaxIterations);
  if (!(s.newton_tolerance > 0) || !std::isfinite(s.newton_tolerance)) {
    char b[64];
    std::snprintf(b, sizeof b, "%g", s.newton_tolerance);
    throw std::invalid_argument(prefix + "tolerance: " + b + " is not a finite positive number");
  }
}

std::unique_ptr<Solver> make_solver(SolverKind kind, const ClothModel& model,
                                    const SolverSettings& settings) {
  validate_solver_settings(settings);
  switch (kind) {
    case SolverKind::MassSpring: return make_mass_spring_solver(model, settings);
    case SolverKind::Pbd: return make_pbd_solver(model, settings);
    case SolverKind::Xpbd: return make_xpbd_solver(model, settings);
    case SolverKind::Newton: return make_newton_solver(model, settings);
  }
  return nullptr;
}

}  // namespace clothdb
