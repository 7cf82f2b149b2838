// One solver interface, four implementations: mass-spring (Provot 1995, seed 001), PBD (Mueller
// 2007, seed 000 Algorithm 1), XPBD (Macklin 2016), implicit Newton on discrete elastic plates /
// shells energies (seed 004 Algorithm 1; Baraff & Witkin 1998). One step: state, dt -> state.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <string>

#include "cloth/collision.hpp"
#include "cloth/model.hpp"

namespace clothdb {

struct ClothState {
  Eigen::Matrix3Xd x;  // positions, m
  Eigen::Matrix3Xd v;  // velocities, m/s
};

// The state at rest positions with zero velocity.
ClothState rest_state(const ClothModel& model);

enum class SolverKind { MassSpring, Pbd, Xpbd, Newton };
const char* solver_name(SolverKind kind);  // "mass-spring", "pbd", "xpbd", "newton"
// Parses a name as above; throws std::invalid_argument naming the accepted values.
SolverKind parse_solver_kind(const std::string& name);

// ConjugateGradient: Jacobi (diagonal) preconditioner; ConjugateGradientIC: incomplete Cholesky.
enum class LinearSolverKind { SimplicialLDLT, Cholmod, ConjugateGradient, ConjugateGradientIC };
const char* linear_solver_name(LinearSolverKind kind);  // "ldlt", "cholmod", "pcg", "pcg-ic"
LinearSolverKind parse_linear_solver_kind(const std::string& name);

struct SolverSettings {
  int substeps = 1;     // sub-steps per step (all solvers)
  int iterations = 10;  // constraint iterations per sub-step (PBD, XPBD)
  // PBD constraint stiffness in [0, 1] (Mueller 2007); negative: derived from the material so that
  // PBD approximates the same cloth (see pbd.cpp).
  double pbd_stretch_stiffness = 1.0;
  double pbd_bend_stiffness = -1.0;
  // Provot's critical deformation rate for the mass-spring solver (0.1 = 10 %).
  double provot_critical_rate = 0.1;
  // Newton: stop when the free-DOF force residual's infinity norm is below
  // newton_tolerance * (max vertex weight m g), or after newton_max_iterations (then halve dt).
  double newton_tolerance = 1e-6;
  // Newton: also stop once an iteration's update changes no free vertex's velocity by more than
  // this (m/s), i.e. max |dx_i| / h below it (issue 15: the force tolerance above sits within a
  // few times its own rounding floor on stiff cloth, so the loop stalled to the cap). 0: off.
  double newton_velocity_tolerance = 1e-3;
  // Newton: at the iteration cap, or when the line search can make no more progress, keep the
  // iterate if it lowered the incremental potential Phi below its value at the sub-step's start
  // (a descent iterate of backward Euler's minimisation), instead of halving the step. Counted in
  // StepReport::unconverged. false: halve, as before.
  bool newton_accept_decrease = true;
  int newton_max_iterations = 25;
  int newton_max_halvings = 6;
  // Newton's first iterate (seed 004 Algorithm 1 line 22 starts from x_n): Start is x_n;
  // Inertial is x_n + h v_n; Extrapolate is x_n + h v_n + h^2 a with a the acceleration of the
  // previous sub-step this solver produced (when it continues from that state, otherwise as
  // Inertial). Whichever candidate has the lower incremental potential Phi is used, so a bad
  // prediction never costs more than starting from x_n. Off (Start) by default: on a stretched
  // hanging sheet it ended 2e-5 m from the plain loop's solution after six frames, more than the
  // tolerance explains, which is not understood yet (docs/BENCHMARKS.md, Newton study).
  enum class Guess { Start, Inertial, Extrapolate };
  Guess newton_guess = Guess::Start;
  // Chord (modified) Newton: keep the last factorisation while each iteration still reduces the
  // force residual to at most this fraction of the previous one; 0 refactorises every iteration.
  // The stale matrix is positive definite, so its direction is still a descent direction and the
  // line search still guarantees progress; only the convergence rate changes (linear, not
  // quadratic), and the tolerance test is the same. Off by default: on seed 004's grids it cost
  // more CPU time than it saved (`clothdb bench newton`, docs/BENCHMARKS.md).
  double newton_reuse_contraction = 0.0;
  // Try the exact Hessian first (quadratic convergence near a minimum) and fall back to the
  // projected element Hessians when it is indefinite; false: the projected ones only (no wasted
  // factorisation of an indefinite matrix when the cloth is compressed or buckling).
  bool newton_exact_hessian = true;
  // With newton_exact_hessian: start every solve with the projected Hessians and try the exact
  // one only once the residual contracts (the last iteration at most halved it), near the minimum
  // where it is positive definite; far from it (compressed or buckling cloth) the exact matrix is
  // usually indefinite and its factorisation wasted. false: exact first on every iteration.
  bool newton_projected_first = true;
  LinearSolverKind linear_solver = LinearSolverKind::SimplicialLDLT;
  int threads = 1;  // OpenMP threads; results are identical whatever this is
  // XPBD: long-range attachments (Kim, Chentanez & Mueller 2012): each free vertex may be no
  // farther from its geodesically nearest pin than its rest path along the mesh. Cheap, and what
  // keeps a hanging garment from stretching when few iterations leave the constraints soft.
  bool tethers = true;
  // XPBD: Gauss-Seidel sweeps of the stretch (edge) constraints per sub-step; 0: `iterations`.
  // Bending gets `iterations`. Stretch is the stiff part that does not converge in one sweep
  // (issue 15); bending is soft and cheap to leave at one.
  int stretch_iterations = 0;
  // XPBD: Provot-style strain limit: after the constraint sweeps and before collisions, every
  // edge longer than (1 + strain_limit) l0 is shortened to that, strain_limit_iterations
  // Gauss-Seidel passes over the edge colouring. 0: off.
  double strain_limit = 0.0;
  int strain_limit_iterations = 1;
};

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
  int unconverged = 0;     // Newton: sub-steps kept unconverged (SolverSettings::newton_accept_decrease)
  double residual = 0.0;   // Newton: final force residual (N); others: 0
  std::string message;     // why it was unstable or halved, for the user
};

class Solver {
 public:
  virtual ~Solver() = default;
  // Advances `state` by dt. On instability returns stable=false and leaves `state` as it was.
  virtual StepReport step(ClothState& state, double dt, const StepInputs& inputs) = 0;
  // Solver name and its settings, e.g. "xpbd substeps=20 iterations=1".
  virtual std::string describe() const = 0;
};

std::unique_ptr<Solver> make_solver(SolverKind kind, const ClothModel& model,
                                    const SolverSettings& settings);

// Individual factories (each in its own .cpp).
std::unique_ptr<Solver> make_mass_spring_solver(const ClothModel& model, const SolverSettings& s);
std::unique_ptr<Solver> make_pbd_solver(const ClothModel& model, const SolverSettings& s);
std::unique_ptr<Solver> make_xpbd_solver(const ClothModel& model, const SolverSettings& s);
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
double kinetic_energy(const ClothModel& model, const Eigen::Matrix3Xd& v);   // J, free vertices
double gravity_potential(const ClothModel& model, const Eigen::Matrix3Xd& x, const Vec3& g);

}  // namespace clothdb
