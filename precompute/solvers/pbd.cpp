// Position Based Dynamics (Mueller, Heidelberger, Hennix, Ratcliff 2007; seed 000 Algorithm 1):
// per sub-step, external forces -> dampVelocities -> predict p = x + h v -> project the distance,
// bending and collision constraints by non-linear Gauss-Seidel for `iterations` sweeps ->
// v = (p - x) / h, x = p.
//
// Constraints:
//   stretch: one distance constraint C = |p_i - p_j| - l0 per mesh edge (Mueller 2007 sec. 3.3,
//     eqs. 10-11: corrections weighted by inverse mass).
//   bending: one dihedral-angle constraint C = theta(p) - theta0 per hinge (Mueller 2007 sec. 4.2
//     and appendix A). Mueller's appendix uses acos(n1 . n2), which is unsigned and has a 0/0
//     gradient at the flat configuration every sheet starts in; we use the signed angle
//     theta = atan2((n1 x n2) . e, n1 . n2) about the hinge edge e with the closed-form gradients
//     of Bridson, Marino, Fedkiw 2003 ("Simulation of clothing with folds and wrinkles", sec. 4),
//     which are finite at theta = 0. The projection is the generic PBD step (Mueller 2007 eqs.
//     8-9): s = C / sum_k w_k |grad_k C|^2, dp_k = -k' s w_k grad_k C.
//   collisions: resolve_collisions after each sweep, so contacts take part in the Gauss-Seidel
//     iteration like Mueller's generateCollisionConstraints (Algorithm 1 line 13) and the last
//     thing done to p is the collision projection.
//
// Stiffness: a stiffness k in [0, 1] is applied per sweep as k' = 1 - (1 - k)^(1/n_iter)
// (Mueller 2007 sec. 3.3), so that after n_iter sweeps the violation is scaled by (1 - k)
// whatever n_iter is. Settings below 0 derive k per constraint from the material (approximate):
// the material's constraint stiffness k_m (N/m for stretch, N*m/rad for bending) corresponds to
// XPBD compliance 1/k_m, whose first Gauss-Seidel update (Macklin, Mueller, Chentanez 2016, eq. 18
// with lambda = 0) removes the fraction alpha / (1 + alpha) of the violation, alpha = k_m h^2 w,
// w = sum_k w_k |grad_k C|^2 the constraint's generalised inverse mass at rest. That fraction is
// used as PBD's k for the sub-step of length h.
//   stretch k_m = E t A_e / l0^2 (A_e: rest area of the edge's triangles; same as the
//     mass-spring structural spring, see mass_spring.cpp).
//   bending k_m = 3 D |e|^2 / (A_1 + A_2) (Grinspun et al. 2003, discrete shells: the energy
//     D kappa^2 / 2 over the hinge's area (A_1 + A_2) / 3 with kappa = theta / h_e and
//     h_e = (A_1 + A_2) / (3 |e|)).
// Damping: dampVelocities of Mueller 2007 sec. 3.5, which removes a fraction k_damping of every
// vertex's deviation from the free vertices' rigid-body motion (so free fall and rigid swinging
// are not damped). The material's Rayleigh coefficient beta damps a mode of angular frequency w
// at the rate beta w^2 / 2; PBD damps all non-rigid motion alike, so we take the rate of a
// reference cloth-wave frequency (10 Hz): k_damping = 1 - exp(-h beta w_ref^2 / 2), independent
// of the sub-step length in the limit.
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <utility>
#include <vector>

#include "solvers/solver.hpp"

namespace clothdb {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDampingReferenceOmega = 2.0 * kPi * 10.0;  // rad/s, see header comment
constexpr double kTiny = 1e-30;

struct DistanceConstraint {
  int i, j;
  double rest;        // m
  double material_k;  // N/m
};

struct BendConstraint {
  int v0, v1, a, b;   // hinge: triangles (v0, v1, a) and (v1, v0, b)
  double rest_angle;  // signed dihedral angle at rest, rad
  double material_k;  // N*m/rad
  double rest_w;      // sum_k w_k |grad_k theta|^2 at rest
};

// Signed dihedral angle of a hinge and its gradient with respect to (x0, x1, xa, xb)
// (Bridson et al. 2003 sec. 4). Returns false for degenerate triangles, where it is undefined.
bool dihedral(const Vec3& x0, const Vec3& x1, const Vec3& xa, const Vec3& xb, double& theta,
              Vec3 grad[4]) {
  const Vec3 e = x1 - x0;
  const double el = e.norm();
  const Vec3 na = e.cross(xa - x0);    // normal of (x0, x1, xa), length 2 area
  const Vec3 nb = (xb - x1).cross(e);  // normal of (x1, x0, xb)
  const double na2 = na.squaredNorm(), nb2 = nb.squaredNorm();
  if (el < 1e-15 || na2 < kTiny || nb2 < kTiny) return false;
  const Vec3 ua = na / std::sqrt(na2), ub = nb / std::sqrt(nb2);
  theta = std::atan2(ua.cross(ub).dot(e) / el, ua.dot(ub));
  const Vec3 qa = na / na2, qb = nb / nb2;
  grad[2] = -el * qa;
  grad[3] = -el * qb;
  grad[0] = -((xa - x1).dot(e) / el) * qa - ((xb - x1).dot(e) / el) * qb;
  grad[1] = ((xa - x0).dot(e) / el) * qa + ((xb - x0).dot(e) / el) * qb;
  return true;
}

// Maps an angle difference to (-pi, pi] so a hinge never "unwinds" the long way round.
double wrap_angle(double a) {
  while (a > kPi) a -= 2.0 * kPi;
  while (a <= -kPi) a += 2.0 * kPi;
  return a;
}

// Mueller 2007 sec. 3.3: per-sweep stiffness so that n sweeps scale the violation by (1 - k).
double per_iteration(double k, int iterations) {
  k = std::clamp(k, 0.0, 1.0);
  if (k >= 1.0) return 1.0;
  return 1.0 - std::pow(1.0 - k, 1.0 / iterations);
}

// Fraction of the violation removed by one XPBD update with compliance 1/k_m (see header).
double material_fraction(double material_k, double h, double w) {
  const double alpha = material_k * h * h * w;
  return alpha / (1.0 + alpha);
}

class PbdSolver final : public Solver {
 public:
  PbdSolver(const ClothModel& model, const SolverSettings& settings)
      : model_(model), settings_(settings) {
    if (settings_.substeps < 1) throw std::invalid_argument("pbd: substeps must be >= 1");
    if (settings_.iterations < 1) throw std::invalid_argument("pbd: iterations must be >= 1");
    build_constraints();
  }

  StepReport step(ClothState& state, double dt, const StepInputs& inputs) override {
    if (inputs.env == nullptr) throw std::invalid_argument("pbd: StepInputs.env is null");
    if (!(dt > 0.0)) throw std::invalid_argument("pbd: dt must be > 0");
    const Eigen::Index n = model_.vertex_count();
    if (state.x.cols() != n || state.v.cols() != n) {
      throw std::invalid_argument("pbd: state has " + std::to_string(state.x.cols()) +
                                  " vertices, the model " + std::to_string(n));
    }
    if (inputs.kinematic_targets.cols() != 0 &&
        inputs.kinematic_targets.cols() != static_cast<Eigen::Index>(model_.kinematic.size())) {
      throw std::invalid_argument(
          "pbd: kinematic_targets has " + std::to_string(inputs.kinematic_targets.cols()) +
          " columns, the model " + std::to_string(model_.kinematic.size()) + " kinematic vertices");
    }
    const Environment& env = *inputs.env;
    const ClothState saved = state;
    const Eigen::Matrix3Xd kin_start = kinematic_positions(model_, state.x);
    const int substeps = settings_.substeps, iterations = settings_.iterations;
    const double h = dt / substeps;
    update_stiffness(h);
    const double k_damping = 1.0 - std::exp(-h * model_.material.damping * kDampingReferenceOmega *
                                            kDampingReferenceOmega / 2.0);

    StepReport report;
    ClothState predicted;
    for (int sub = 0; sub < substeps; ++sub) {
      const double s0 = static_cast<double>(sub) / substeps;
      const double s1 = static_cast<double>(sub + 1) / substeps;
      place_kinematic(model_, kin_start, inputs, s0, dt, state);
      // Algorithm 1 lines 5-7: v += h w f_ext. Gravity, and the linear air drag -c A v taken
      // implicitly (v / (1 + h c A w)) so that it can never reverse a velocity.
      for (Eigen::Index i = 0; i < n; ++i) {
        const double w = model_.inv_mass[i];
        if (w <= 0.0) continue;
        const double drag = env.air_drag * model_.vertex_area[i] * w * h;
        state.v.col(i) = (state.v.col(i) + h * env.gravity) / (1.0 + drag);
      }
      damp_velocities(state, k_damping);  // line 8
      // Lines 9-11: p = x + h v; kinematic vertices go to their sub-step targets.
      predicted.x = state.x;
      predicted.v = state.v;
      for (Eigen::Index i = 0; i < n; ++i)
        if (model_.inv_mass[i] > 0.0) predicted.x.col(i) += h * state.v.col(i);
      place_kinematic(model_, kin_start, inputs, s1, dt, predicted);
      // Lines 12-17: Gauss-Seidel over all constraints, collisions included, in a fixed order.
      for (int it = 0; it < iterations; ++it) {
        project_distances(predicted.x);
        project_bending(predicted.x);
        resolve_collisions(predicted.x, state.x, model_.inv_mass, env, s1, s0);
      }
      report.iterations += iterations;
      // Lines 18-21: v = (p - x) / h, x = p.
      for (Eigen::Index i = 0; i < n; ++i)
        if (model_.inv_mass[i] > 0.0)
          predicted.v.col(i) = (predicted.x.col(i) - state.x.col(i)) / h;
      std::swap(state, predicted);
      if (!state_is_sane(state)) {
        state = saved;
        report.stable = false;
        char buf[256];
        std::snprintf(buf, sizeof buf,
                      "pbd: non-finite or runaway state (speed > 200 m/s) at sub-step dt=%.3g s; "
                      "check the scene's forces and kinematic targets",
                      h);
        report.message = buf;
        return report;
      }
    }
    return report;
  }

  std::string describe() const override {
    char buf[200];
    std::snprintf(buf, sizeof buf, "pbd substeps=%d iterations=%d stretch=%s bend=%s",
                  settings_.substeps, settings_.iterations,
                  stiffness_label(settings_.pbd_stretch_stiffness).c_str(),
                  stiffness_label(settings_.pbd_bend_stiffness).c_str());
    return buf;
  }

 private:
  static std::string stiffness_label(double k) {
    if (k < 0.0) return "material";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", k);
    return buf;
  }

  void build_constraints() {
    const ClothMesh& mesh = model_.mesh;
    const Eigen::Matrix3Xd& rest = mesh.rest;
    const Eigen::VectorXd& w = model_.inv_mass;
    const double stretch = model_.material.stretch_stiffness();
    for (size_t e = 0; e < mesh.edges.size(); ++e) {
      const auto [i, j] = mesh.edges[e];
      const double l0 = model_.edge_rest_length[e];
      if (w[i] + w[j] <= 0.0 || l0 <= 0.0) continue;  // both pinned: nothing to project
      distance_.push_back({i, j, l0, stretch * model_.edge_area[e] / (l0 * l0)});
    }
    // Gauss-Seidel leaves each sweep's last constraints exactly satisfied and the earlier ones with
    // a residual of similar absolute size. The same residual is the largest relative strain on the
    // shortest edges (slivers), so project those last: longest rest length first, ties in edge
    // order (stable sort, deterministic).
    std::stable_sort(
        distance_.begin(), distance_.end(),
        [](const DistanceConstraint& a, const DistanceConstraint& b) { return a.rest > b.rest; });
    const double bend = model_.material.bending_rigidity();
    for (const Hinge& hg : mesh.hinges) {
      if (w[hg.v0] + w[hg.v1] + w[hg.a] + w[hg.b] <= 0.0) continue;
      double theta = 0.0;
      Vec3 grad[4];
      if (!dihedral(rest.col(hg.v0), rest.col(hg.v1), rest.col(hg.a), rest.col(hg.b), theta,
                    grad)) {
        continue;  // a zero-area rest triangle has no bending direction to restore
      }
      const int ids[4] = {hg.v0, hg.v1, hg.a, hg.b};
      double wsum = 0.0;
      for (int k = 0; k < 4; ++k) wsum += w[ids[k]] * grad[k].squaredNorm();
      const double areas =
          triangle_area(rest, {hg.v0, hg.v1, hg.a}) + triangle_area(rest, {hg.v1, hg.v0, hg.b});
      const double e2 = (rest.col(hg.v1) - rest.col(hg.v0)).squaredNorm();
      bend_.push_back({hg.v0, hg.v1, hg.a, hg.b, theta, 3.0 * bend * e2 / areas, wsum});
    }
    distance_k_.assign(distance_.size(), 0.0);
    bend_k_.assign(bend_.size(), 0.0);
  }

  // Per-sweep stiffness k' of every constraint for sub-steps of length h (cached per h).
  void update_stiffness(double h) {
    if (h == cached_h_) return;
    cached_h_ = h;
    const int n_iter = settings_.iterations;
    const Eigen::VectorXd& w = model_.inv_mass;
    const double ks = settings_.pbd_stretch_stiffness, kb = settings_.pbd_bend_stiffness;
    for (size_t c = 0; c < distance_.size(); ++c) {
      const auto& d = distance_[c];
      const double k = ks >= 0.0 ? ks : material_fraction(d.material_k, h, w[d.i] + w[d.j]);
      distance_k_[c] = per_iteration(k, n_iter);
    }
    for (size_t c = 0; c < bend_.size(); ++c) {
      const auto& b = bend_[c];
      const double k = kb >= 0.0 ? kb : material_fraction(b.material_k, h, b.rest_w);
      bend_k_[c] = per_iteration(k, n_iter);
    }
  }

  // Mueller 2007 eqs. 10-11.
  void project_distances(Eigen::Matrix3Xd& p) const {
    const Eigen::VectorXd& w = model_.inv_mass;
    for (size_t c = 0; c < distance_.size(); ++c) {
      const double k = distance_k_[c];
      if (k <= 0.0) continue;
      const auto& d = distance_[c];
      const Vec3 diff = p.col(d.i) - p.col(d.j);
      const double l = diff.norm();
      if (l < 1e-15) continue;
      const double wi = w[d.i], wj = w[d.j];
      const Vec3 corr = (k * (l - d.rest) / ((wi + wj) * l)) * diff;
      p.col(d.i) -= wi * corr;
      p.col(d.j) += wj * corr;
    }
  }

  // Mueller 2007 eqs. 8-9 on the signed dihedral angle.
  void project_bending(Eigen::Matrix3Xd& p) const {
    const Eigen::VectorXd& w = model_.inv_mass;
    for (size_t c = 0; c < bend_.size(); ++c) {
      const double k = bend_k_[c];
      if (k <= 0.0) continue;
      const auto& b = bend_[c];
      const int ids[4] = {b.v0, b.v1, b.a, b.b};
      double theta = 0.0;
      Vec3 grad[4];
      if (!dihedral(p.col(b.v0), p.col(b.v1), p.col(b.a), p.col(b.b), theta, grad)) continue;
      double wsum = 0.0;
      for (int m = 0; m < 4; ++m) wsum += w[ids[m]] * grad[m].squaredNorm();
      if (wsum < kTiny) continue;
      const double s = k * wrap_angle(theta - b.rest_angle) / wsum;
      for (int m = 0; m < 4; ++m) p.col(ids[m]) -= (s * w[ids[m]]) * grad[m];
    }
  }

  // Mueller 2007 sec. 3.5: blend each free vertex's velocity towards the rigid-body motion
  // (linear and angular momentum) of the free vertices, by the fraction k.
  void damp_velocities(ClothState& state, double k) const {
    if (k <= 0.0) return;
    const Eigen::Index n = model_.vertex_count();
    double mass = 0.0;
    Vec3 x_cm = Vec3::Zero(), v_cm = Vec3::Zero();
    for (Eigen::Index i = 0; i < n; ++i) {
      if (model_.inv_mass[i] <= 0.0) continue;
      mass += model_.mass[i];
      x_cm += model_.mass[i] * state.x.col(i);
      v_cm += model_.mass[i] * state.v.col(i);
    }
    if (mass <= 0.0) return;
    x_cm /= mass;
    v_cm /= mass;
    Vec3 angular = Vec3::Zero();
    Eigen::Matrix3d inertia = Eigen::Matrix3d::Zero();
    for (Eigen::Index i = 0; i < n; ++i) {
      if (model_.inv_mass[i] <= 0.0) continue;
      const Vec3 r = state.x.col(i) - x_cm;
      angular += r.cross(model_.mass[i] * state.v.col(i));
      // [r]x [r]x^T = |r|^2 I - r r^T.
      inertia +=
          model_.mass[i] * (r.squaredNorm() * Eigen::Matrix3d::Identity() - r * r.transpose());
    }
    // omega = I^-1 L; a line of vertices has a singular I, so invert only the non-degenerate axes.
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(inertia);
    const Eigen::Vector3d lambda = eig.eigenvalues();
    const double cutoff = 1e-12 * std::max(lambda.maxCoeff(), 0.0);
    Eigen::Vector3d coeff = eig.eigenvectors().transpose() * angular;
    for (int a = 0; a < 3; ++a)
      coeff[a] = lambda[a] > cutoff && lambda[a] > 0.0 ? coeff[a] / lambda[a] : 0.0;
    const Vec3 omega = eig.eigenvectors() * coeff;
    for (Eigen::Index i = 0; i < n; ++i) {
      if (model_.inv_mass[i] <= 0.0) continue;
      const Vec3 rigid = v_cm + omega.cross(state.x.col(i) - x_cm);
      state.v.col(i) += k * (rigid - state.v.col(i));
    }
  }

  ClothModel model_;
  SolverSettings settings_;
  std::vector<DistanceConstraint> distance_;
  std::vector<BendConstraint> bend_;
  std::vector<double> distance_k_, bend_k_;
  double cached_h_ = -1.0;
};

}  // namespace

std::unique_ptr<Solver> make_pbd_solver(const ClothModel& model, const SolverSettings& s) {
  return std::make_unique<PbdSolver>(model, s);
}

}  // namespace clothdb
