#include "solvers/solver.hpp"

namespace clothdb {

std::unique_ptr<Solver> make_solver(SolverKind kind, const ClothModel& model,
                                    const SolverSettings& settings) {
  switch (kind) {
    case SolverKind::MassSpring: return make_mass_spring_solver(model, settings);
    case SolverKind::Pbd: return make_pbd_solver(model, settings);
    case SolverKind::Xpbd: return make_xpbd_solver(model, settings);
    case SolverKind::Newton: return make_newton_solver(model, settings);
  }
  return nullptr;
}

}  // namespace clothdb
