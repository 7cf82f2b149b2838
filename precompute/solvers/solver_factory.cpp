#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <thread>

#include "solvers/solver.hpp"

namespace clothdb {

int max_solver_threads() {
  const int hw = int(std::max(1u, std::thread::hardware_concurrency()));
  return std::min(1024, 4 * hw);
}

std::unique_ptr<Solver> make_solver(SolverKind kind, const ClothModel& model,
                                    const SolverSettings& settings) {
  // The record's own ranges (database/store/run_settings.hpp), then this machine's thread cap.
  validate_solver_settings(settings, "solver settings");
  if (settings.threads > max_solver_threads())
    throw std::invalid_argument("solver settings: threads: " + std::to_string(settings.threads) +
                                " is outside [1, " + std::to_string(max_solver_threads()) +
                                "] (4 x this machine's hardware threads, at most 1024)");
  // Only XPBD resolves self-contacts (solvers/self_collision.hpp); the others would silently let
  // the cloth pass through itself.
  if (settings.self_collision_thickness_mm > 0.0 && kind != SolverKind::Xpbd)
    throw std::invalid_argument(
        std::string("solver settings: self_collision.thickness_mm: self-collision is implemented "
                    "for xpbd only, not for ") +
        solver_name(kind) + " (remove the self_collision block or use xpbd)");
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
