// Implicit (backward) Euler on discrete elastic plates / shells energies, solved by Newton-Raphson
// (seed 004 Algorithm 1; Baraff & Witkin 1998, "Large steps in cloth simulation").
//
// One (sub)step of length h from (x_n, v_n) minimises the incremental potential
//   Phi(x) = 1/(2h^2) |x - x_n - h v_n|_M^2 + E(x) - sum_i m_i g . (x_i - x_n,i)
//            + sum_i c A_i / (2h) |x_i - x_n,i|^2 + beta / (2h) (x - x_n)^T K_n (x - x_n)
// over the free DOFs, whose gradient is the backward Euler residual
//   r = M/h^2 (x - x_n - h v_n) - f_elastic(x) - f_gravity - f_drag(v) - f_damping(v),
// with v = (x - x_n)/h. E is the sum of the stretching and hinge-bending energies
// (shell_energy.hpp); c is the environment's linear air drag; beta is the material's Rayleigh
// (stiffness-proportional) damping: the damping force -beta K v uses the projected (positive
// semi-definite) stiffness K_n at the start of the step (kinematic vertices already moved), held
// fixed over the step so that it stays symmetric, only dissipates and derives from a potential
// (the line search needs one); it adds beta/h K_n to the system matrix. Newton's system matrix is
//   A = M/h^2 + c A_i/h + K(x) + beta/h K_n,
// assembled on the free DOFs only (seed 004 "free_index": kinematic vertices are not unknowns)
// into a lower-triangular sparse pattern built once, with a precomputed slot for every element
// Hessian entry; the direct solvers analyse that pattern once and refactorise each iteration.
// Iterations start with the projected element Hessians (compressed edges clamped, bending
// Gauss-Newton), which always give a descent direction, and try the exact Hessian once the residual
// contracts (newton_projected_first), falling back to the projected one when it is indefinite.
// The loop stops when the force residual is below the tolerance or when an update (or, from the
// contraction of two full steps, the updates still to come) changes no velocity by more than
// newton_velocity_tolerance; PCG's linear tolerance follows Eisenstat &
// Walker (1996, choice 2). A sub-step that reaches the iteration cap, or whose line search stalls,
// is kept if it lowered Phi (newton_accept_decrease); otherwise, and on NaN or a system that is
// indefinite even when projected, it is halved recursively (seed 004's remedy for degeneracies)
// up to newton_max_halvings.
#include <omp.h>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#ifdef CLOTHDB_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

#include "solvers/shell_energy.hpp"
#include "solvers/solver.hpp"

namespace clothdb {

namespace {

using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

// Armijo constant and the longest backtracking sequence of the line search.
constexpr double kArmijo = 1e-4;
constexpr int kMaxBacktracks = 12;
// Acceleration floor of the convergence scale, m/s^2: without gravity the tolerance still refers
// to a force a vertex mass would feel at a millimetre per second squared.
constexpr double kMinAccelerationScale = 1e-3;

struct EdgeElement {
  std::array<int, 2> v;
  double rest_length;
  double k_s;
};

struct HingeElement {
  std::array<int, 4> v;
  double theta0;
  double k_b;
};

// Where each entry of an element Hessian goes in the assembled matrix' value array.
struct Scatter {
  std::vector<int> offset;  // per element: first entry in `local` / `slot`
  std::vector<int> local;   // index into the element's column-major Hessian
  std::vector<int> slot;    // index into SpMat::valuePtr()
};

// An element Hessian block coupling a free vertex to a kinematic one: it turns the kinematic
// vertices' motion into damping forces on free DOFs.
struct KinematicCoupling {
  int element;     // index into the edge or hinge arrays
  int free_local;  // local vertex index of the free vertex in the element
  int kin_local;   // local vertex index of the kinematic vertex
};

// %g without the exponent's sign padding: 1e-06 -> 1e-6, 1e+08 -> 1e8.
std::string compact_number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  std::string s(buf);
  const size_t e = s.find('e');
  if (e == std::string::npos) return s;
  std::string mantissa = s.substr(0, e), exponent = s.substr(e + 1);
  std::string sign;
  if (!exponent.empty() && (exponent[0] == '-' || exponent[0] == '+')) {
    if (exponent[0] == '-') sign = "-";
    exponent.erase(0, 1);
  }
  exponent.erase(0, std::min(exponent.find_first_not_of('0'), exponent.size() - 1));
  return mantissa + "e" + sign + exponent;
}

// CHOLMOD 3 (SuiteSparse 5, Debian 12) runs loops of its factorisation in OpenMP regions with a
// fixed num_threads(4) clause, whatever OMP_NUM_THREADS says, so a one-thread solver factorised on
// four threads: on the 3k skirt the fork-joins around every supernode cost more than the
// supernodal factorisation itself (docs/notebook/BENCHMARKS.md, "Newton on seed 004's grids").
// While alive and `active`, this makes the calling thread's parallel regions inactive (one thread
// each). max-active-levels is a per-thread ICV since OpenMP 5.0 (libgomp 11 and later), so other
// threads' parallel regions are not affected.
class SerialOpenMpScope {
 public:
  explicit SerialOpenMpScope(bool active) : saved_(active ? omp_get_max_active_levels() : -1) {
    if (active) omp_set_max_active_levels(0);
  }
  ~SerialOpenMpScope() {
    if (saved_ >= 0) omp_set_max_active_levels(saved_);
  }
  SerialOpenMpScope(const SerialOpenMpScope&) = delete;
  SerialOpenMpScope& operator=(const SerialOpenMpScope&) = delete;

 private:
  int saved_;
};

// The linear solvers behind one interface. `factorize` factorises the matrix (direct solvers) or
// builds the preconditioner (PCG); `solve` then solves with it, and may be called again after
// later Newton iterations without a new factorisation (chord iterations: the direct solvers keep
// their factors, PCG keeps the matrix and preconditioner it was given). Both return false when
// the matrix is not positive definite or the solve failed; `why` then says which.
class LinearSolver {
 public:
  // `threads`: the solver's thread count; with one, CHOLMOD runs on the calling thread only.
  LinearSolver(LinearSolverKind kind, const SpMat& pattern, int threads)
      : kind_(kind),
        serial_(threads <= 1 && (kind == LinearSolverKind::Cholmod ||
                                 kind == LinearSolverKind::CholmodSupernodal)) {
    const SerialOpenMpScope serial(serial_);
    switch (kind_) {
      case LinearSolverKind::SimplicialLDLT:
        // The fill-reducing ordering and the elimination tree depend only on the pattern, which
        // is fixed: analysed once here, refactorised numerically every time.
        ldlt_.analyzePattern(pattern);
        break;
      case LinearSolverKind::Cholmod:
      case LinearSolverKind::CholmodSupernodal:
#ifdef CLOTHDB_HAVE_CHOLMOD
        // LL^T (not LDL^T) so that an indefinite matrix is reported rather than factorised.
        // Simplicial: as fast as SimplicialLDLT at 1,587 unknowns, 1.4x faster at 8,900.
        // Supernodal: factorises dense column blocks with the BLAS behind libblas.so.3; on
        // OpenBLAS 2x faster than SimplicialLDLT at 1,587 unknowns and 5x at 8,900, on the
        // reference BLAS no faster and 1.3x (docs/notebook/BENCHMARKS.md, "Newton on seed 004's
        // grids"). A failed (indefinite) supernodal factorisation leaves the factor supernodal, so
        // the projected retry that follows it is supernodal too.
        cholmod_.setMode(kind_ == LinearSolverKind::CholmodSupernodal
                             ? Eigen::CholmodSupernodalLLt
                             : Eigen::CholmodSimplicialLLt);
        // Indefinite systems are expected (and handled): no warnings on stderr.
        cholmod_.cholmod().print = 0;
        cholmod_.analyzePattern(pattern);
        break;
#else
        throw std::invalid_argument(std::string("newton: linear solver '") +
                                    linear_solver_name(kind_) +
                                    "' requested but clothdb was built without CHOLMOD");
#endif
      case LinearSolverKind::ConjugateGradient:
        cg_.analyzePattern(pattern);
        break;
      case LinearSolverKind::ConjugateGradientIC:
        cg_ic_.analyzePattern(pattern);  // the AMD ordering of the incomplete factor, once
        break;
    }
  }

  bool factorize(const SpMat& a, std::string& why) {
    const SerialOpenMpScope serial(serial_);
    switch (kind_) {
      case LinearSolverKind::SimplicialLDLT:
        ldlt_.factorize(a);
        if (ldlt_.info() != Eigen::Success) {
          why = "LDLT factorisation failed (singular matrix)";
          return false;
        }
        // LDL^T succeeds on indefinite matrices; a non-positive pivot means the Newton direction
        // need not be a descent direction.
        if (!(ldlt_.vectorD().minCoeff() > 0.0)) {
          why = "system matrix is indefinite (LDLT pivot <= 0)";
          return false;
        }
        return true;
      case LinearSolverKind::Cholmod:
      case LinearSolverKind::CholmodSupernodal:
#ifdef CLOTHDB_HAVE_CHOLMOD
        cholmod_.factorize(a);
        if (cholmod_.info() != Eigen::Success) {
          why = "CHOLMOD factorisation failed (matrix not positive definite)";
          return false;
        }
#endif
        return true;
      case LinearSolverKind::ConjugateGradient:
        cg_.factorize(a);
        return true;
      case LinearSolverKind::ConjugateGradientIC:
        cg_ic_.factorize(a);
        if (cg_ic_.preconditioner().info() != Eigen::Success) {
          why = "incomplete Cholesky preconditioner failed";
          return false;
        }
        return true;
    }
    return false;
  }

  // Solves A d = b with the last factorisation. `guess` (may be empty) warm-starts PCG;
  // `relative_tolerance` is PCG's |A d - b| / |b| target.
  bool solve(const Eigen::VectorXd& b, const Eigen::VectorXd& guess, double relative_tolerance,
             Eigen::VectorXd& d, std::string& why) {
    const SerialOpenMpScope serial(serial_);
    switch (kind_) {
      case LinearSolverKind::SimplicialLDLT:
        d = ldlt_.solve(b);
        break;
      case LinearSolverKind::Cholmod:
      case LinearSolverKind::CholmodSupernodal:
#ifdef CLOTHDB_HAVE_CHOLMOD
        d = cholmod_.solve(b);
#endif
        break;
      case LinearSolverKind::ConjugateGradient:
        if (!cg_solve(cg_, b, guess, relative_tolerance, d, why)) return false;
        break;
      case LinearSolverKind::ConjugateGradientIC:
        if (!cg_solve(cg_ic_, b, guess, relative_tolerance, d, why)) return false;
        break;
    }
    if (!d.allFinite()) {
      why = "linear solve produced NaN";
      return false;
    }
    return true;
  }

 private:
  template <class Cg>
  static bool cg_solve(Cg& cg, const Eigen::VectorXd& b, const Eigen::VectorXd& guess,
                       double relative_tolerance, Eigen::VectorXd& d, std::string& why) {
    cg.setTolerance(relative_tolerance);
    d = guess.size() == b.size() ? Eigen::VectorXd(cg.solveWithGuess(b, guess))
                                 : Eigen::VectorXd(cg.solve(b));
    if (cg.info() != Eigen::Success) {
      why = "PCG did not converge in " + std::to_string(cg.iterations()) + " iterations";
      return false;
    }
    // CG on an indefinite matrix can return a non-descent direction: b = -r, so descent means
    // d . b > 0.
    if (!(d.dot(b) > 0.0)) {
      why = "system matrix is indefinite (PCG direction is not a descent direction)";
      return false;
    }
    return true;
  }

  LinearSolverKind kind_;
  bool serial_;  // CHOLMOD on one thread: its OpenMP regions stay on the caller (SerialOpenMpScope)
  Eigen::SimplicialLDLT<SpMat, Eigen::Lower> ldlt_;
#ifdef CLOTHDB_HAVE_CHOLMOD
  Eigen::CholmodDecomposition<SpMat, Eigen::Lower> cholmod_;
#endif
  // The CG solvers keep a reference to the system matrix (the solver's a_, whose values the
  // Newton loop overwrites in place before every factorize()).
  Eigen::ConjugateGradient<SpMat, Eigen::Lower, Eigen::DiagonalPreconditioner<double>> cg_;
  Eigen::ConjugateGradient<SpMat, Eigen::Lower,
                           Eigen::IncompleteCholesky<double, Eigen::Lower, Eigen::AMDOrdering<int>>>
      cg_ic_;
};

class NewtonSolver final : public Solver {
 public:
  NewtonSolver(const ClothModel& model, const SolverSettings& settings)
      : model_(model), settings_(settings) {
    if (settings_.substeps < 1) throw std::invalid_argument("newton: substeps must be >= 1");
    if (settings_.newton_max_iterations < 1)
      throw std::invalid_argument("newton: newton_max_iterations must be >= 1");
    if (settings_.newton_max_halvings < 0)
      throw std::invalid_argument("newton: newton_max_halvings must be >= 0");
    build_elements();
    build_free_index();
    build_pattern();
    linear_ = std::make_unique<LinearSolver>(settings_.linear_solver, a_, settings_.threads);
  }

  std::string describe() const override {
    return std::string("newton ") + linear_solver_name(settings_.linear_solver) +
           " tol=" + compact_number(settings_.newton_tolerance) +
           (settings_.newton_velocity_tolerance > 0.0
                ? " vtol=" + compact_number(settings_.newton_velocity_tolerance)
                : std::string()) +
           " substeps=" + std::to_string(settings_.substeps);
  }

  StepReport step(ClothState& state, double dt, const StepInputs& inputs) override {
    if (inputs.env == nullptr) throw std::invalid_argument("newton: StepInputs::env is required");
    if (!(dt > 0.0)) throw std::invalid_argument("newton: dt must be positive");
    StepReport report;
    const ClothState saved = state;
    const Eigen::Matrix3Xd kin_start = kinematic_positions(model_, state.x);
    Interval whole{dt, &inputs, &kin_start};
    const int n = settings_.substeps;
    for (int k = 0; k < n; ++k) {
      const double s0 = static_cast<double>(k) / n, s1 = static_cast<double>(k + 1) / n;
      if (!advance(state, whole, s0, s1, 0, report)) {
        state = saved;
        report.stable = false;
        return report;
      }
    }
    return report;
  }

 private:
  struct Interval {
    double dt;  // the whole step
    const StepInputs* inputs;
    const Eigen::Matrix3Xd* kin_start;  // kinematic positions at the start of the whole step
  };

  // ---- Setup ------------------------------------------------------------------------------------

  void build_elements() {
    const ClothMesh& mesh = model_.mesh;
    const Eigen::Matrix3Xd& rest = mesh.rest;
    // Rest area adjacent to each edge (for k_s) and to each hinge's edge (for k_b).
    std::map<std::pair<int, int>, double> adjacent_area;
    for (const auto& t : mesh.triangles) {
      const double area = triangle_area(rest, t);
      for (int k = 0; k < 3; ++k) {
        const int a = t[k], b = t[(k + 1) % 3];
        adjacent_area[{std::min(a, b), std::max(a, b)}] += area;
      }
    }
    const double membrane = model_.material.stretch_stiffness();
    const double rigidity = model_.material.bending_rigidity();
    edges_.reserve(mesh.edges.size());
    for (size_t e = 0; e < mesh.edges.size(); ++e) {
      const auto& ed = mesh.edges[e];
      const double l0 = model_.edge_rest_length[e];
      if (!(l0 > 0.0)) continue;  // coincident rest vertices: no direction to resist along
      const double area = adjacent_area[{ed[0], ed[1]}];
      edges_.push_back({{ed[0], ed[1]}, l0, stretch_coefficient(membrane, area, l0)});
    }
    hinges_.reserve(mesh.hinges.size());
    for (const auto& h : mesh.hinges) {
      const double le = (rest.col(h.v1) - rest.col(h.v0)).norm();
      const double area = adjacent_area[{std::min(h.v0, h.v1), std::max(h.v0, h.v1)}];
      const double theta0 = hinge_angle(rest.col(h.v0).data(), rest.col(h.v1).data(),
                                        rest.col(h.a).data(), rest.col(h.b).data());
      const double k_b = bend_coefficient(rigidity, le, area);
      if (k_b > 0.0) hinges_.push_back({{h.v0, h.v1, h.a, h.b}, theta0, k_b});
    }
  }

  void build_free_index() {
    const int n = model_.vertex_count();
    free_index_.assign(n, -1);
    kinematic_flag_.assign(n, 0);
    for (int k : model_.kinematic) kinematic_flag_[k] = 1;
    free_count_ = 0;
    for (int i = 0; i < n; ++i)
      if (!kinematic_flag_[i] && model_.inv_mass[i] > 0.0) free_index_[i] = free_count_++;
    force_scale_ = 0.0;
    for (int i = 0; i < n; ++i)
      if (free_index_[i] >= 0) force_scale_ = std::max(force_scale_, model_.mass[i]);
  }

  // Lower-triangular pattern of the free-DOF Hessian and the scatter slots of every element.
  void build_pattern() {
    const int ndof = 3 * free_count_;
    std::vector<std::vector<int>> rows(ndof);  // rows[col]: row indices >= col
    auto add_element = [&](const int* v, int nv) {
      for (int p = 0; p < nv; ++p)
        for (int q = 0; q < nv; ++q) {
          const int fp = free_index_[v[p]], fq = free_index_[v[q]];
          if (fp < 0 || fq < 0) continue;
          for (int c = 0; c < 3; ++c)
            for (int d = 0; d < 3; ++d) {
              const int r = 3 * fp + c, col = 3 * fq + d;
              if (r >= col) rows[col].push_back(r);
            }
        }
    };
    for (int i = 0; i < model_.vertex_count(); ++i) {
      const int f = free_index_[i];
      if (f >= 0)
        for (int c = 0; c < 3; ++c) rows[3 * f + c].push_back(3 * f + c);  // mass diagonal
    }
    for (const auto& e : edges_) add_element(e.v.data(), 2);
    for (const auto& h : hinges_) add_element(h.v.data(), 4);
    std::vector<Eigen::Triplet<double, int>> triplets;
    for (int col = 0; col < ndof; ++col) {
      auto& r = rows[col];
      std::sort(r.begin(), r.end());
      r.erase(std::unique(r.begin(), r.end()), r.end());
      for (int row : r) triplets.emplace_back(row, col, 0.0);
    }
    a_.resize(ndof, ndof);
    a_.setFromTriplets(triplets.begin(), triplets.end());
    a_.makeCompressed();

    auto slot_of = [&](int row, int col) {
      const int* outer = a_.outerIndexPtr();
      const int* inner = a_.innerIndexPtr();
      const int* begin = inner + outer[col];
      const int* end = inner + outer[col + 1];
      const int* it = std::lower_bound(begin, end, row);
      return static_cast<int>(it - inner);
    };
    auto build_scatter = [&](Scatter& s, const int* v, int nv) {
      s.offset.push_back(static_cast<int>(s.local.size()));
      for (int q = 0; q < nv; ++q)
        for (int p = 0; p < nv; ++p) {
          const int fp = free_index_[v[p]], fq = free_index_[v[q]];
          if (fp < 0 || fq < 0) continue;
          for (int d = 0; d < 3; ++d)
            for (int c = 0; c < 3; ++c) {
              const int r = 3 * fp + c, col = 3 * fq + d;
              if (r < col) continue;
              s.local.push_back((3 * q + d) * 3 * nv + 3 * p + c);
              s.slot.push_back(slot_of(r, col));
            }
        }
    };
    for (const auto& e : edges_) build_scatter(edge_scatter_, e.v.data(), 2);
    edge_scatter_.offset.push_back(static_cast<int>(edge_scatter_.local.size()));
    for (const auto& h : hinges_) build_scatter(hinge_scatter_, h.v.data(), 4);
    hinge_scatter_.offset.push_back(static_cast<int>(hinge_scatter_.local.size()));

    diagonal_slot_.resize(ndof);
    for (int k = 0; k < ndof; ++k) diagonal_slot_[k] = slot_of(k, k);

    auto couplings = [&](std::vector<KinematicCoupling>& out, const int* v, int nv, int element) {
      for (int p = 0; p < nv; ++p)
        for (int q = 0; q < nv; ++q)
          if (free_index_[v[p]] >= 0 && kinematic_flag_[v[q]]) out.push_back({element, p, q});
    };
    for (size_t e = 0; e < edges_.size(); ++e)
      couplings(edge_coupling_, edges_[e].v.data(), 2, static_cast<int>(e));
    for (size_t h = 0; h < hinges_.size(); ++h)
      couplings(hinge_coupling_, hinges_[h].v.data(), 4, static_cast<int>(h));

    edge_grad_.resize(6 * edges_.size());
    edge_hess_.resize(36 * edges_.size());
    edge_hess_proj_.resize(36 * edges_.size());
    hinge_grad_.resize(12 * hinges_.size());
    hinge_hess_.resize(144 * hinges_.size());
    hinge_hess_proj_.resize(144 * hinges_.size());
    edge_energy_.resize(edges_.size());
    hinge_energy_.resize(hinges_.size());
    // Zero, not left uninitialised: residual() and extra_potential() multiply K_n by x - x_n
    // before the first start_damping() of a solver (x = x_n, so the product is 0), and garbage
    // holding a NaN made that product NaN at random (found by `bench solvers`' chaos floor).
    stiffness_start_.setZero(a_.nonZeros());
  }

  // ---- Element evaluation -----------------------------------------------------------------------

  // Elastic energy at x; with `gradient` also the full-DOF elastic gradient in grad (3n); with
  // `hessian` also the projected element Hessians and, with `exact`, the exact ones (into the
  // per-element buffers). Elements are evaluated in parallel into per-element buffers and summed
  // serially in a fixed order, so the result does not depend on the thread count.
  double evaluate(const Eigen::Matrix3Xd& x, bool gradient, bool hessian, Eigen::VectorXd* grad,
                  bool exact = true) {
    const int ne = static_cast<int>(edges_.size()), nh = static_cast<int>(hinges_.size());
    const double* px = x.data();
    if (hessian) {
      // Where these element Hessians are from, so that the exact ones can be added later at the
      // same point (ensure_exact) when this evaluation skipped them.
      hessian_x_ = x;
      exact_elements_ = exact;
    }
    // With one thread no parallel region is opened: libgomp's fork-join (futex wake-ups) cost 5-10
    // % of a one-thread solve on seed 004's falling grid, where this runs about 20 times a frame.
#pragma omp parallel num_threads(std::max(1, settings_.threads)) if (settings_.threads > 1)
    {
#pragma omp for schedule(static)
      for (int e = 0; e < ne; ++e) {
        const EdgeElement& el = edges_[e];
        const double* a = px + 3 * el.v[0];
        const double* b = px + 3 * el.v[1];
        if (hessian)
          edge_energy_[e] =
              stretch_hessians(a, b, el.rest_length, el.k_s, &edge_grad_[6 * e],
                               exact ? &edge_hess_[36 * e] : nullptr, &edge_hess_proj_[36 * e]);
        else if (gradient)
          edge_energy_[e] = stretch_gradient(a, b, el.rest_length, el.k_s, &edge_grad_[6 * e]);
        else
          edge_energy_[e] = stretch_energy(a, b, el.rest_length, el.k_s);
      }
#pragma omp for schedule(static)
      for (int h = 0; h < nh; ++h) {
        const HingeElement& el = hinges_[h];
        const double* p0 = px + 3 * el.v[0];
        const double* p1 = px + 3 * el.v[1];
        const double* p2 = px + 3 * el.v[2];
        const double* p3 = px + 3 * el.v[3];
        if (hessian)
          hinge_energy_[h] =
              bend_hessians(p0, p1, p2, p3, el.theta0, el.k_b, &hinge_grad_[12 * h],
                            exact ? &hinge_hess_[144 * h] : nullptr, &hinge_hess_proj_[144 * h]);
        else if (gradient)
          hinge_energy_[h] = bend_gradient(p0, p1, p2, p3, el.theta0, el.k_b, &hinge_grad_[12 * h]);
        else
          hinge_energy_[h] = bend_energy(p0, p1, p2, p3, el.theta0, el.k_b);
      }
    }
    double energy = 0.0;
    for (int e = 0; e < ne; ++e) energy += edge_energy_[e];
    for (int h = 0; h < nh; ++h) energy += hinge_energy_[h];
    if (gradient || hessian) {
      grad->setZero(3 * x.cols());
      double* g = grad->data();
      for (int e = 0; e < ne; ++e)
        for (int p = 0; p < 2; ++p)
          for (int c = 0; c < 3; ++c) g[3 * edges_[e].v[p] + c] += edge_grad_[6 * e + 3 * p + c];
      for (int h = 0; h < nh; ++h)
        for (int p = 0; p < 4; ++p)
          for (int c = 0; c < 3; ++c) g[3 * hinges_[h].v[p] + c] += hinge_grad_[12 * h + 3 * p + c];
    }
    return energy;
  }

  // Sums element Hessians of the last evaluate(..., hessian = true) into a value array of the
  // free-DOF pattern (lower triangle): the projected (PSD) stiffness, or with `exact` the exact one
  // (which that evaluation must have computed).
  void assemble_stiffness(bool exact, Eigen::VectorXd& out) const {
    auto scatter = [](const Scatter& s, const std::vector<double>& hess, int stride, int count,
                      double* values) {
      for (int el = 0; el < count; ++el) {
        const double* h = hess.data() + static_cast<size_t>(stride) * el;
        for (int k = s.offset[el]; k < s.offset[el + 1]; ++k) values[s.slot[k]] += h[s.local[k]];
      }
    };
    const int ne = static_cast<int>(edges_.size()), nh = static_cast<int>(hinges_.size());
    out.setZero(a_.nonZeros());
    scatter(edge_scatter_, exact ? edge_hess_ : edge_hess_proj_, 36, ne, out.data());
    scatter(hinge_scatter_, exact ? hinge_hess_ : hinge_hess_proj_, 144, nh, out.data());
  }

  // The exact stiffness at the point of the last Hessian evaluation, into `exact`. Most iterations
  // factorise only the projected one (newton_projected_first), so the exact element Hessians (the
  // hinge's curvature term is the costliest part of an evaluation) and their assembly are made
  // only for the iterations that try them: the same values, computed when needed.
  void ensure_exact(Eigen::VectorXd& exact) {
    if (exact_assembled_) return;
    if (!exact_elements_) evaluate(hessian_x_, true, true, &scratch_grad_, true);
    assemble_stiffness(true, exact);
    exact_assembled_ = true;
  }

  // Element Hessian blocks (free row, kinematic column) times the kinematic displacement over the
  // step: the part of K_n (x - x_n) that the free-DOF matrix does not hold.
  void kinematic_damping_load(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_n,
                              Eigen::VectorXd& load) const {
    load.setZero(3 * free_count_);
    auto add = [&](const std::vector<KinematicCoupling>& list, const std::vector<double>& hess,
                   int nv, auto vertices) {
      const int n = 3 * nv;
      for (const auto& k : list) {
        const double* h = hess.data() + static_cast<size_t>(n) * n * k.element;
        const int vf = vertices(k.element)[k.free_local];
        const int vk = vertices(k.element)[k.kin_local];
        const Vec3 dx = x.col(vk) - x_n.col(vk);
        const int f = free_index_[vf];
        for (int c = 0; c < 3; ++c)
          for (int d = 0; d < 3; ++d)
            load[3 * f + c] += h[(3 * k.kin_local + d) * n + 3 * k.free_local + c] * dx[d];
      }
    };
    add(edge_coupling_, edge_hess_proj_, 2, [this](int e) { return edges_[e].v.data(); });
    add(hinge_coupling_, hinge_hess_proj_, 4, [this](int h) { return hinges_[h].v.data(); });
  }

  // ---- One Newton solve -------------------------------------------------------------------------

  struct SubstepContext {
    double h;
    Eigen::Matrix3Xd x_n, v_n;
    Vec3 gravity;
    double drag;
    double beta;
  };

  // Gathers free DOFs of a 3 x n matrix into a vector.
  void gather(const Eigen::Matrix3Xd& m, Eigen::VectorXd& out) const {
    out.resize(3 * free_count_);
    for (int i = 0; i < m.cols(); ++i)
      if (free_index_[i] >= 0) out.segment<3>(3 * free_index_[i]) = m.col(i);
  }

  // Non-elastic part of Phi at x (inertia, gravity, drag, damping), relative to x_n.
  double extra_potential(const SubstepContext& ctx, const Eigen::Matrix3Xd& x) {
    double phi = 0.0;
    const double h = ctx.h;
    for (int i = 0; i < x.cols(); ++i) {
      if (free_index_[i] < 0) continue;
      const Vec3 dx = x.col(i) - ctx.x_n.col(i);
      const Vec3 inertial = dx - h * ctx.v_n.col(i);
      phi += 0.5 * model_.mass[i] / (h * h) * inertial.squaredNorm();
      phi -= model_.mass[i] * ctx.gravity.dot(dx);
      phi += 0.5 * ctx.drag * model_.vertex_area[i] / h * dx.squaredNorm();
    }
    if (ctx.beta > 0.0) {
      gather(x - ctx.x_n, dx_free_);
      damping_product(dx_free_, tmp_);
      phi += ctx.beta / h * (0.5 * dx_free_.dot(tmp_) + dx_free_.dot(kinematic_load_));
    }
    return phi;
  }

  // out = K_n dx on the free DOFs (K_n stored as its lower triangle).
  void damping_product(const Eigen::VectorXd& dx, Eigen::VectorXd& out) const {
    const Eigen::Map<const SpMat> kn(a_.rows(), a_.cols(), a_.nonZeros(), a_.outerIndexPtr(),
                                     a_.innerIndexPtr(), stiffness_start_.data());
    out = kn.selfadjointView<Eigen::Lower>() * dx;
  }

  // Free-DOF residual r = dPhi/dx at x, given the full elastic gradient there.
  void residual(const SubstepContext& ctx, const Eigen::Matrix3Xd& x,
                const Eigen::VectorXd& elastic_grad, Eigen::VectorXd& r) {
    r.resize(3 * free_count_);
    const double h = ctx.h;
    for (int i = 0; i < x.cols(); ++i) {
      const int f = free_index_[i];
      if (f < 0) continue;
      const Vec3 dx = x.col(i) - ctx.x_n.col(i);
      r.segment<3>(3 * f) = model_.mass[i] / (h * h) * (dx - h * ctx.v_n.col(i)) +
                            elastic_grad.segment<3>(3 * i) - model_.mass[i] * ctx.gravity +
                            ctx.drag * model_.vertex_area[i] / h * dx;
    }
    if (ctx.beta > 0.0) {
      gather(x - ctx.x_n, dx_free_);
      damping_product(dx_free_, tmp_);
      r += ctx.beta / h * (tmp_ + kinematic_load_);
    }
  }

  // True if any kinematic vertex moves over the substep.
  bool kinematic_moved(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_n) const {
    for (int k : model_.kinematic)
      if (x.col(k) != x_n.col(k)) return true;
    return false;
  }

  // Assembles the Hessian at x = x_n and keeps its projected part as the damping matrix K_n
  // (projected so that damping can only dissipate), with its kinematic coupling load.
  void start_damping(const SubstepContext& ctx, const Eigen::Matrix3Xd& x,
                     Eigen::VectorXd& projected) {
    assemble_stiffness(false, projected);
    exact_assembled_ = false;
    stiffness_start_ = projected;
    if (ctx.beta > 0.0) kinematic_damping_load(x, ctx.x_n, kinematic_load_);
  }

  // A = K + beta/h K_n + M/h^2 + drag/h into the matrix values, from stiffness values K.
  void build_system(const SubstepContext& ctx, const Eigen::VectorXd& stiffness) {
    double* av = a_.valuePtr();
    const double damp = ctx.beta / ctx.h;
    for (Eigen::Index k = 0; k < a_.nonZeros(); ++k)
      av[k] = stiffness[k] + damp * stiffness_start_[k];
    for (int i = 0; i < model_.vertex_count(); ++i) {
      const int f = free_index_[i];
      if (f < 0) continue;
      const double diag =
          model_.mass[i] / (ctx.h * ctx.h) + ctx.drag * model_.vertex_area[i] / ctx.h;
      for (int c = 0; c < 3; ++c) a_.valuePtr()[diagonal_slot_[3 * f + c]] += diag;
    }
  }

  // Minimises Phi from x = x_n (kinematic vertices already at their end-of-substep positions),
  // or from `guess` (positions of the free vertices) when Phi is lower there. Returns false with
  // `why` on NaN, a system that is not positive definite even with projected element Hessians, a
  // failed line search, or no convergence within newton_max_iterations.
  bool newton(const SubstepContext& ctx, Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* guess,
              StepReport& report, std::string& why) {
    Eigen::VectorXd grad, r, d, b, trial_grad, exact, projected;
    Eigen::Matrix3Xd trial;

    // At x = x_n the damping force is K_n (x - x_n) / h = (kinematic coupling only), so when the
    // kinematic vertices do not move the residual needs no Hessian, and a cloth at rest costs one
    // gradient evaluation per step.
    const bool kinematic_moving = kinematic_moved(x, ctx.x_n);
    bool hessian_current = kinematic_moving && ctx.beta > 0.0;  // exact/projected are at x
    double elastic = evaluate(x, true, hessian_current, &grad, false);
    bool have_damping = hessian_current;  // K_n (stiffness_start_) is set
    kinematic_load_.setZero(3 * free_count_);
    if (have_damping) start_damping(ctx, x, projected);
    residual(ctx, x, grad, r);
    double phi = elastic + extra_potential(ctx, x);
    const double phi_start = phi;  // Phi at x_n (kinematic vertices moved): what must decrease
    double rnorm = r.lpNorm<Eigen::Infinity>();
    // Scale-free tolerance: newton_tolerance times the largest vertex weight. Forces computed from
    // absolute coordinates carry a rounding error of about eps * stiffness * |x| (an edge length
    // is a difference of coordinates), below which no residual can be measured; the tolerance
    // never asks for less than a few times that (the stiffness scale is known once a Hessian is).
    const double base_tolerance = settings_.newton_tolerance * force_scale_ *
                                  std::max(ctx.gravity.norm(), kMinAccelerationScale);
    double tolerance = base_tolerance;
    auto update_tolerance = [&]() {
      double max_stiffness = 0.0;
      for (int k : diagonal_slot_) max_stiffness = std::max(max_stiffness, std::abs(projected[k]));
      tolerance = std::max(base_tolerance, 16.0 * std::numeric_limits<double>::epsilon() *
                                               max_stiffness * x.cwiseAbs().maxCoeff());
    };
    if (hessian_current) update_tolerance();

    // The predicted start (SolverSettings::newton_guess), tried only when x_n is not already
    // converged. It needs K_n first (the residual away from x_n includes the damping force); the
    // Hessian evaluated for that at x_n then also serves as the first Newton matrix at the
    // prediction (a chord step) when chord iterations are on.
    const bool chords = settings_.newton_reuse_contraction > 0.0;
    bool stale_hessian = false;  // exact/projected are from x_n while x is the prediction
    if (guess != nullptr && std::isfinite(rnorm) && !(rnorm < tolerance)) {
      if (!have_damping) {
        evaluate(x, true, true, &grad, false);
        start_damping(ctx, x, projected);
        update_tolerance();
        have_damping = hessian_current = true;
      }
      trial = x;
      for (int i = 0; i < x.cols(); ++i)
        if (free_index_[i] >= 0) trial.col(i) = guess->col(i);
      const double trial_elastic = evaluate(trial, true, false, &trial_grad);
      const double trial_phi = trial_elastic + extra_potential(ctx, trial);
      if (std::isfinite(trial_phi) && trial_phi < phi) {
        x.swap(trial);
        grad.swap(trial_grad);
        phi = trial_phi;
        elastic = trial_elastic;
        residual(ctx, x, grad, r);
        rnorm = r.lpNorm<Eigen::Infinity>();
        stale_hessian = chords;
        hessian_current = false;
      }
    }

    int skip_exact = 0;               // iterations left that go straight to the projected Hessian
    double ratio = 1.0;               // last iteration's residual over the one before
    double previous_full_step = 0.0;  // the last iteration's max |dx| if it was a full step, else 0
    double eta = 0.1;                 // Eisenstat-Walker forcing term (PCG's relative tolerance)
    // A non-converged iterate is kept when it lowered Phi by more than rounding
    // (newton_accept_decrease); the caller then does not halve the step.
    auto keep_descent = [&]() {
      if (!settings_.newton_accept_decrease) return false;
      if (!(phi < phi_start - 1e-12 * (std::abs(phi_start) + std::abs(elastic)))) return false;
      ++report.unconverged;
      last_residual_ = rnorm;
      return true;
    };
    bool factor_valid = false;  // linear_ holds a factorisation a chord iteration may reuse
    bool contracted = false;    // the last iteration cut the residual by the contraction factor
    std::string solve_why;
    // Builds A from the stiffness values, factorises and solves A d = -r.
    auto factor_and_solve = [&](const Eigen::VectorXd& stiffness, const Eigen::VectorXd& cg_guess,
                                double rel_tol) {
      build_system(ctx, stiffness);
      ++report.factorizations;
      return linear_->factorize(a_, solve_why) &&
             linear_->solve(b, cg_guess, rel_tol, d, solve_why);
    };

    for (int it = 0;; ++it) {
      if (!std::isfinite(rnorm) || !std::isfinite(phi)) {
        why = "NaN in the Newton residual";
        return false;
      }
      if (rnorm < tolerance) {
        last_residual_ = rnorm;
        return true;
      }
      if (it >= settings_.newton_max_iterations) {
        if (keep_descent()) return true;
        char buf[160];
        std::snprintf(buf, sizeof buf,
                      "no convergence in %d Newton iterations (residual %.3g N > %.3g N)",
                      settings_.newton_max_iterations, rnorm, tolerance);
        why = buf;
        return false;
      }
      b = -r;
      // PCG: inexact Newton with the Eisenstat-Walker (1996) forcing term, choice 2 (gamma 0.9,
      // exponent 2) with its safeguard: a loose linear solve far from the solution, a tight one as
      // the residual contracts, never tighter than a tenth of the nonlinear tolerance needs.
      if (it > 0) {
        const double safeguard = 0.9 * eta * eta;
        eta = 0.9 * ratio * ratio;
        if (safeguard > 0.1) eta = std::max(eta, safeguard);
        eta = std::min(eta, 0.25);
      }
      const double rel_tol =
          std::clamp(std::max(eta, 0.1 * tolerance / std::max(b.norm(), 1e-300)), 1e-14, 0.25);
      const Eigen::VectorXd& cg_guess = it == 0 ? cg_guess_ : empty_;
      // A chord iteration: the last factorisation again, no Hessian evaluation.
      const bool chord = chords && factor_valid && contracted;
      bool solved = chord && linear_->solve(b, cg_guess, rel_tol, d, solve_why);
      const bool fresh = !solved && !stale_hessian;
      if (!solved) {
        // Whether this iteration tries the exact Hessian (the branches below).
        const bool try_exact = settings_.newton_exact_hessian &&
                               !(settings_.newton_projected_first && !(ratio <= 0.5)) &&
                               skip_exact == 0;
        if (!hessian_current && !stale_hessian) {
          evaluate(x, true, true, &grad, try_exact);
          if (!have_damping) {
            // Still at x_n (nothing moved before the first Hessian): this is K_n.
            start_damping(ctx, x, projected);
            have_damping = true;
          } else {
            assemble_stiffness(false, projected);
            exact_assembled_ = false;
          }
          update_tolerance();
          hessian_current = true;
          if (rnorm < tolerance) continue;  // converged once rounding is accounted for
        }
        // The exact Hessian first (quadratic convergence near a minimum, where it is positive
        // definite); if the system is indefinite (compressed edges, folded hinges far from
        // equilibrium), the projected element Hessians, which always give a descent direction.
        // An indefinite exact system costs a wasted factorisation, so after one the next two
        // iterations go straight to the projected Hessian.
        if (!settings_.newton_exact_hessian) {
          // projected only
        } else if (settings_.newton_projected_first && !(ratio <= 0.5)) {
          // projected until the residual contracts
        } else if (skip_exact > 0) {
          --skip_exact;
        } else {
          ensure_exact(exact);
          solved = factor_and_solve(exact, cg_guess, rel_tol);
          if (!solved) skip_exact = 2;
        }
        if (!solved && !factor_and_solve(projected, cg_guess, rel_tol)) {
          why = solve_why;
          return false;
        }
        factor_valid = true;
      }
      stale_hessian = false;
      ++report.iterations;
      if (it == 0 && (settings_.linear_solver == LinearSolverKind::ConjugateGradient ||
                      settings_.linear_solver == LinearSolverKind::ConjugateGradientIC))
        cg_guess_ = d;

      // Backtracking line search on Phi. Near convergence the decrease of Phi falls below its
      // rounding error, so a step that leaves Phi within rounding of its value is accepted too.
      const double slope = r.dot(d);  // < 0: d is a descent direction
      const double rounding = 1e-12 * (std::abs(phi) + std::abs(elastic));
      double alpha = 1.0;
      bool accepted = false;
      for (int ls = 0; ls <= kMaxBacktracks; ++ls, alpha *= 0.5) {
        trial = x;
        for (int i = 0; i < x.cols(); ++i)
          if (free_index_[i] >= 0) trial.col(i) += alpha * d.segment<3>(3 * free_index_[i]);
        const double trial_elastic = evaluate(trial, true, false, &trial_grad);
        const double trial_phi = trial_elastic + extra_potential(ctx, trial);
        if (std::isfinite(trial_phi) && trial_phi <= phi + kArmijo * alpha * slope + rounding) {
          x.swap(trial);
          grad.swap(trial_grad);
          phi = trial_phi;
          elastic = trial_elastic;
          accepted = true;
          hessian_current = false;
          break;
        }
      }
      if (!accepted) {
        if (!fresh) {  // a stale matrix's direction: retry with the Hessian at x
          contracted = false;
          continue;
        }
        if (keep_descent()) return true;
        char buf[160];
        std::snprintf(buf, sizeof buf, "line search failed (residual %.3g N)", rnorm);
        why = buf;
        return false;
      }
      const double previous = rnorm;
      residual(ctx, x, grad, r);
      rnorm = r.lpNorm<Eigen::Infinity>();
      ratio = previous > 0.0 ? rnorm / previous : 0.0;
      contracted = rnorm <= settings_.newton_reuse_contraction * previous;
      // Converged on the update: this iteration changed no free vertex's velocity (dx / h) by
      // more than newton_velocity_tolerance (1e-3 m/s is 0.03 mm of position per 1/30 s step);
      // the iterates converge at least linearly, so the ones left would move the cloth less.
      if (settings_.newton_velocity_tolerance > 0.0 && std::isfinite(rnorm)) {
        double max_step = 0.0;
        for (int f = 0; f < free_count_; ++f)
          max_step = std::max(max_step, alpha * d.segment<3>(3 * f).norm());
        const double bound = settings_.newton_velocity_tolerance * ctx.h;
        if (max_step < bound) {
          last_residual_ = rnorm;
          return true;
        }
        // ... or on the updates still to come, estimated from the contraction of two successive
        // full (alpha = 1) Newton steps, theta = |dx_k| / |dx_k-1| (Deuflhard 2004, "Newton
        // Methods for Nonlinear Problems", sec. 2.1: with contraction theta < 1 the distance to
        // the solution after step k is at most theta / (1 - theta) |dx_k|). This saves the
        // iteration whose only use would be to find its own update below the bound.
        if (alpha == 1.0 && previous_full_step > 0.0) {
          const double theta = max_step / previous_full_step;
          if (theta <= 0.25 && theta / (1.0 - theta) * max_step < bound) {
            last_residual_ = rnorm;
            return true;
          }
        }
        // Not from the first step: from x_n (or a prediction) it carries the inertial motion of
        // the whole step, which says nothing about the elastic part still to converge (measured:
        // counting it stopped steady frames of seed 004's falling grid 0.35 mm short per frame).
        previous_full_step = alpha == 1.0 && it > 0 ? max_step : 0.0;
      }
    }
  }

  // Advances state over the fraction [s0, s1] of the whole step; on failure splits it into two
  // halves (seed 004's remedy for degeneracies: a smaller step) up to newton_max_halvings deep.
  bool advance(ClothState& state, const Interval& iv, double s0, double s1, int depth,
               StepReport& report) {
    const ClothState before = state;
    std::string why;
    if (substep(state, iv, s0, s1, report, why)) {
      report.residual = std::max(report.residual, last_residual_);
      return true;
    }
    state = before;
    if (depth >= settings_.newton_max_halvings) {
      char buf[64];
      std::snprintf(buf, sizeof buf, " (after %d halvings, dt=%.3g s)", report.step_halvings,
                    (s1 - s0) * iv.dt);
      report.message = "newton: " + why + buf;
      return false;
    }
    ++report.step_halvings;
    report.message = "newton: halved the step: " + why;
    const double mid = 0.5 * (s0 + s1);
    return advance(state, iv, s0, mid, depth + 1, report) &&
           advance(state, iv, mid, s1, depth + 1, report);
  }

  bool substep(ClothState& state, const Interval& iv, double s0, double s1, StepReport& report,
               std::string& why) {
    SubstepContext ctx;
    ctx.h = (s1 - s0) * iv.dt;
    ctx.x_n = state.x;
    ctx.v_n = state.v;
    ctx.gravity = iv.inputs->env->gravity;
    ctx.drag = iv.inputs->env->air_drag;
    ctx.beta = model_.material.damping;
    // Newton's predicted start (SolverSettings::newton_guess): the inertial position, plus the
    // last sub-step's acceleration when this call continues from the state that sub-step produced
    // (bitwise, so the prediction depends only on this solver's own call sequence).
    const Eigen::Matrix3Xd* guess = nullptr;
    if (settings_.newton_guess != SolverSettings::Guess::Start) {
      predicted_ = state.x + ctx.h * state.v;
      if (settings_.newton_guess == SolverSettings::Guess::Extrapolate && have_previous_ &&
          state.x == previous_x_ && state.v == previous_v_)
        predicted_ += ctx.h * ctx.h * previous_a_;
      guess = &predicted_;
    }
    // Kinematic vertices are not unknowns: they sit at their end-of-substep positions.
    place_kinematic(model_, *iv.kin_start, *iv.inputs, s1, iv.dt, state);
    last_residual_ = 0.0;
    if (free_count_ > 0 && !newton(ctx, state.x, guess, report, why)) return false;
    // Collisions: a position projection after the implicit solve (contacts are not part of Phi),
    // then backward Euler's velocity v = (x - x_n) / h, which also accounts for the correction.
    resolve_collisions(state.x, ctx.x_n, model_.inv_mass, *iv.inputs->env, s1, s0);
    for (int i = 0; i < model_.vertex_count(); ++i)
      if (free_index_[i] >= 0) state.v.col(i) = (state.x.col(i) - ctx.x_n.col(i)) / ctx.h;
    if (!state_is_sane(state)) {
      why = "state became non-finite or too fast";
      return false;
    }
    previous_a_ = (state.v - ctx.v_n) / ctx.h;
    previous_x_ = state.x;
    previous_v_ = state.v;
    have_previous_ = true;
    return true;
  }

  const ClothModel model_;  // a copy: the solver must not depend on the caller's lifetime
  SolverSettings settings_;
  std::vector<EdgeElement> edges_;
  std::vector<HingeElement> hinges_;
  std::vector<int> free_index_;
  std::vector<char> kinematic_flag_;
  int free_count_ = 0;
  double force_scale_ = 0.0;  // max free vertex mass, kg
  SpMat a_;
  Scatter edge_scatter_, hinge_scatter_;
  std::vector<int> diagonal_slot_;
  std::vector<KinematicCoupling> edge_coupling_, hinge_coupling_;
  std::vector<double> edge_grad_, edge_hess_, hinge_grad_, hinge_hess_;
  std::vector<double> edge_hess_proj_, hinge_hess_proj_;  // projected (PSD) element Hessians
  std::vector<double> edge_energy_, hinge_energy_;
  // The point of the last Hessian evaluation, whether it computed the exact element Hessians, and
  // whether the exact stiffness assembled from them is current (ensure_exact).
  Eigen::Matrix3Xd hessian_x_;
  bool exact_elements_ = false, exact_assembled_ = false;
  Eigen::VectorXd scratch_grad_;
  Eigen::VectorXd stiffness_start_;  // K_n values (lower triangle) for Rayleigh damping
  Eigen::VectorXd kinematic_load_;   // K_n(free, kinematic) (x - x_n)(kinematic)
  Eigen::VectorXd dx_free_, tmp_, cg_guess_, empty_;
  double last_residual_ = 0.0;
  // The last sub-step's result and acceleration, for the extrapolated Newton start.
  Eigen::Matrix3Xd previous_x_, previous_v_, previous_a_, predicted_;
  bool have_previous_ = false;
  std::unique_ptr<LinearSolver> linear_;
};

}  // namespace

std::unique_ptr<Solver> make_newton_solver(const ClothModel& model, const SolverSettings& s) {
  return std::make_unique<NewtonSolver>(model, s);
}

}  // namespace clothdb
