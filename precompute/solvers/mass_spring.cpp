// Provot's mass-spring cloth (Provot 1995, "Deformation constraints in a mass-spring model to
// describe rigid cloth behavior"; seed 001): structural, shear and flexion springs with Hooke and
// damping forces, semi-implicit (symplectic) Euler, and Provot's deformation-rate limit on the
// structural and shear springs after every sub-step.
//
// Springs (seed 001, "Cloth models"):
//   structural: every mesh edge.
//   shear:      grid meshes: the diagonal of each cell [i,j]-[i+1,j+1] / [i+1,j]-[i,j+1] that is
//               not already a mesh edge (a triangulated grid already has one diagonal as an edge).
//               General meshes: the pair (a, b) of each hinge, i.e. the other diagonal of the
//               quad formed by two triangles sharing an edge (seed 001, ADDSPRINGSTONODES step 8).
//   flexion:    grid meshes: [i,j]-[i+2,j] and [i,j]-[i,j+2]. General meshes: the "straightest
//               skip-one neighbour": for each edge v->u, the neighbour w of u whose rest direction
//               u->w deviates least from v->u, if by less than 45 degrees. On a grid this is
//               exactly Provot's rule; on irregular meshes it keeps flexion springs roughly
//               straight across their middle vertex, which is what lets them resist folding.
//
// Material mapping (all in SI units, so the four solvers simulate the same cloth):
//   structural k = Y A_e / l0^2, Y = E t (N/m), A_e = total rest area of the triangles adjacent to
//     the edge. With spring energy k (l - l0)^2 / 2 = k l0^2 eps^2 / 2 this makes the spring carry
//     Y eps^2 / 2 per unit area of the triangles it spans. On an equilateral lattice it gives
//     k = (sqrt 3 / 2) Y, the exact lattice value (2D Young's modulus of a triangular spring
//     lattice is 2k / sqrt 3, Poisson 1/3); on a square grid the axis springs get k = Y.
//   shear k = G t A_q / l^2 with G t = Y / (2 (1 + nu)) and A_q the rest area of the quad (two
//     triangles) whose diagonal the spring is: the same area argument with the shear modulus,
//     about Y/5 for a square cell, i.e. "small" relative to structural as Provot requires.
//   flexion k from the bending rigidity D: chosen so that folding the spring's middle vertex by a
//     reference angle theta_r = 1 rad stores the plate bending energy D kappa^2 A_m / 2, with
//     kappa = theta_r / (L/2) and A_m the middle vertex's area, while the chord L shortens by
//     L (1 - cos(theta_r / 2)). A linear spring cannot reproduce the plate's quadratic response to
//     small folds (the chord shortens only to second order), so this matches energies at one fold.
//   damping: seed 001's force with d = beta k (material.damping = beta, stiffness-proportional).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>
#include <stdexcept>
#include <utility>
#include <vector>

#include "solvers/solver.hpp"

namespace clothdb {

namespace {

enum class SpringType { Structural, Shear, Flexion };

struct Spring {
  int i, j;
  double rest;  // m
  double k;     // N/m
  double d;     // N*s/m, seed 001's damping factor
  SpringType type;
};

// Reference fold angle at which a flexion spring's energy equals the plate's (see header comment).
constexpr double kFlexionReferenceFold = 1.0;
// Springs shorter than this at rest (duplicate vertices that escaped welding) carry no direction.
constexpr double kMinRestLength = 1e-12;
// Provot's limit is a Gauss-Seidel sweep; a correction can re-stretch a neighbour, so sweep until
// no spring exceeds the critical rate by more than this relative slack, or kMaxProvotPasses. A
// stiff fabric at small sub-steps needs a few sweeps; a soft one hanging entirely at the limit
// with large sub-steps needs hundreds (the whole sheet is then an inextensible chain).
constexpr int kMaxProvotPasses = 500;
constexpr double kProvotSlack = 1e-4;
// Runaway detection besides NaN/Inf and speed: Provot's limit keeps every structural spring within
// (1 + tau_c) of its rest length, so an edge strained by more than 10 tau_c (and at least 100 %)
// after the limit means the explicit integration has run away faster than the limit can undo.
constexpr double kRunawayFactor = 10.0;
// Power iterations for the largest stiffness eigenvalue (the Rayleigh quotient converges fast).
constexpr int kPowerIterations = 100;
// Fraction of the linear stability limit recommended as sub-step (see estimate_stability_limit).
constexpr double kStabilityMargin = 0.8;

std::pair<int, int> ordered(int a, int b) {
  return {std::min(a, b), std::max(a, b)};
}

bool is_grid(const ClothMesh& mesh) {
  return mesh.grid_columns >= 2 && mesh.grid_rows >= 2 &&
         static_cast<long>(mesh.grid_columns) * mesh.grid_rows == mesh.vertex_count();
}

// The springs of a model, their per-vertex incidence and the explicit stability limit.
struct SpringNetwork {
  std::vector<Spring> springs;
  std::vector<int> adjacency_start, adjacency;
  double max_omega2 = 0.0, stiffest_k = 0.0, stiffest_m = 0.0;
  double critical_dt = 0.0;  // recommended largest sub-step
  double unstable_dt = 0.0;  // sub-steps above this are linearly unstable (power iteration)

  explicit SpringNetwork(const ClothModel& model) {
    build_springs(model);
    build_adjacency(model);
    estimate_stability_limit(model);
  }

 private:
  void add_spring(const ClothModel& model, int i, int j, double k, SpringType type,
                  std::set<std::pair<int, int>>& used) {
    if (i == j || !used.insert(ordered(i, j)).second) return;
    const double rest = (model.mesh.rest.col(i) - model.mesh.rest.col(j)).norm();
    if (rest < kMinRestLength) return;
    springs.push_back({i, j, rest, k, model.material.damping * k, type});
  }

  void build_springs(const ClothModel& model) {
    const ClothMesh& mesh = model.mesh;
    const Material& mat = model.material;
    const Eigen::Matrix3Xd& rest = mesh.rest;
    std::set<std::pair<int, int>> used;

    // Structural: A_e = sum of the adjacent triangles' rest areas (ClothModel::edge_area).
    const double stretch = mat.stretch_stiffness();
    for (size_t e = 0; e < mesh.edges.size(); ++e) {
      const auto [a, b] = mesh.edges[e];
      const double l0 = model.edge_rest_length[e];
      if (l0 < kMinRestLength) continue;
      add_spring(model, a, b, stretch * model.edge_area[e] / (l0 * l0), SpringType::Structural,
                 used);
    }

    // Shear: G t A_q / l^2 over the quad the diagonal spans.
    const double shear = stretch / (2.0 * (1.0 + mat.poisson));
    auto add_shear = [&](int i, int j, double quad_area) {
      const double l = (rest.col(i) - rest.col(j)).norm();
      if (l >= kMinRestLength)
        add_spring(model, i, j, shear * quad_area / (l * l), SpringType::Shear, used);
    };
    const bool grid = is_grid(mesh);
    if (grid) {
      for (int r = 0; r + 1 < mesh.grid_rows; ++r)
        for (int c = 0; c + 1 < mesh.grid_columns; ++c) {
          const int p00 = grid_index(mesh, c, r), p10 = grid_index(mesh, c + 1, r);
          const int p01 = grid_index(mesh, c, r + 1), p11 = grid_index(mesh, c + 1, r + 1);
          const double area =
              (rest.col(p10) - rest.col(p00)).cross(rest.col(p01) - rest.col(p00)).norm();
          add_shear(p00, p11, area);
          add_shear(p10, p01, area);
        }
    } else {
      for (const Hinge& hg : mesh.hinges) {
        const double area =
            triangle_area(rest, {hg.v0, hg.v1, hg.a}) + triangle_area(rest, {hg.v1, hg.v0, hg.b});
        add_shear(hg.a, hg.b, area);
      }
    }

    // Flexion: k = 4 D A_m / (L^4 (1 - cos(theta_r/2))^2), from
    // D (theta_r / (L/2))^2 A_m / 2 = k (L (1 - cos(theta_r / 2)))^2 / 2.
    const double bend = mat.bending_rigidity();
    const double chord = 1.0 - std::cos(0.5 * kFlexionReferenceFold);
    const double fold2 = kFlexionReferenceFold * kFlexionReferenceFold;
    auto add_flexion = [&](int i, int middle, int j) {
      const double l = (rest.col(i) - rest.col(j)).norm();
      if (l < kMinRestLength) return;
      const double k =
          4.0 * bend * fold2 * model.vertex_area[middle] / (l * l * l * l * chord * chord);
      add_spring(model, i, j, k, SpringType::Flexion, used);
    };
    if (grid) {
      for (int r = 0; r < mesh.grid_rows; ++r)
        for (int c = 0; c < mesh.grid_columns; ++c) {
          if (c + 2 < mesh.grid_columns) {
            add_flexion(grid_index(mesh, c, r), grid_index(mesh, c + 1, r),
                        grid_index(mesh, c + 2, r));
          }
          if (r + 2 < mesh.grid_rows) {
            add_flexion(grid_index(mesh, c, r), grid_index(mesh, c, r + 1),
                        grid_index(mesh, c, r + 2));
          }
        }
    } else {
      std::vector<std::vector<int>> neighbours(mesh.vertex_count());
      for (const auto& e : mesh.edges) {
        neighbours[e[0]].push_back(e[1]);
        neighbours[e[1]].push_back(e[0]);
      }
      const double min_cos = std::cos(0.25 * 3.14159265358979323846);  // 45 degrees
      for (int v = 0; v < mesh.vertex_count(); ++v)
        for (int u : neighbours[v]) {
          const Vec3 dir = (rest.col(u) - rest.col(v)).normalized();
          int best = -1;
          double best_cos = min_cos;
          for (int w : neighbours[u]) {
            if (w == v) continue;
            const Vec3 next = rest.col(w) - rest.col(u);
            const double len = next.norm();
            if (len < kMinRestLength) continue;
            const double c = dir.dot(next) / len;
            if (c > best_cos) {
              best_cos = c;
              best = w;
            }
          }
          if (best >= 0) add_flexion(v, u, best);
        }
    }
  }

  // Per-vertex incident springs (CSR) so forces are gathered per vertex: each thread writes only
  // its own vertices and sums in a fixed order, so the result does not depend on the thread count.
  void build_adjacency(const ClothModel& model) {
    const int n = model.vertex_count();
    adjacency_start.assign(n + 1, 0);
    for (const Spring& s : springs) {
      ++adjacency_start[s.i + 1];
      ++adjacency_start[s.j + 1];
    }
    for (int i = 0; i < n; ++i) adjacency_start[i + 1] += adjacency_start[i];
    adjacency.assign(adjacency_start[n], 0);
    std::vector<int> fill(adjacency_start.begin(), adjacency_start.end() - 1);
    for (size_t s = 0; s < springs.size(); ++s) {
      adjacency[fill[springs[s].i]++] = static_cast<int>(s);
      adjacency[fill[springs[s].j]++] = static_cast<int>(s);
    }
  }

  // Linear stability of symplectic Euler for M x'' = -K x - beta K x' (Rayleigh damping: every
  // spring's d is beta k): a mode with eigenvalue lambda = w^2 of M^-1 K is stable iff
  // h^2 lambda + 2 h beta lambda < 4, i.e. h < -beta + sqrt(beta^2 + 4 / lambda).
  // lambda_max is estimated by power iteration on M^-1/2 K M^-1/2 with K the rest-state stiffness
  // (k u u^T per spring); the Rayleigh quotient converges from below, and on the test sheets the
  // resulting limit separates the observed stable and exploding sub-steps to within 5 %
  // (Gershgorin's bound, max_i 2 sum k / m_i, is about 2.5x too pessimistic there). A sub-step
  // above `unstable_dt` makes the stiffest mode grow every sub-step whatever Provot's limit then
  // does to the positions, so the solver refuses it up front. `critical_dt` keeps a margin for
  // the geometric stiffness that tension adds (at Provot's 10 % about 9 % of k) and for the
  // power iteration's under-estimate.
  void estimate_stability_limit(const ClothModel& model) {
    // The stiffest vertex (largest sum k / m), only to name k and m in messages.
    double worst = 0.0;
    for (int i = 0; i < model.vertex_count(); ++i) {
      if (model.inv_mass[i] <= 0.0) continue;
      double k_sum = 0.0;
      for (int a = adjacency_start[i]; a < adjacency_start[i + 1]; ++a)
        k_sum += springs[adjacency[a]].k;
      if (k_sum * model.inv_mass[i] > worst) {
        worst = k_sum * model.inv_mass[i];
        stiffest_k = k_sum;
        stiffest_m = model.mass[i];
      }
    }
    const double beta = model.material.damping;
    max_omega2 = largest_eigenvalue(model);
    unstable_dt = max_omega2 > 0.0 ? -beta + std::sqrt(beta * beta + 4.0 / max_omega2)
                                   : std::numeric_limits<double>::infinity();
    critical_dt = kStabilityMargin * unstable_dt;
  }

  // Power iteration for the largest eigenvalue of M^-1/2 K M^-1/2 over the free vertices.
  double largest_eigenvalue(const ClothModel& model) const {
    const int n = model.vertex_count();
    const Eigen::VectorXd scale = model.inv_mass.cwiseSqrt();  // 0 at kinematic vertices
    Eigen::Matrix3Xd x(3, n), y(3, n);
    // Deterministic, sign-alternating start: rich in the high-frequency modes we are after.
    unsigned state = 12345u;
    for (int i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) {
        state = state * 1664525u + 1013904223u;
        x(c, i) = scale[i] * (((i + c) % 2 ? 1.0 : -1.0) + 0.5 * (state >> 8) / 16777216.0);
      }
    double lambda = 0.0;
    for (int it = 0; it < kPowerIterations; ++it) {
      const double norm = x.norm();
      if (norm == 0.0) return 0.0;
      x /= norm;
      y.setZero();
      for (const Spring& s : springs) {
        const Vec3 u = (model.mesh.rest.col(s.i) - model.mesh.rest.col(s.j)) / s.rest;
        const double d = s.k * u.dot(scale[s.i] * x.col(s.i) - scale[s.j] * x.col(s.j));
        y.col(s.i) += d * u;
        y.col(s.j) -= d * u;
      }
      for (int i = 0; i < n; ++i) y.col(i) *= scale[i];
      lambda = (x.array() * y.array()).sum();  // Rayleigh quotient, x normalised
      std::swap(x, y);
    }
    return lambda;
  }
};

class MassSpringSolver final : public Solver {
 public:
  MassSpringSolver(const ClothModel& model, const SolverSettings& settings)
      : model_(model), settings_(settings), net_(model_) {
    if (settings_.substeps < 1) throw std::invalid_argument("mass-spring: substeps must be >= 1");
    if (!(settings_.provot_critical_rate > 0.0)) {
      throw std::invalid_argument("mass-spring: provot_critical_rate must be > 0");
    }
  }

  StepReport step(ClothState& state, double dt, const StepInputs& inputs) override {
    if (inputs.env == nullptr) throw std::invalid_argument("mass-spring: StepInputs.env is null");
    if (!(dt > 0.0)) throw std::invalid_argument("mass-spring: dt must be > 0");
    const Eigen::Index n = model_.vertex_count();
    if (state.x.cols() != n || state.v.cols() != n) {
      throw std::invalid_argument("mass-spring: state has " + std::to_string(state.x.cols()) +
                                  " vertices, the model " + std::to_string(n));
    }
    if (inputs.kinematic_targets.cols() != 0 &&
        inputs.kinematic_targets.cols() != static_cast<Eigen::Index>(model_.kinematic.size())) {
      throw std::invalid_argument(
          "mass-spring: kinematic_targets has " + std::to_string(inputs.kinematic_targets.cols()) +
          " columns, the model " + std::to_string(model_.kinematic.size()) + " kinematic vertices");
    }
    const Environment& env = *inputs.env;
    const ClothState saved = state;
    const Eigen::Matrix3Xd kin_start = kinematic_positions(model_, state.x);
    const int substeps = settings_.substeps;
    const double h = dt / substeps;

    StepReport report;
    if (h > net_.unstable_dt) {
      report.stable = false;
      report.message = instability_message(h);
      return report;
    }
    Eigen::Matrix3Xd force(3, n);
    for (int sub = 0; sub < substeps; ++sub) {
      const double s0 = static_cast<double>(sub) / substeps;
      const double s1 = static_cast<double>(sub + 1) / substeps;
      // Kinematic vertices at the sub-step start, with their velocity, so the forces they exert
      // (and the damping against their motion) are those of the interpolated path.
      place_kinematic(model_, kin_start, inputs, s0, dt, state);
      // A state that already violates the limit at the sub-step start (a stretched initial state,
      // a jump of the kinematic targets, a collision push) is projected back without touching the
      // velocities: turning that correction into velocity would release the elongation beyond
      // tau_c as kinetic energy (a 50 % stretch corrected in one sub-step becomes ~1e4 m/s),
      // which is exactly the super-elastic energy Provot's limit exists to deny.
      report.iterations += provot_limit(state.x, model_.inv_mass);
      const Eigen::Matrix3Xd x_start = state.x;

      compute_forces(state, env, force);
      // Symplectic Euler (seed 001 "Dynamics of the System"): v += h F/m, then x += h v. The
      // linear air drag -c A v is taken implicitly, v' = (v + h F/m) / (1 + h c A / m), so a large
      // drag coefficient slows a vertex down but can never reverse it.
      for (Eigen::Index i = 0; i < n; ++i) {
        const double w = model_.inv_mass[i];
        if (w <= 0.0) continue;
        const double drag = env.air_drag * model_.vertex_area[i] * w * h;
        state.v.col(i) = (state.v.col(i) + h * w * force.col(i)) / (1.0 + drag);
        state.x.col(i) += h * state.v.col(i);
      }
      place_kinematic(model_, kin_start, inputs, s1, dt, state);

      report.iterations += provot_limit(state.x, model_.inv_mass);
      resolve_collisions(state.x, x_start, model_.inv_mass, env, s1, s0);
      // Provot 1995 sec. 4 / seed 001: the limit changes positions only; the velocities must
      // follow, otherwise the removed elongation comes back as kinetic energy in the next
      // sub-step. The same holds for the collision projection (and its friction).
      for (Eigen::Index i = 0; i < n; ++i)
        if (model_.inv_mass[i] > 0.0) state.v.col(i) = (state.x.col(i) - x_start.col(i)) / h;

      if (!state_is_sane(state) || max_edge_strain(model_, state.x) > runaway_strain()) {
        state = saved;
        report.stable = false;
        report.message = instability_message(h);
        return report;
      }
    }
    return report;
  }

  std::string describe() const override {
    char buf[160];
    std::snprintf(buf, sizeof buf, "mass-spring substeps=%d provot=%g threads=%d",
                  settings_.substeps, settings_.provot_critical_rate, settings_.threads);
    return buf;
  }

 private:
  double runaway_strain() const {
    return std::max(1.0, kRunawayFactor * settings_.provot_critical_rate);
  }

  std::string instability_message(double h) const {
    char buf[512];
    if (std::isfinite(net_.critical_dt)) {
      const int needed = static_cast<int>(std::ceil(h * settings_.substeps / net_.critical_dt));
      std::snprintf(buf, sizeof buf,
                    "mass-spring: explicit integration unstable at dt=%.3g s per sub-step (the "
                    "stiffest spring mode, w=%.3g rad/s from springs up to k=%.3g N/m on m=%.3g "
                    "kg, with damping beta=%.3g s needs dt < -beta + sqrt(beta^2 + 4/w^2) = "
                    "%.3g s, ~2*sqrt(m/k) without damping); use more substeps (>= %d for this "
                    "step)",
                    h, std::sqrt(net_.max_omega2), net_.stiffest_k, net_.stiffest_m,
                    model_.material.damping, net_.unstable_dt, needed);
    } else {
      std::snprintf(buf, sizeof buf,
                    "mass-spring: integration produced a non-finite or runaway state at dt=%.3g s "
                    "per sub-step; use more substeps",
                    h);
    }
    return buf;
  }

  // Hooke's law and seed 001's damping force for every spring, plus gravity, gathered per vertex.
  void compute_forces(const ClothState& state, const Environment& env,
                      Eigen::Matrix3Xd& force) const {
    const int n = model_.vertex_count();
#pragma omp parallel for num_threads(std::max(1, settings_.threads)) schedule(static)
    for (int i = 0; i < n; ++i) {
      Vec3 f = model_.mass[i] * env.gravity;
      if (model_.inv_mass[i] > 0.0) {
        for (int a = net_.adjacency_start[i]; a < net_.adjacency_start[i + 1]; ++a) {
          const Spring& s = net_.springs[net_.adjacency[a]];
          const int j = s.i == i ? s.j : s.i;
          const Vec3 xij = state.x.col(i) - state.x.col(j);
          const double l2 = xij.squaredNorm();
          if (l2 < kMinRestLength * kMinRestLength) continue;
          const double l = std::sqrt(l2);
          // Hooke: F_i = -k (|x_i - x_j| - r) (x_i - x_j) / |x_i - x_j|.
          f -= s.k * (l - s.rest) / l * xij;
          // Damping (seed 001): d ((v_i - v_j) . (x_i - x_j)) / |x_i - x_j|^2 (x_i - x_j), with
          // the sign that opposes the relative velocity along the spring (the seed prints the
          // magnitude; with a plus sign the force would feed energy in).
          f -= s.d * (state.v.col(i) - state.v.col(j)).dot(xij) / l2 * xij;
        }
      }
      force.col(i) = f;
    }
  }

  // Provot 1995 sec. 4 (seed 001 "Critical Deformation Rate"): a structural or shear spring
  // longer than (1 + tau_c) r is shortened to exactly that length: both ends loose -> both moved
  // evenly towards the middle; one end fixed (inverse mass 0) -> only the loose end moves; both
  // fixed -> unchanged. Swept in spring order (deterministic) until no spring exceeds the limit.
  // Returns the number of sweeps.
  int provot_limit(Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass) const {
    const double tau = settings_.provot_critical_rate;
    int passes = 0;
    bool violated = true;
    while (violated && passes < kMaxProvotPasses) {
      ++passes;
      violated = false;
      for (const Spring& s : net_.springs) {
        if (s.type == SpringType::Flexion) continue;
        const bool free_i = inv_mass[s.i] > 0.0, free_j = inv_mass[s.j] > 0.0;
        if (!free_i && !free_j) continue;
        const Vec3 d = x.col(s.j) - x.col(s.i);
        const double l = d.norm();
        const double limit = (1.0 + tau) * s.rest;
        if (l <= limit) continue;
        if (l > limit * (1.0 + kProvotSlack)) violated = true;
        const Vec3 excess = (l - limit) / l * d;  // move i by +excess or j by -excess in total
        if (free_i && free_j) {
          x.col(s.i) += 0.5 * excess;
          x.col(s.j) -= 0.5 * excess;
        } else if (free_i) {
          x.col(s.i) += excess;
        } else {
          x.col(s.j) -= excess;
        }
      }
    }
    return passes;
  }

  ClothModel model_;
  SolverSettings settings_;
  SpringNetwork net_;
};

}  // namespace

double mass_spring_critical_dt(const ClothModel& model) {
  return SpringNetwork(model).critical_dt;
}

std::unique_ptr<Solver> make_mass_spring_solver(const ClothModel& model, const SolverSettings& s) {
  return std::make_unique<MassSpringSolver>(model, s);
}

}  // namespace clothdb
