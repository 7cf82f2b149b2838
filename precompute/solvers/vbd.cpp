// EXPERIMENT for issue 28 (docs/notebook/resolution.md, "Eighth round"): Vertex Block Descent
// (Chen, Liu, Yang & Yuksel 2024) on the XPBD solver's cloth model: the same edge springs
// U = 1/2 k (l - l0)^2, k = k_s / l0 (XPBD's compliance 1/k), and the same dihedral-angle hinges
// U = 1/2 k_b (theta - theta0)^2 (shell_energy.hpp's coefficients). Each sub-step minimises the
// variational implicit-Euler objective (Chen et al. 2024 eq. 1)
//   G(x) = 1/(2 h^2) |x - y|_M^2 + E(x)
// by Gauss-Seidel over vertices (their Algorithm 1): a vertex's local objective is its inertia
// term plus the energies of the elements it belongs to, and one Newton step on it,
//   dx_i = H_i^-1 f_i,  f_i = -m_i/h^2 (x_i - y_i) - sum_j dE_j/dx_i,
//   H_i = m_i/h^2 I + sum_j d^2E_j/dx_i^2,
// moves that vertex alone. Vertices of one colour share no element, so a colour is updated in
// parallel with the same result as any order: 1 and 2 threads agree bit for bit.
#include "solvers/vbd.hpp"

#include <omp.h>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#ifdef CLOTHDB_HAVE_CHOLMOD
#include <Eigen/CholmodSupport>
#endif

#include "solvers/coloring.hpp"
#include "solvers/shell_energy.hpp"

namespace clothdb {

namespace {

using M3 = Eigen::Matrix3d;

// Signed dihedral angle of hinge (v0, v1, a, b) and its gradient (Bridson, Marino & Fedkiw 2003
// sec. 4.1), the XPBD solver's convention, so theta0 and the energy are XPBD's.
bool dihedral(const Vec3& p0, const Vec3& p1, const Vec3& pa, const Vec3& pb, double& theta,
              std::array<Vec3, 4>& g) {
  const Vec3 e = p1 - p0;
  const double e_sq = e.squaredNorm();
  const Vec3 n1 = (pa - p0).cross(pa - p1);
  const Vec3 n2 = (pb - p1).cross(pb - p0);
  const double n1_sq = n1.squaredNorm(), n2_sq = n2.squaredNorm();
  const double tiny = 1e-24 * e_sq * e_sq;
  if (!(e_sq > 0.0) || n1_sq <= tiny || n2_sq <= tiny) return false;
  const double e_len = std::sqrt(e_sq), inv_e = 1.0 / e_len;
  theta = std::atan2(n2.cross(n1).dot(e) * inv_e, n1.dot(n2));
  const Vec3 m1 = n1 * (1.0 / n1_sq), m2 = n2 * (1.0 / n2_sq);
  const double a0 = (pa - p0).dot(e) * inv_e, b0 = (pb - p0).dot(e) * inv_e;
  g[2] = e_len * m1;
  g[3] = e_len * m2;
  g[0] = (a0 - e_len) * m1 + (b0 - e_len) * m2;
  g[1] = -a0 * m1 - b0 * m2;
  return true;
}

double wrap(double d) {
  if (d > std::numbers::pi) return d - 2.0 * std::numbers::pi;
  if (d <= -std::numbers::pi) return d + 2.0 * std::numbers::pi;
  return d;
}

// The elements of E, built as XpbdSolver::build_constraints builds its constraints.
struct Elements {
  std::vector<std::array<int, 2>> edge;
  std::vector<double> rest, k;  // l0 (m), k = k_s / l0 (N/m)
  std::vector<std::array<int, 4>> hinge;
  std::vector<double> theta0, kb;    // rad, N m per rad^2
  std::vector<double> theta0_shell;  // the rest angle in shell_energy.hpp's sign convention
};

Elements build_elements(const ClothModel& model) {
  Elements el;
  const ClothMesh& mesh = model.mesh;
  const double et = model.material.stretch_stiffness();
  for (std::size_t e = 0; e < mesh.edges.size(); ++e) {
    const double l0 = model.edge_rest_length[e];
    if (l0 <= 0.0) continue;
    const double k_s = stretch_coefficient(et, model.edge_area[e], l0);
    el.edge.push_back(mesh.edges[e]);
    el.rest.push_back(l0);
    el.k.push_back(k_s > 0.0 ? k_s / l0 : 1e-12);  // XPBD's compliance 1e12 for such an edge
  }
  const double d = model.material.bending_rigidity();
  if (d > 0.0) {
    for (const Hinge& h : mesh.hinges) {
      std::array<Vec3, 4> g;
      double theta0 = 0.0;
      if (!dihedral(mesh.rest.col(h.v0), mesh.rest.col(h.v1), mesh.rest.col(h.a),
                    mesh.rest.col(h.b), theta0, g))
        continue;
      const double areas =
          triangle_area(mesh.rest, {h.v0, h.v1, h.a}) + triangle_area(mesh.rest, {h.v1, h.v0, h.b});
      const double kb =
          bend_coefficient(d, (mesh.rest.col(h.v1) - mesh.rest.col(h.v0)).norm(), areas);
      if (!(kb > 0.0)) continue;
      el.hinge.push_back({h.v0, h.v1, h.a, h.b});
      el.theta0.push_back(theta0);
      el.theta0_shell.push_back(hinge_angle(mesh.rest.col(h.v0).data(), mesh.rest.col(h.v1).data(),
                                            mesh.rest.col(h.a).data(), mesh.rest.col(h.b).data()));
      el.kb.push_back(kb);
    }
  }
  return el;
}

// Gradient of G over all vertices (kinematic columns zeroed) and, optionally, G itself.
Eigen::Matrix3Xd objective_gradient(const ClothModel& model, const Elements& el,
                                    const Eigen::Matrix3Xd& y, double h, const Eigen::Matrix3Xd& x,
                                    double* value) {
  const Eigen::Index n = x.cols();
  Eigen::Matrix3Xd grad(3, n);
  double g_value = 0.0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vec3 d = x.col(i) - y.col(i);
    grad.col(i) = model.mass[i] / (h * h) * d;
    if (model.inv_mass[i] > 0.0) g_value += 0.5 * model.mass[i] / (h * h) * d.squaredNorm();
  }
  for (std::size_t e = 0; e < el.edge.size(); ++e) {
    const int i = el.edge[e][0], j = el.edge[e][1];
    const Vec3 d = x.col(i) - x.col(j);
    const double l = d.norm();
    g_value += 0.5 * el.k[e] * (l - el.rest[e]) * (l - el.rest[e]);
    if (!(l > 1e-12 * el.rest[e])) continue;
    const Vec3 f = el.k[e] * (l - el.rest[e]) / l * d;
    grad.col(i) += f;
    grad.col(j) -= f;
  }
  for (std::size_t c = 0; c < el.hinge.size(); ++c) {
    const auto& v = el.hinge[c];
    std::array<Vec3, 4> g;
    double theta = 0.0;
    if (!dihedral(x.col(v[0]), x.col(v[1]), x.col(v[2]), x.col(v[3]), theta, g)) continue;
    const double dth = wrap(theta - el.theta0[c]);
    g_value += 0.5 * el.kb[c] * dth * dth;
    for (int k = 0; k < 4; ++k) grad.col(v[static_cast<std::size_t>(k)]) += el.kb[c] * dth * g[k];
  }
  for (int i : model.kinematic) grad.col(i).setZero();
  if (value) *value = g_value;
  return grad;
}

class VbdSolver final : public Solver {
 public:
  VbdSolver(const ClothModel& model, const VbdSettings& settings)
      : model_(model), settings_(settings), el_(build_elements(model_)) {
    if (settings.substeps < 1 || settings.iterations < 1 || settings.threads < 1)
      throw std::invalid_argument("vbd: substeps, iterations and threads must be at least 1");
    if (!(settings.chebyshev_rho >= 0.0 && settings.chebyshev_rho < 1.0))
      throw std::invalid_argument("vbd: chebyshev_rho must be in [0, 1)");
    const std::size_t n = static_cast<std::size_t>(model_.vertex_count());
    // Per-vertex element lists (CSR): edges with the other end, hinges with the vertex's slot.
    edge_begin_.assign(n + 1, 0);
    hinge_begin_.assign(n + 1, 0);
    for (const auto& e : el_.edge)
      for (int v : e) ++edge_begin_[static_cast<std::size_t>(v) + 1];
    for (const auto& hh : el_.hinge)
      for (int v : hh) ++hinge_begin_[static_cast<std::size_t>(v) + 1];
    for (std::size_t i = 0; i < n; ++i) {
      edge_begin_[i + 1] += edge_begin_[i];
      hinge_begin_[i + 1] += hinge_begin_[i];
    }
    vertex_edges_.resize(static_cast<std::size_t>(edge_begin_[n]));
    vertex_hinges_.resize(static_cast<std::size_t>(hinge_begin_[n]));
    std::vector<int> fe(edge_begin_.begin(), edge_begin_.end() - 1);
    std::vector<int> fh(hinge_begin_.begin(), hinge_begin_.end() - 1);
    for (std::size_t e = 0; e < el_.edge.size(); ++e) {
      const int a = el_.edge[e][0], b = el_.edge[e][1];
      vertex_edges_[static_cast<std::size_t>(fe[static_cast<std::size_t>(a)]++)] = {
          static_cast<int>(e), b};
      vertex_edges_[static_cast<std::size_t>(fe[static_cast<std::size_t>(b)]++)] = {
          static_cast<int>(e), a};
    }
    for (std::size_t c = 0; c < el_.hinge.size(); ++c)
      for (int s = 0; s < 4; ++s) {
        const int v = el_.hinge[c][static_cast<std::size_t>(s)];
        vertex_hinges_[static_cast<std::size_t>(fh[static_cast<std::size_t>(v)]++)] = {
            static_cast<int>(c), s};
      }
    // Vertex colouring (Chen et al. 2024 sec. 3.3 "Parallelization"): two vertices conflict when
    // they share an element. greedy_coloring colours tuples that share an index, so each free
    // vertex is the tuple of the ids of its elements (edges, then hinges offset by the edge
    // count), padded with -1. Greedy in vertex order: deterministic.
    std::vector<int> free;
    std::size_t arity = 1;
    for (std::size_t i = 0; i < n; ++i) {
      if (model_.inv_mass[static_cast<Eigen::Index>(i)] <= 0.0) continue;
      free.push_back(static_cast<int>(i));
      arity = std::max(arity, static_cast<std::size_t>(edge_begin_[i + 1] - edge_begin_[i] +
                                                       hinge_begin_[i + 1] - hinge_begin_[i]));
    }
    std::vector<int> tuples(free.size() * arity, -1);
    const int edge_count = static_cast<int>(el_.edge.size());
    for (std::size_t f = 0; f < free.size(); ++f) {
      const std::size_t i = static_cast<std::size_t>(free[f]);
      std::size_t slot = f * arity;
      for (int k = edge_begin_[i]; k < edge_begin_[i + 1]; ++k)
        tuples[slot++] = vertex_edges_[static_cast<std::size_t>(k)][0];
      for (int k = hinge_begin_[i]; k < hinge_begin_[i + 1]; ++k)
        tuples[slot++] = edge_count + vertex_hinges_[static_cast<std::size_t>(k)][0];
    }
    if (!free.empty()) {
      for (const auto& group : greedy_coloring(tuples, static_cast<int>(arity))) {
        colors_.emplace_back();
        for (int f : group) colors_.back().push_back(free[static_cast<std::size_t>(f)]);
      }
    }
  }

  std::string describe() const override {
    return "vbd substeps=" + std::to_string(settings_.substeps) +
           " iterations=" + std::to_string(settings_.iterations) +
           " chebyshev_rho=" + std::to_string(settings_.chebyshev_rho);
  }

  StepReport step(ClothState& state, double dt, const StepInputs& inputs) override;

 private:
  void vertex_update(int i, Eigen::Matrix3Xd& x, double inv_h2, double damp) const;

  const ClothModel model_;
  VbdSettings settings_;
  Elements el_;
  std::vector<int> edge_begin_, hinge_begin_;
  std::vector<std::array<int, 2>> vertex_edges_, vertex_hinges_;
  std::vector<std::vector<int>> colors_;
  Eigen::Matrix3Xd y_, xt_, cheb_prev_, cheb_cur_;
  // Velocities at the start of the previous sub-step, for the adaptive initialisation's
  // acceleration a_t = (v_t - v_t-1) / h; empty until the first sub-step.
  Eigen::Matrix3Xd v_last_;
};

// One vertex's block Newton step (Algorithm 1, lines 8-11): the force and the 3 x 3 Hessian of
// its local objective G_i summed over its elements, then x_i += H_i^-1 f_i. Edge springs with
// their exact block, the transverse (string tension) term clamped at zero for a compressed edge
// so H_i stays positive definite (the PSD projection the paper asks of a non-convex element);
// hinges with their Gauss-Newton block k_b grad theta grad theta^T. Rayleigh damping (the paper's
// damping term, f_i -= (k_d / h) H_i (x_i - x_i^t), H_i += (k_d / h) H_i with k_d the material's
// damping) on the hinges only, as the XPBD solver damps only bending.
void VbdSolver::vertex_update(int i, Eigen::Matrix3Xd& x, double inv_h2, double damp) const {
  const std::size_t iu = static_cast<std::size_t>(i);
  const Vec3 xi = x.col(i);
  const double m = model_.mass[i] * inv_h2;
  Vec3 f = -m * (xi - y_.col(i));
  M3 H = m * M3::Identity();
  for (int k = edge_begin_[iu]; k < edge_begin_[iu + 1]; ++k) {
    const auto& [e, j] = vertex_edges_[static_cast<std::size_t>(k)];
    const std::size_t eu = static_cast<std::size_t>(e);
    const Vec3 d = xi - x.col(j);
    const double l = d.norm(), l0 = el_.rest[eu], ke = el_.k[eu];
    if (!(l > 1e-12 * l0)) {
      H += ke * M3::Identity();  // collapsed edge: no direction; isotropic axial stiffness
      continue;
    }
    const Vec3 u = d / l;
    const M3 uu = u * u.transpose();
    f -= ke * (l - l0) * u;
    H += ke * uu + ke * std::max(0.0, 1.0 - l0 / l) * (M3::Identity() - uu);
  }
  for (int k = hinge_begin_[iu]; k < hinge_begin_[iu + 1]; ++k) {
    const auto& [c, s] = vertex_hinges_[static_cast<std::size_t>(k)];
    const std::size_t cu = static_cast<std::size_t>(c);
    const auto& v = el_.hinge[cu];
    std::array<Vec3, 4> g;
    double theta = 0.0;
    if (!dihedral(x.col(v[0]), x.col(v[1]), x.col(v[2]), x.col(v[3]), theta, g)) continue;
    const Vec3& gi = g[static_cast<std::size_t>(s)];
    const double kb = el_.kb[cu];
    const M3 hb = kb * gi * gi.transpose();
    f -= kb * wrap(theta - el_.theta0[cu]) * gi;
    H += hb;
    if (damp > 0.0) {
      f -= damp * (hb * (xi - xt_.col(i)));
      H += damp * hb;
    }
  }
  // H_i >= m_i/h^2 I > 0: the inertia term keeps every block solvable.
  x.col(i) = xi + H.llt().solve(f);
}

StepReport VbdSolver::step(ClothState& state, double dt, const StepInputs& inputs) {
  if (inputs.env == nullptr) throw std::invalid_argument("vbd: StepInputs::env is required");
  if (!(dt > 0.0)) throw std::invalid_argument("vbd: dt must be positive");
  const Eigen::Index n = model_.vertex_count();
  if (state.x.cols() != n || state.v.cols() != n)
    throw std::invalid_argument("vbd: state does not match the model");
  const Environment& env = *inputs.env;
  const ClothState saved = state;
  const Eigen::Matrix3Xd kin_start = kinematic_positions(model_, state.x);
  const int substeps = settings_.substeps;
  const double h = dt / substeps, inv_h2 = 1.0 / (h * h);
  const double damp = model_.material.damping / h;
  const double rho = settings_.chebyshev_rho;
  const Vec3 g = env.gravity;
  const double g_norm = g.norm();
  const double* w = model_.inv_mass.data();
  y_.resize(3, n);
  xt_.resize(3, n);
  if (rho > 0.0) {
    cheb_prev_.resize(3, n);
    cheb_cur_.resize(3, n);
  }
  Eigen::VectorXd drag_factor(n);
  for (Eigen::Index i = 0; i < n; ++i)
    drag_factor[i] = 1.0 / (1.0 + h * env.air_drag * model_.vertex_area[i] * model_.inv_mass[i]);

  auto substep_loop = [&]() {
    for (int sub = 0; sub < substeps; ++sub) {
      const double s_start = static_cast<double>(sub) / substeps;
      const double s_end = static_cast<double>(sub + 1) / substeps;
#pragma omp single
      {
        xt_ = state.x;
        place_kinematic(model_, kin_start, inputs, s_end, dt, state);
        if (v_last_.cols() != n) v_last_ = state.v;
      }
      // y = x_t + h v_t + h^2 a_ext (eq. 2), with XPBD's implicit air drag on h v_t + h^2 g.
      // Initial guess (sec. 3.5 "Initialization", adaptive): x = x_t + h v_t + h^2 a~, a~ the
      // previous sub-step's acceleration a_t = (v_t - v_t-1) / h projected on the direction of
      // a_ext = g and clamped to [0, |g|]: a cloth held up by its pins starts where it was pushed,
      // a falling one where gravity takes it.
#pragma omp for schedule(static)
      for (Eigen::Index i = 0; i < n; ++i) {
        if (w[i] <= 0.0) {
          y_.col(i) = state.x.col(i);
          continue;
        }
        const Vec3 vt = state.v.col(i);
        y_.col(i) = xt_.col(i) + h * ((vt + h * g) * drag_factor[i]);
        switch (settings_.init) {
          case VbdSettings::Init::Inertia:
            state.x.col(i) = y_.col(i);
            break;
          case VbdSettings::Init::Previous:
            break;
          case VbdSettings::Init::Adaptive: {
            Vec3 a_tilde = Vec3::Zero();
            if (g_norm > 0.0) {
              const Vec3 g_hat = g / g_norm;
              const double a_ext = ((vt - v_last_.col(i)) / h).dot(g_hat);
              a_tilde = a_ext > g_norm ? g : a_ext < 0.0 ? Vec3::Zero() : Vec3(a_ext * g_hat);
            }
            state.x.col(i) = xt_.col(i) + h * vt + h * h * a_tilde;
            break;
          }
        }
        v_last_.col(i) = vt;
        if (rho > 0.0) cheb_cur_.col(i) = state.x.col(i);
      }
      double omega = 1.0;
      for (int it = 0; it < settings_.iterations; ++it) {
        for (const std::vector<int>& color : colors_) {
          const int count = static_cast<int>(color.size());
#pragma omp for schedule(static)
          for (int k = 0; k < count; ++k)
            vertex_update(color[static_cast<std::size_t>(k)], state.x, inv_h2, damp);
        }
        if (rho > 0.0) {
          // Sec. 3.7: x^(n) = omega_n (x^_(n) - x^(n-2)) + x^(n-2), omega_1 = 1,
          // omega_2 = 2 / (2 - rho^2), omega_n = 4 / (4 - rho^2 omega_n-1) (Wang 2015 eq. 12).
          omega = it == 0   ? 1.0
                  : it == 1 ? 2.0 / (2.0 - rho * rho)
                            : 4.0 / (4.0 - rho * rho * omega);
#pragma omp for schedule(static)
          for (Eigen::Index i = 0; i < n; ++i) {
            if (w[i] <= 0.0) continue;
            if (it > 0)
              state.x.col(i) = omega * (state.x.col(i) - cheb_prev_.col(i)) + cheb_prev_.col(i);
            cheb_prev_.col(i) = cheb_cur_.col(i);
            cheb_cur_.col(i) = state.x.col(i);
          }
        }
      }
#pragma omp for schedule(static)
      for (Eigen::Index i = 0; i < n; ++i)
        resolve_vertex_collisions(state.x, xt_, model_.inv_mass, i, env, s_end, s_start);
        // v_t+1 = (x - x_t) / h (Algorithm 1, last line).
#pragma omp for schedule(static)
      for (Eigen::Index i = 0; i < n; ++i)
        if (w[i] > 0.0) state.v.col(i) = (state.x.col(i) - xt_.col(i)) / h;
    }
  };
  if (settings_.threads > 1 || omp_in_parallel()) {
#pragma omp parallel num_threads(settings_.threads)
    substep_loop();
  } else {
    substep_loop();
  }
  StepReport report;
  report.iterations = substeps * settings_.iterations;
  if (!state_is_sane(state)) {
    state = saved;
    report.stable = false;
    report.message = "vbd: the step produced non-finite or runaway velocities with " + describe();
  }
  return report;
}

}  // namespace

std::unique_ptr<Solver> make_vbd_solver(const ClothModel& model, const VbdSettings& settings) {
  return std::make_unique<VbdSolver>(model, settings);
}

Eigen::Matrix3Xd implicit_euler_target(const ClothModel& model, const Environment& env,
                                       const ClothState& start, double h,
                                       const Eigen::Matrix3Xd& x_end) {
  Eigen::Matrix3Xd y = x_end;
  for (Eigen::Index i = 0; i < y.cols(); ++i) {
    if (model.inv_mass[i] <= 0.0) continue;
    const double drag = 1.0 / (1.0 + h * env.air_drag * model.vertex_area[i] * model.inv_mass[i]);
    y.col(i) = start.x.col(i) + h * ((start.v.col(i) + h * env.gravity) * drag);
  }
  return y;
}

double implicit_euler_residual(const ClothModel& model, const Eigen::Matrix3Xd& y, double h,
                               const Eigen::Matrix3Xd& x) {
  return objective_gradient(model, build_elements(model), y, h, x, nullptr).norm();
}

Eigen::Matrix3Xd implicit_euler_solve(const ClothModel& model, const Eigen::Matrix3Xd& y, double h,
                                      const Eigen::Matrix3Xd& x0, double rel_tol,
                                      double* residual) {
  const Elements el = build_elements(model);
  const Eigen::Index n = x0.cols();
  std::vector<int> dof(static_cast<std::size_t>(n), -1);
  int dofs = 0;
  for (Eigen::Index i = 0; i < n; ++i)
    if (model.inv_mass[i] > 0.0) dof[static_cast<std::size_t>(i)] = 3 * dofs++;
  const int size = 3 * dofs;
  Eigen::Matrix3Xd x = x0;
  double value = 0.0;
  const double r0 = objective_gradient(model, el, y, h, y, nullptr).norm();
  Eigen::Matrix3Xd grad = objective_gradient(model, el, y, h, x, &value);
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
#ifdef CLOTHDB_HAVE_CHOLMOD
  // Supernodal CHOLMOD for the 84-a-side sheet's 21,000 unknowns (SimplicialLDLT took seconds a
  // factorisation); serial, as the Newton solver runs it (its fixed num_threads(4) regions made
  // inactive). LDLT when the exact Hessian is not positive definite.
  Eigen::CholmodDecomposition<Eigen::SparseMatrix<double>> cholmod;
  cholmod.setMode(Eigen::CholmodSupernodalLLt);
  cholmod.cholmod().print = 0;
  const int saved_levels = omp_get_max_active_levels();
  omp_set_max_active_levels(0);
#endif
  for (int iter = 0; iter < 40 && grad.norm() > rel_tol * r0; ++iter) {
    // Near the solution (a strict minimum, where the exact Hessian is positive definite) the exact
    // Hessians, for Newton's quadratic convergence: the projected ones leave a linear tail (at 84
    // nodes a side, 0.93 per iteration from 1e-9 of the start's residual).
    const bool exact = grad.norm() < 1e-6 * r0;
    std::vector<Eigen::Triplet<double>> t;
    t.reserve(9 * (static_cast<std::size_t>(n) + 4 * el.edge.size() + 16 * el.hinge.size()));
    auto add = [&](int a, int b, const M3& k) {
      const int da = dof[static_cast<std::size_t>(a)], db = dof[static_cast<std::size_t>(b)];
      if (da < 0 || db < 0) return;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) t.emplace_back(da + r, db + c, k(r, c));
    };
    for (Eigen::Index i = 0; i < n; ++i)
      add(static_cast<int>(i), static_cast<int>(i), model.mass[i] / (h * h) * M3::Identity());
    for (std::size_t e = 0; e < el.edge.size(); ++e) {
      const int i = el.edge[e][0], j = el.edge[e][1];
      const Vec3 d = x.col(i) - x.col(j);
      const double l = d.norm();
      M3 k = el.k[e] * M3::Identity();
      if (l > 1e-12 * el.rest[e]) {
        const Vec3 u = d / l;
        const double tension = 1.0 - el.rest[e] / l;
        k = el.k[e] * (u * u.transpose()) + el.k[e] * (exact ? tension : std::max(0.0, tension)) *
                                                (M3::Identity() - u * u.transpose());
      }
      add(i, i, k);
      add(j, j, k);
      add(i, j, -k);
      add(j, i, -k);
    }
    for (std::size_t c = 0; c < el.hinge.size(); ++c) {
      const auto& v = el.hinge[c];
      if (exact) {
        double gb[12], hb[144];
        bend_hessian(x.col(v[0]).data(), x.col(v[1]).data(), x.col(v[2]).data(), x.col(v[3]).data(),
                     el.theta0_shell[c], el.kb[c], gb, hb, false);
        const Eigen::Map<const Eigen::Matrix<double, 12, 12>> hm(hb);
        for (int a = 0; a < 4; ++a)
          for (int b = 0; b < 4; ++b)
            add(v[static_cast<std::size_t>(a)], v[static_cast<std::size_t>(b)],
                hm.block<3, 3>(3 * a, 3 * b));
        continue;
      }
      std::array<Vec3, 4> g;
      double theta = 0.0;
      if (!dihedral(x.col(v[0]), x.col(v[1]), x.col(v[2]), x.col(v[3]), theta, g)) continue;
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
          add(v[static_cast<std::size_t>(a)], v[static_cast<std::size_t>(b)],
              el.kb[c] * g[static_cast<std::size_t>(a)] *
                  g[static_cast<std::size_t>(b)].transpose());
    }
    Eigen::SparseMatrix<double> H(size, size);
    H.setFromTriplets(t.begin(), t.end());
    Eigen::VectorXd rhs(size);
    for (Eigen::Index i = 0; i < n; ++i)
      if (dof[static_cast<std::size_t>(i)] >= 0)
        rhs.segment<3>(dof[static_cast<std::size_t>(i)]) = -grad.col(i);
    Eigen::VectorXd d;
#ifdef CLOTHDB_HAVE_CHOLMOD
    if (iter == 0) cholmod.analyzePattern(H);
    cholmod.factorize(H);
    if (cholmod.info() == Eigen::Success) d = cholmod.solve(rhs);
#endif
    if (d.size() != size) {
      ldlt.compute(H);
      if (ldlt.info() != Eigen::Success) break;
      d = ldlt.solve(rhs);
    }
    const double slope = -rhs.dot(d);
    if (!(slope < 0.0)) break;
    if (std::getenv("CLOTHDB_PROBE_VBD_NEWTON"))
      std::fprintf(stderr, " it %d r %.3e\n", iter, grad.norm());
    // Backtracking on G; near the solution G's change is below its rounding, so a step that
    // lowers the gradient's norm is taken as well.
    double alpha = 1.0;
    for (int ls = 0; ls < 30; ++ls, alpha *= 0.5) {
      Eigen::Matrix3Xd trial = x;
      for (Eigen::Index i = 0; i < n; ++i)
        if (dof[static_cast<std::size_t>(i)] >= 0)
          trial.col(i) += alpha * d.segment<3>(dof[static_cast<std::size_t>(i)]);
      double trial_value = 0.0;
      Eigen::Matrix3Xd trial_grad = objective_gradient(model, el, y, h, trial, &trial_value);
      if (trial_value <= value + 1e-4 * alpha * slope || trial_grad.norm() < grad.norm()) {
        x = std::move(trial);
        grad = std::move(trial_grad);
        value = trial_value;
        break;
      }
    }
  }
#ifdef CLOTHDB_HAVE_CHOLMOD
  omp_set_max_active_levels(saved_levels);
#endif
  if (residual) *residual = grad.norm();
  if (std::getenv("CLOTHDB_PROBE_VBD_NEWTON"))
    std::fprintf(stderr, "newton r0 %.3e r %.3e\n", r0, grad.norm());
  return x;
}

}  // namespace clothdb
