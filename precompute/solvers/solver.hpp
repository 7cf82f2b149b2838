// One solver interface, four implementations: mass-spring (Provot 1995, seed 001), PBD (Mueller
// 2007, seed 000 Algorithm 1), XPBD (Macklin 2016), implicit Newton on discrete elastic plates /
// shells energies (seed 004 Algorithm 1; Baraff & Witkin 1998). One step: state, dt -> state.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "cloth/collision.hpp"
#include "cloth/model.hpp"
#include "database/store/run_settings.hpp"  // SolverKind, SolverSettings: what a database records

namespace clothdb {

struct ClothState {
  Eigen::Matrix3Xd x;  // positions, m
  Eigen::Matrix3Xd v;  // velocities, m/s
};

// The state at rest positions with zero velocity.
ClothState rest_state(const ClothModel& model);

struct StepInputs {
  const Environment* env = nullptr;  // required
  // Positions of model.kinematic vertices at the end of the step (3 x kinematic.size()); empty
  // means the kinematic vertices stay where they are. Solvers interpolate linearly in sub-steps.
  Eigen::Matrix3Xd kinematic_targets;
};

struct StepReport {
  bool stable = true;      // false: the step blew up (NaN/Inf or runaway); state was restored
  int step_halvings = 0;   // Newton: how many times the step was halved to recover
  int iterations = 0;      // Newton iterations or constraint iterations actually run
  int factorizations = 0;  // Newton: matrix factorisations (or preconditioner builds for PCG)
  int unconverged =
      0;  // Newton: sub-steps kept unconverged (SolverSettings::newton_accept_decrease)
  double residual = 0.0;  // Newton: final force residual (N); others: 0
  // XPBD with a strain limit: its passes run in this step (every run: after the constraint
  // sweeps and in each contact round; a pass that corrects nothing ends a run and counts), and
  // the runs that stopped at strain_limit_iterations with an edge still being shortened.
  long strain_limit_passes = 0;
  int strain_limit_capped = 0;
  std::string message;  // why it was unstable or halved, for the user
};

class Solver {
 public:
  virtual ~Solver() = default;
  // Advances `state` by dt. On instability returns stable=false and leaves `state` as it was.
  virtual StepReport step(ClothState& state, double dt, const StepInputs& inputs) = 0;
  // Solver name and its settings, e.g. "xpbd substeps=20 iterations=1".
  virtual std::string describe() const = 0;
};

// Largest OpenMP thread count a solver accepts: four per hardware thread, at most 1024. OpenMP
// crashes asked for 100,000 threads, and a few thousand make a 5-frame run take minutes.
int max_solver_threads();
// validate_solver_settings (database/run_settings.hpp) checks every field of the record;
// make_solver also refuses more threads than max_solver_threads().

std::unique_ptr<Solver> make_solver(SolverKind kind, const ClothModel& model,
                                    const SolverSettings& settings);

// Individual factories (each in its own .cpp).
std::unique_ptr<Solver> make_mass_spring_solver(const ClothModel& model, const SolverSettings& s);
std::unique_ptr<Solver> make_pbd_solver(const ClothModel& model, const SolverSettings& s);
std::unique_ptr<Solver> make_xpbd_solver(const ClothModel& model, const SolverSettings& s);
// XPBD's step without its bending and stretch sweeps: the tethers, the strain limit with its
// contact rounds, the body collisions and self-collision only (the fine pass of an upsampled
// solve, solvers/upsampled.hpp).
std::unique_ptr<Solver> make_xpbd_projection_solver(const ClothModel& model,
                                                    const SolverSettings& s);
std::unique_ptr<Solver> make_newton_solver(const ClothModel& model, const SolverSettings& s);
// Mass-spring (mass_spring.cpp): the recommended largest sub-step (s) for its explicit
// integration on `model`: 80 % of the linear stability limit of the stiffest spring mode, with
// damping. Choose substeps >= dt / mass_spring_critical_dt(model). Infinite if no spring acts on
// a free vertex.
double mass_spring_critical_dt(const ClothModel& model);

// Shared helpers (solver_common.cpp).
// True if every entry of x and v is finite and no speed exceeds max_speed (m/s).
bool state_is_sane(const ClothState& state, double max_speed = 200.0);
// Sets kinematic vertices to the targets interpolated at fraction s in [0,1] between `start`
// (their positions at the step start, 3 x k) and inputs.kinematic_targets; velocities of kinematic
// vertices are set to (target - start) / dt.
void place_kinematic(const ClothModel& model, const Eigen::Matrix3Xd& start,
                     const StepInputs& inputs, double s, double dt, ClothState& state);
// Gathers the current positions of the kinematic vertices (3 x k).
Eigen::Matrix3Xd kinematic_positions(const ClothModel& model, const Eigen::Matrix3Xd& x);

// Diagnostics used by tests and benchmarks.
double max_edge_strain(const ClothModel& model, const Eigen::Matrix3Xd& x);  // max (l - l0)/l0
// Appends the strain (l - l0) / l0 of every edge with a rest length at x to `out` (for
// percentiles) and returns the largest with its edge (the first such; strain -inf and edge
// mesh.edges.size() when no edge has a rest length).
struct EdgeStrainMax {
  double strain;
  size_t edge;
};
EdgeStrainMax append_edge_strains(const ClothModel& model, const Eigen::Matrix3Xd& x,
                                  std::vector<double>& out);
double kinetic_energy(const ClothModel& model, const Eigen::Matrix3Xd& v);  // J, free vertices
double gravity_potential(const ClothModel& model, const Eigen::Matrix3Xd& x, const Vec3& g);

}  // namespace clothdb
