// How a clothdb file was made: the solver, its settings, the codec, epsilon and the budget of a
// precompute run, as one typed record with ONE serialiser (JSON). Every place that records or
// carries these settings uses it: the database (the run row's settings and the garment's solver
// column), the scene file's "solver" block, and the MPI job wire (explore/job_wire.hpp). A new
// solver option is added in this file only (the field table in run_settings.cpp) and then survives
// resume, MPI and edits.
//
// Plain C++ (no Eigen, no SQLite): the solvers include it for SolverSettings, the store side of
// the database to record a run. The runtime does not need it (clothdb_run_settings is a separate
// target, the only one here that uses nlohmann-json).
//
// Validation happens where a record is built from text (and in validate()): NaN, negative or
// out-of-range values are refused with an exception whose message names the field, e.g.
// "run settings: epsilon_m: must be a finite number > 0 (got nan)".
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

#include "database/codec/settings.hpp"

namespace clothdb {

enum class SolverKind { MassSpring, Pbd, Xpbd, Newton };
const char* solver_name(SolverKind kind);  // "mass-spring", "pbd", "xpbd", "newton"
// Parses a name as above; throws std::invalid_argument naming the accepted values.
SolverKind parse_solver_kind(const std::string& name);

// Cholmod: CHOLMOD's simplicial LL^T; CholmodSupernodal: its supernodal LL^T, whose dense blocks
// go to whatever BLAS libblas.so.3 is. ConjugateGradient: Jacobi (diagonal) preconditioner;
// ConjugateGradientIC: incomplete Cholesky.
enum class LinearSolverKind {
  SimplicialLDLT,
  Cholmod,
  ConjugateGradient,
  ConjugateGradientIC,
  CholmodSupernodal
};
// "ldlt", "cholmod", "pcg", "pcg-ic", "cholmod-supernodal"
const char* linear_solver_name(LinearSolverKind kind);
LinearSolverKind parse_linear_solver_kind(const std::string& name);

// Sub-steps and iterations per frame above this are refused: well past what any solver asks
// (explicit mass-spring's stability limit goes up to 200,000 sub-steps in `bench solvers`), far
// below where an int wraps.
constexpr int kMaxSubsteps = 1000000;
constexpr int kMaxIterations = 10000;

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
  // this (m/s), i.e. max |dx_i| / h below it (docs/notebook/BENCHMARKS.md, "Newton on seed 004's
  // grids": the force tolerance above sits within a few times its own rounding floor on stiff
  // cloth, so the loop stalled to the cap). 0: off.
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
  // tolerance explains, which is not understood yet (docs/notebook/BENCHMARKS.md, Newton study).
  enum class Guess { Start, Inertial, Extrapolate };
  Guess newton_guess = Guess::Start;
  // Chord (modified) Newton: keep the last factorisation while each iteration still reduces the
  // force residual to at most this fraction of the previous one; 0 refactorises every iteration.
  // The stale matrix is positive definite, so its direction is still a descent direction and the
  // line search still guarantees progress; only the convergence rate changes (linear, not
  // quadratic), and the tolerance test is the same. Off by default: on seed 004's grids it cost
  // more CPU time than it saved (`clothdb bench newton`, docs/notebook/BENCHMARKS.md).
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
  // (docs/GUIDE.md#the-solvers); bending is soft and cheap to leave at one.
  int stretch_iterations = 0;
  // XPBD: Provot-style strain limit: after the constraint sweeps and before collisions, every
  // edge longer than (1 + strain_limit) l0 is shortened to that, at most strain_limit_iterations
  // Gauss-Seidel passes over the edge colouring (it stops after a pass that corrects nothing).
  // 0: off.
  double strain_limit = 0.0;
  int strain_limit_iterations = 1;
  // XPBD: over-relaxation of the strain limit's passes: an edge over the limit is shortened past
  // it by (strain_limit_relaxation - 1) times its excess (never below its rest length), so a
  // correction that must travel along many edges takes fewer passes (docs/guide/resolution.md).
  // 1: off (shortened to the limit exactly).
  double strain_limit_relaxation = 1.0;
  // XPBD with the strain limit on: after the collision pass, up to this many rounds of the
  // strain limit, with a frictionless collision projection between rounds, so edges the body
  // pushes on are shortened (by sliding along it) rather than left stretched
  // (docs/GUIDE.md#the-solvers). The last round vertices are kept out of the body but may end
  // inside the collision margin. 0: off.
  int strain_limit_contact_rounds = 0;
  // XPBD: Chebyshev semi-iterative acceleration of the stretch sweeps (Wang 2015, "A Chebyshev
  // semi-iterative approach for accelerating projective and position-based dynamics", eq. 12):
  // after stretch sweep k the free vertices are moved to omega_k (x^ - x^(k-2)) + x^(k-2), with
  // omega from this estimate of the sweeps' spectral radius (docs/guide/resolution.md). 0: off.
  double chebyshev_rho = 0.0;
  // XPBD cloth self-collision (docs/guide/self_collision.md): vertex-triangle and edge-edge
  // contacts keep the cloth at least this far (mm) from itself, resolved in every sub-step
  // (precompute/solvers/self_collision.hpp). JSON: "self_collision": {"thickness_mm": T}, written
  // only when on so records made without it read and compare as before. 0: off. Newton, PBD and
  // mass-spring refuse a setting with it on.
  double self_collision_thickness_mm = 0.0;
  // XPBD on a procedural garment (skirt or cape): > 0 solves the same garment made with this many
  // vertices and drives the scene's garment from it: the coarse solution interpolated
  // barycentrically to the fine vertices, then one pass of the fine strain limit, tethers, body
  // collisions and self-collision (precompute/solvers/upsampled.hpp; docs/guide/resolution.md).
  // Every other field applies to the coarse solve; the fine pass takes the strain limit's fields.
  // Written only when on. 0: off (the garment is solved itself).
  int coarse_vertices = 0;
};

// Thrown for an invalid setting; what() is "<where>: <field>: <problem>".
struct SettingsError : std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

// The solver part, as JSON text: {"name": "xpbd", "substeps": 10, ...} with every field of
// SolverSettings (the scene file's "solver" block uses the same names; "tolerance" is
// newton_tolerance). threads is included only when include_threads (it never changes a result,
// so what a database records to compare settings leaves it out).
std::string solver_settings_json(SolverKind kind, const SolverSettings& settings,
                                 bool include_threads = false);
// Parses text as above; fields it does not hold keep the values of `*settings` (so an older
// database's shorter record, or a scene's partial block, reads with the caller's defaults).
// Unknown fields, wrong types and invalid values throw SettingsError naming `where` and the field.
// field_prefix goes before each field name in messages (a scene file's block: "solver.").
void parse_solver_settings_json(const std::string& text, const std::string& where, SolverKind* kind,
                                SolverSettings* settings, const std::string& field_prefix = "");
// Throws SettingsError naming `where` and the first invalid field.
void validate_solver_settings(const SolverSettings& settings, const std::string& where);

namespace db {

using clothdb::SettingsError;

// What a precompute run is given: the record stored in the run row, carried to every MPI worker.
struct RunSettings {
  double epsilon = 0.005;  // m: a clip end links back when the state distance is at most this
  SolverKind solver = SolverKind::Xpbd;
  SolverSettings settings;
  CodecSettings codec;
  double cpu_hours = 0;      // budget: CPU hours of simulation in this run (0: none)
  long max_frames = 0;       // budget: cloth frames simulated in this run (0: none)
  int threads = 1;           // OpenMP threads across jobs
  int batch = 8;             // dead ends per batch (fixed: the result does not depend on threads)
  bool auto_solver = false;  // the solver setting was chosen by `precompute --auto`
  long resim_clip = 0;       // > 0: a `clip resim` of this clip carried forward (not a precompute)
  // Codec version 2 during the run (docs/DATABASE.md, "clothdb precompute ... --codec v2"): modes
  // of the garment subspace the explorer builds from the clips stored so far (0: version 1 only).
  uint32_t subspace_modes = 0;
  // ... coding the cloth relative to a body frame (precompute/compress/body_frame.hpp).
  bool subspace_body_frame = false;
};

// One serialiser: JSON text with every field ({"epsilon_m": ..., "solver": {...}, "codec": {...},
// "cpu_hours": ..., "max_frames": ..., "threads": ..., "batch": ...}). Validates first.
std::string run_settings_json(const RunSettings& run);
// Parses and validates; throws SettingsError naming `where` and the field. Fields missing from
// the text keep the values of `defaults` (records written before a field existed).
RunSettings parse_run_settings_json(const std::string& text, const std::string& where,
                                    const RunSettings& defaults = {});
// Throws SettingsError naming `where` and the first invalid field.
void validate_run_settings(const RunSettings& run, const std::string& where);

}  // namespace db
}  // namespace clothdb
