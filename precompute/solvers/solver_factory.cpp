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

std::unique_ptr<Solver> make_solver(SolverKind kind, const ClothModel& model,
                                    const SolverSettings& settings) {
  // The record's own ranges (database/run_settings.hpp), then this machine's thread cap.
  validate_solver_settings(settings, "solver settings");
  if (settings.threads > max_solver_threads())
    throw std::invalid_argument("solver settings: threads: " + std::to_string(settings.threads) +
                                " is outside [1, " + std::to_string(max_solver_threads()) +
                                "] (4 x this machine's hardware threads, at most 1024)");
  switch (kind) {
    case SolverKind::MassSpring:
      return make_mass_spring_solver(model, settings);
    case SolverKind::Pbd:
      return make_pbd_solver(model, settings);
    case SolverKind::Xpbd:
      return make_xpbd_solver(model, settings);
    case SolverKind::Newton:
      return make_newton_solver(model, settings);
  }
  return nullptr;
}

}  // namespace clothdb
