// XPBD: extended position-based dynamics (Macklin, Mueller, Chentanez 2016, "XPBD: Position-Based
// Simulation of Compliant Constrained Dynamics"), run with many small sub-steps (Macklin et al.
// 2019, "Small Steps in Physics Simulation"). Constraints:
//  * one distance constraint per mesh edge, C = |x_i - x_j| - l0, and
//  * one dihedral-angle bending constraint per hinge, C = theta - theta0 (Mueller 2007 appendix A,
//    with the Bridson, Marino & Fedkiw 2003 gradients),
// each with a compliance alpha = 1/k from the physical Material, using the Newton solver's
// stiffness coefficients (shell_energy.hpp; see build_constraints) so XPBD simulates the same
// cloth. Stiffness-proportional (Rayleigh) damping (Macklin 2016 eq. 26) acts on bending only:
// in the stretch update it would sit in the denominator, (1 + damping/h), so that every sweep
// corrected only a fraction of the stretch error, and the smaller h (more sub-steps), the smaller
// that fraction (docs/notebook/BENCHMARKS.md, "The 10,000-vertex sheet (hanging from two corners,
// tethers on)": on a tethered 10k sheet, 80 sub-steps gave 27 % strain with damping 1e-3 and 6 %
// without). Stretch gets its own sweep count (stretch_iterations), and an optional Provot (1995)
// strain limit clamps the edges that are still longer than (1 + limit) l0 before collisions.
// For fine meshes (docs/guide/resolution.md) the strain limit's passes can be over-relaxed
// (strain_limit_relaxation) and the stretch sweeps Chebyshev-accelerated (chebyshev_rho), both off
// by default.
// Constraints, the strain limit and collisions run in parallel (each colour's constraints share no
// vertex; collisions are per vertex): the result does not depend on the number of threads.
#include <omp.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numbers>
#include <queue>
#include <stdexcept>
#include <string>
#include <vector>

#include "solvers/coloring.hpp"
#include "solvers/self_collision.hpp"
#include "solvers/shell_energy.hpp"
#include "solvers/solver.hpp"
#include "solvers/strain_limit.hpp"

namespace clothdb {

namespace {

// Constraints of one kind, stored flat (structure of arrays) and sorted by colour so that colour g
// is the contiguous range [color_begin[g], color_begin[g + 1]).
template <std::size_t N>
struct ConstraintSet {
  std::vector<std::array<int, N>> vertices;
  std::vector<double> rest;        // l0 (m) or theta0 (rad)
  std::vector<double> compliance;  // alpha = 1/k (m/N, or 1/(N m) per rad^2 for bending)
  std::vector<double> lambda;  // Lagrange multiplier, reset every sub-step (Macklin 2016 alg. 1)
  std::vector<int> color_begin;

  // Reorders the constraints by greedy colour (coloring.hpp), keeping the original order within a
  // colour so memory access stays mostly sequential.
  void sort_by_color() {
    const std::vector<std::vector<int>> groups = greedy_coloring(vertices);
    ConstraintSet sorted;
    sorted.color_begin.push_back(0);
    for (const auto& group : groups) {
      for (int c : group) {
        sorted.vertices.push_back(vertices[static_cast<std::size_t>(c)]);
        sorted.rest.push_back(rest[static_cast<std::size_t>(c)]);
        sorted.compliance.push_back(compliance[static_cast<std::size_t>(c)]);
      }
      sorted.color_begin.push_back(static_cast<int>(sorted.vertices.size()));
    }
    sorted.lambda.assign(sorted.vertices.size(), 0.0);
    *this = std::move(sorted);
  }
  int color_count() const { return static_cast<int>(color_begin.size()) - 1; }
};

using Vec = Eigen::Map<Vec3>;

// Signed dihedral angle of hinge (v0, v1, a, b) and its gradient with respect to the four vertices
// (Bridson, Marino & Fedkiw 2003, sec. 4.1 "bending"). Triangles (v0, v1, a) and (v1, v0, b) have
// normals n1, n2 (area-weighted); theta = atan2((n2 x n1) . e_hat, n1 . n2) is 0 when flat,
// positive when the wings a, b move along their normals. Returns false for degenerate triangles.
[[gnu::always_inline]] inline bool dihedral_angle(const Vec3& p0, const Vec3& p1, const Vec3& pa,
                                                  const Vec3& pb, double& theta, Vec3& g0, Vec3& g1,
                                                  Vec3& ga, Vec3& gb) {
  const Vec3 e = p1 - p0;
  const double e_sq = e.squaredNorm();
  const Vec3 n1 = (pa - p0).cross(pa - p1);
  const Vec3 n2 = (pb - p1).cross(pb - p0);
  const double n1_sq = n1.squaredNorm(), n2_sq = n2.squaredNorm();
  // |n| is twice the triangle area: skip slivers whose area is ~1e-12 of e^2, where the gradient
  // 1/|n| would blow up.
  const double tiny = 1e-24 * e_sq * e_sq;
  if (!(e_sq > 0.0) || n1_sq <= tiny || n2_sq <= tiny) return false;
  const double e_len = std::sqrt(e_sq), inv_e = 1.0 / e_len;
  theta = std::atan2(n2.cross(n1).dot(e) * inv_e, n1.dot(n2));
  const Vec3 m1 = n1 * (1.0 / n1_sq), m2 = n2 * (1.0 / n2_sq);
  // Signed distances along the edge from v0 to the projections of the wings a and b.
  const double a0 = (pa - p0).dot(e) * inv_e, b0 = (pb - p0).dot(e) * inv_e;
  ga = e_len * m1;
  gb = e_len * m2;
  g0 = (a0 - e_len) * m1 + (b0 - e_len) * m2;
  g1 = -a0 * m1 - b0 * m2;
  return true;
}

// Wraps an angle difference into (-pi, pi] so a rest angle near +pi and a current angle near -pi
// (the same fold) give a small constraint value.
double wrap_angle(double d) {
  constexpr double pi = std::numbers::pi;
  constexpr double two_pi = 2.0 * std::numbers::pi;
  if (d > pi) return d - two_pi;
  if (d <= -pi) return d + two_pi;
  return d;
}

class XpbdSolver final : public Solver {
 public:
  // sweeps false: the step runs no bending or stretch sweeps (make_xpbd_projection_solver).
  XpbdSolver(const ClothModel& model, const SolverSettings& settings, bool sweeps = true)
      : model_(model), settings_(settings), sweeps_(sweeps) {
    if (settings.substeps < 1) throw std::invalid_argument("xpbd: substeps must be at least 1");
    if (settings.iterations < 1) throw std::invalid_argument("xpbd: iterations must be at least 1");
    if (settings.stretch_iterations < 0)
      throw std::invalid_argument("xpbd: stretch_iterations must be at least 0 (0: as iterations)");
    if (!(settings.strain_limit >= 0.0))
      throw std::invalid_argument("xpbd: strain_limit must be at least 0 (0: off)");
    if (settings.strain_limit_iterations < 1)
      throw std::invalid_argument("xpbd: strain_limit_iterations must be at least 1");
    if (settings.strain_limit_contact_rounds < 0)
      throw std::invalid_argument("xpbd: strain_limit_contact_rounds must be at least 0");
    if (settings.threads < 1) throw std::invalid_argument("xpbd: threads must be at least 1");
    if (!(settings.strain_limit_relaxation >= 1.0 && settings.strain_limit_relaxation < 2.0))
      throw std::invalid_argument("xpbd: strain_limit_relaxation must be in [1, 2) (1: off)");
    if (!(settings.chebyshev_rho >= 0.0 && settings.chebyshev_rho < 1.0))
      throw std::invalid_argument("xpbd: chebyshev_rho must be in [0, 1) (0: off)");
    build_constraints();
    if (settings.tethers) build_tethers();
    build_vertex_edges();
    if (settings.self_collision_thickness_mm > 0.0) {
      self_ = make_self_collision(model_, settings.self_collision_thickness_mm * 1e-3);
      self_.body_normal.setZero(3, model_.vertex_count());
      self_.body_room.assign(static_cast<std::size_t>(model_.vertex_count()), NAN);  // not asked
    }
  }

  std::string describe() const override {
    std::string out = "xpbd substeps=" + std::to_string(settings_.substeps);
    if (!sweeps_)
      out += " projections only";
    else
      out += " iterations=" + std::to_string(settings_.iterations);
    if (sweeps_ && stretch_iterations() != settings_.iterations)
      out += " stretch_iterations=" + std::to_string(stretch_iterations());
    if (settings_.strain_limit > 0.0) {
      char buf[64];
      std::snprintf(buf, sizeof buf, " strain_limit=%g", settings_.strain_limit);
      out += buf;
      if (settings_.strain_limit_iterations != 1) {
        std::snprintf(buf, sizeof buf, "x%d", settings_.strain_limit_iterations);
        out += buf;
      }
      if (settings_.strain_limit_relaxation != 1.0) {
        std::snprintf(buf, sizeof buf, " relaxation=%g", settings_.strain_limit_relaxation);
        out += buf;
      }
      if (settings_.strain_limit_contact_rounds > 0)
        out += " contact_rounds=" + std::to_string(settings_.strain_limit_contact_rounds);
    }
    if (settings_.chebyshev_rho > 0.0) {
      char buf[64];
      std::snprintf(buf, sizeof buf, " chebyshev_rho=%g", settings_.chebyshev_rho);
      out += buf;
    }
    if (settings_.self_collision_thickness_mm > 0.0) {
      char buf[64];
      std::snprintf(buf, sizeof buf, " self_collision=%gmm", settings_.self_collision_thickness_mm);
      out += buf;
    }
    return out;
  }

  StepReport step(ClothState& state, double dt, const StepInputs& inputs) override;

 private:
  void build_constraints();
  int stretch_iterations() const {
    return settings_.stretch_iterations > 0 ? settings_.stretch_iterations : settings_.iterations;
  }
  void solve_stretch(int begin, int end, Eigen::Matrix3Xd& x, double alpha_scale);
  // Chebyshev semi-iterative acceleration of the stretch sweeps (Wang 2015), after stretch sweep
  // `sweep` of a sub-step with weight omega; called by every thread of the team.
  void chebyshev_extrapolate(int sweep, double omega, Eigen::Matrix3Xd& x);
  // x^(k-1) and x^k of Wang 2015 eq. 12 (positions before the previous and the last sweep).
  Eigen::Matrix3Xd cheb_prev_, cheb_cur_;
  // One full pass of the strain limit over the constraints [begin, end) of one colour, in
  // parallel; marks the vertices it moves in limit_moved_.
  void limit_strain(int begin, int end, Eigen::Matrix3Xd& x, double max_stretch);
  // The strain limit to convergence (at most strain_limit_iterations passes), called by every
  // thread of the team: a full parallel pass, then serial passes that visit only the edges at a
  // vertex moved since the edge was last checked ("dirty"). A full pass would find every other
  // edge within the limit and skip it, so the result is bit-identical to full passes in colour
  // order, at the cost of the edges near the trouble: a stretched ring (the hem around a leg)
  // needs dozens of passes, each of which would otherwise test all 9,000 edges of the skirt.
  // Returns whether the first pass shortened any edge.
  bool run_strain_limit(Eigen::Matrix3Xd& x, double max_stretch);
  // One pass over the dirty constraints in colour order, serial; returns whether it shortened any.
  bool limit_strain_dirty(Eigen::Matrix3Xd& x, double max_stretch);
  void mark_edges_dirty(int v) {
    const std::size_t vu = static_cast<std::size_t>(v);
    for (int k = vertex_edge_begin_[vu]; k < vertex_edge_begin_[vu + 1]; ++k)
      edge_dirty_[static_cast<std::size_t>(vertex_edges_[static_cast<std::size_t>(k)])] = 1;
  }
  // Set by limit_strain when it shortened an edge in the current pass (read after the pass).
  int limit_corrected_ = 0;
  std::vector<unsigned char> limit_moved_;  // per vertex: moved by the first (parallel) pass
  std::vector<unsigned char> edge_dirty_;   // per constraint: a vertex moved since its last test
  // The vertices the last run_strain_limit moved (flag and list), for the contact rounds.
  // The step's environment for the contact rounds: without friction, and also without the
  // margin after the last round.
  Environment round_env_, surface_env_;
  std::vector<unsigned char> limit_touched_;
  std::vector<int> limit_touched_list_;
  void touch(int v) {
    if (limit_touched_[static_cast<std::size_t>(v)] != 0) return;
    limit_touched_[static_cast<std::size_t>(v)] = 1;
    limit_touched_list_.push_back(v);
  }
  // Stretch constraints at each vertex (CSR): vertex_edges_[vertex_edge_begin_[v] ...].
  std::vector<int> vertex_edge_begin_, vertex_edges_;
  // Strain-limit passes run (the first full pass and the dirty passes after it) and runs that
  // stopped at the cap with a pass that still shortened an edge, since the step began
  // (StepReport::strain_limit_passes, strain_limit_capped).
  long limit_passes_ = 0;
  int limit_capped_ = 0;
  void solve_bend(int begin, int end, Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_prev,
                  double alpha_scale, double gamma);

  // A copy: the solver must not dangle if the caller's model (e.g. a temporary scene) goes away.
  const ClothModel model_;
  SolverSettings settings_;
  bool sweeps_ = true;
  ConstraintSet<2> stretch_;
  ConstraintSet<4> bend_;
  // Long-range attachments: free vertex, its nearest pin along the mesh, and that path's rest
  // length. One per free vertex and pins are never written, so they project in parallel.
  std::vector<int> tether_vertex_, tether_anchor_;
  std::vector<double> tether_length_;
  void build_tethers();
  void build_vertex_edges();
  // Cloth self-collision (solvers/self_collision.hpp); thickness 0 when off.
  SelfCollision self_;
};

void XpbdSolver::build_vertex_edges() {
  const std::size_t n = static_cast<std::size_t>(model_.vertex_count());
  vertex_edge_begin_.assign(n + 1, 0);
  for (const auto& v : stretch_.vertices) {
    ++vertex_edge_begin_[static_cast<std::size_t>(v[0]) + 1];
    ++vertex_edge_begin_[static_cast<std::size_t>(v[1]) + 1];
  }
  for (std::size_t i = 0; i < n; ++i) vertex_edge_begin_[i + 1] += vertex_edge_begin_[i];
  vertex_edges_.assign(static_cast<std::size_t>(vertex_edge_begin_[n]), 0);
  std::vector<int> fill(vertex_edge_begin_.begin(), vertex_edge_begin_.end() - 1);
  for (std::size_t c = 0; c < stretch_.vertices.size(); ++c) {
    for (int v : stretch_.vertices[c])
      vertex_edges_[static_cast<std::size_t>(fill[static_cast<std::size_t>(v)]++)] =
          static_cast<int>(c);
  }
  limit_moved_.assign(n, 0);
  edge_dirty_.assign(stretch_.vertices.size(), 0);
  limit_touched_.assign(n, 0);
}

void XpbdSolver::build_tethers() {
  // Multi-source Dijkstra over the mesh edges (rest lengths) from every pin (Kim, Chentanez &
  // Mueller 2012, "Long Range Attachments": geodesic rest distance to the nearest attachment).
  const int n = model_.vertex_count();
  if (model_.kinematic.empty()) return;
  std::vector<std::vector<std::pair<int, double>>> adjacency(static_cast<std::size_t>(n));
  for (std::size_t e = 0; e < model_.mesh.edges.size(); ++e) {
    const int a = model_.mesh.edges[e][0], b = model_.mesh.edges[e][1];
    adjacency[static_cast<std::size_t>(a)].push_back({b, model_.edge_rest_length[e]});
    adjacency[static_cast<std::size_t>(b)].push_back({a, model_.edge_rest_length[e]});
  }
  std::vector<double> distance(static_cast<std::size_t>(n),
                               std::numeric_limits<double>::infinity());
  std::vector<int> anchor(static_cast<std::size_t>(n), -1);
  using Item = std::pair<double, int>;
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
  for (int k : model_.kinematic) {
    distance[static_cast<std::size_t>(k)] = 0.0;
    anchor[static_cast<std::size_t>(k)] = k;
    queue.push({0.0, k});
  }
  while (!queue.empty()) {
    const auto [d, v] = queue.top();
    queue.pop();
    if (d > distance[static_cast<std::size_t>(v)]) continue;
    for (const auto& [u, len] : adjacency[static_cast<std::size_t>(v)]) {
      const double nd = d + len;
      // Ties go to the lower anchor index so the result does not depend on the queue's order.
      if (nd < distance[static_cast<std::size_t>(u)] ||
          (nd == distance[static_cast<std::size_t>(u)] &&
           anchor[static_cast<std::size_t>(v)] < anchor[static_cast<std::size_t>(u)])) {
        distance[static_cast<std::size_t>(u)] = nd;
        anchor[static_cast<std::size_t>(u)] = anchor[static_cast<std::size_t>(v)];
        queue.push({nd, u});
      }
    }
  }
  for (int i = 0; i < n; ++i) {
    if (model_.inv_mass[i] <= 0.0 || anchor[static_cast<std::size_t>(i)] < 0) continue;
    tether_vertex_.push_back(i);
    tether_anchor_.push_back(anchor[static_cast<std::size_t>(i)]);
    tether_length_.push_back(distance[static_cast<std::size_t>(i)]);
  }
}

void XpbdSolver::build_constraints() {
  const ClothMesh& mesh = model_.mesh;
  const Material& mat = model_.material;
  const Eigen::Matrix3Xd& rest = mesh.rest;

  const std::vector<double>& edge_area = model_.edge_area;  // A_adj per edge

  // Stretch: the same edge springs as the Newton, mass-spring and PBD solvers (shell_energy.hpp,
  // stretch_coefficient): U = 1/2 k (l - l0)^2 with k = k_s / l0 = (E t) A_adj / l0^2. On an
  // equilateral mesh that is the triangular spring lattice whose 2D Young's modulus is E t (Poisson
  // ratio 1/3); equivalently, under a uniform strain eps the springs store 3/2 (E t) eps^2 per unit
  // area, the continuum value (E t) eps^2 / (1 - nu) at nu = 1/3. XPBD writes U = 1/2 alpha^-1 C^2
  // (Macklin 2016 eq. 4) with C = l - l0, so the compliance is alpha = 1 / k = l0 / k_s (m/N).
  const double et = mat.stretch_stiffness();
  for (std::size_t e = 0; e < mesh.edges.size(); ++e) {
    const double l0 = model_.edge_rest_length[e];
    if (l0 <= 0.0) continue;  // coincident rest vertices: no direction to act along
    const double k_s = stretch_coefficient(et, edge_area[e], l0);
    stretch_.vertices.push_back(mesh.edges[e]);
    stretch_.rest.push_back(l0);
    // An edge of zero-area triangles only has k = 0: keep it as a very soft constraint instead of
    // dividing by zero.
    stretch_.compliance.push_back(k_s > 0.0 ? l0 / k_s : 1e12);
  }

  // Bending: discrete shells (Grinspun et al. 2003; Tamstorf & Grinspun 2013), again with the
  // Newton solver's coefficient (shell_energy.hpp, bend_coefficient):
  // U = 1/2 k_b (theta - theta0)^2, k_b = D |e|^2 / (A1 + A2), which stores D/2 kappa^2 per unit
  // area when a grid sheet is rolled into a cylinder of curvature kappa. C = theta - theta0 and
  // alpha = 1 / k_b (1 / (N m) per rad^2).
  const double d = mat.bending_rigidity();
  if (d > 0.0) {
    for (const Hinge& h : mesh.hinges) {
      Vec3 g0, g1, ga, gb;
      double theta0 = 0.0;
      if (!dihedral_angle(rest.col(h.v0), rest.col(h.v1), rest.col(h.a), rest.col(h.b), theta0, g0,
                          g1, ga, gb)) {
        continue;  // degenerate at rest: no meaningful rest angle
      }
      const double areas =
          triangle_area(rest, {h.v0, h.v1, h.a}) + triangle_area(rest, {h.v1, h.v0, h.b});
      const double kb = bend_coefficient(d, (rest.col(h.v1) - rest.col(h.v0)).norm(), areas);
      if (!(kb > 0.0)) continue;
      bend_.vertices.push_back({h.v0, h.v1, h.a, h.b});
      bend_.rest.push_back(theta0);
      bend_.compliance.push_back(1.0 / kb);
    }
  }

  stretch_.sort_by_color();
  bend_.sort_by_color();
}

// XPBD update (Macklin 2016 eq. 18) for C = |xi - xj| - l0, without damping:
//   dlambda = (-C - alpha~ lambda) / (sum w |grad C|^2 + alpha~), alpha~ = alpha / h^2.
// Eq. 26's Rayleigh term would multiply the denominator by (1 + gamma), gamma = damping / h: at
// 30 sub-steps of 1/30 s and damping 1e-3 s, gamma = 0.9 and each sweep would remove only about
// half of the stretch error. Sub-stepping itself damps the stiff stretch modes (Macklin 2019).
void XpbdSolver::solve_stretch(int begin, int end, Eigen::Matrix3Xd& x, double alpha_scale) {
  const double* w = model_.inv_mass.data();
#pragma omp for schedule(static)
  for (int c = begin; c < end; ++c) {
    const std::size_t cu = static_cast<std::size_t>(c);
    const int i = stretch_.vertices[cu][0], j = stretch_.vertices[cu][1];
    const double wi = w[i], wj = w[j];
    const double w_sum = wi + wj;
    if (w_sum <= 0.0) continue;
    Vec xi(x.col(i).data()), xj(x.col(j).data());
    const Vec3 diff = xi - xj;
    const double len = diff.norm();
    if (len <= 1e-12 * stretch_.rest[cu]) continue;  // direction undefined
    const Vec3 n = diff / len;
    const double constraint = len - stretch_.rest[cu];
    const double alpha = stretch_.compliance[cu] * alpha_scale;
    const double dlambda = (-constraint - alpha * stretch_.lambda[cu]) / (w_sum + alpha);
    stretch_.lambda[cu] += dlambda;
    xi += (wi * dlambda) * n;
    xj -= (wj * dlambda) * n;
  }
}

// Wang 2015 eq. 12 with gamma = 1: x^(k+1) = omega_k+1 (x^ - x^(k-1)) + x^(k-1), x^ the positions
// the sweep produced. Applied to the free vertices only (pins follow their bone). The multipliers
// are not extrapolated: the stretch constraints are stiff (alpha~ << w), so lambda hardly enters
// the next sweep's update. Sweep 0 has omega 1 and only shifts x^0 (recorded in cheb_cur_ before
// the sweeps) and x^1 into place.
void XpbdSolver::chebyshev_extrapolate(int sweep, double omega, Eigen::Matrix3Xd& x) {
  const double* w = model_.inv_mass.data();
  const Eigen::Index n = x.cols();
#pragma omp for schedule(static)
  for (Eigen::Index i = 0; i < n; ++i) {
    if (sweep > 0 && w[i] > 0.0)
      x.col(i) = omega * (x.col(i) - cheb_prev_.col(i)) + cheb_prev_.col(i);
    cheb_prev_.col(i) = cheb_cur_.col(i);
    cheb_cur_.col(i) = x.col(i);
  }
}

// Provot 1995 sec. 5 ("deformation rate" limit), as a position projection: an edge longer than
// max_stretch * l0 is shortened to exactly that, split by inverse mass like a PBD distance
// constraint of stiffness 1. Edges within the limit are left alone, so the material's own
// (compliant) response decides everything below it.
// Shortens edge (i, j) to `limit` if it is longer, split by inverse mass; returns whether it did.
// A relative slack of 1e-9 so an edge a previous pass set to the limit does not count again by
// rounding.
// With relax > 1 it is shortened past the limit, never below its rest length `floor`
// (strain_limit_target).
bool shorten_edge(Eigen::Matrix3Xd& x, const double* w, int i, int j, double limit, double floor,
                  double relax) {
  const double wi = w[i], wj = w[j];
  const double w_sum = wi + wj;
  if (w_sum <= 0.0) return false;
  Vec xi(x.col(i).data()), xj(x.col(j).data());
  const Vec3 diff = xi - xj;
  const double len_sq = diff.squaredNorm();
  if (len_sq <= limit * limit * (1.0 + 1e-9)) return false;
  const double len = std::sqrt(len_sq);
  const double target = strain_limit_target(len, limit, floor, relax);
  const Vec3 correction = diff * ((len - target) / (len * w_sum));
  xi -= wi * correction;
  xj += wj * correction;
  return true;
}

void XpbdSolver::limit_strain(int begin, int end, Eigen::Matrix3Xd& x, double max_stretch) {
  const double* w = model_.inv_mass.data();
#pragma omp for schedule(static)
  for (int c = begin; c < end; ++c) {
    const std::size_t cu = static_cast<std::size_t>(c);
    const int i = stretch_.vertices[cu][0], j = stretch_.vertices[cu][1];
    if (!shorten_edge(x, w, i, j, max_stretch * stretch_.rest[cu], stretch_.rest[cu],
                      settings_.strain_limit_relaxation)) {
      continue;
    }
    // Every writer stores the same value: whether a pass corrected anything does not depend on
    // which thread did it.
#pragma omp atomic write
    limit_corrected_ = 1;
    // One colour's constraints share no vertex, and colours are separated by barriers.
    limit_moved_[static_cast<std::size_t>(i)] = 1;
    limit_moved_[static_cast<std::size_t>(j)] = 1;
  }
}

bool XpbdSolver::limit_strain_dirty(Eigen::Matrix3Xd& x, double max_stretch) {
  const double* w = model_.inv_mass.data();
  const std::array<int, 2>* edge = stretch_.vertices.data();
  const double* rest = stretch_.rest.data();
  unsigned char* dirty = edge_dirty_.data();
  bool any = false;
  const std::size_t count = stretch_.vertices.size();
  for (std::size_t c = 0; c < count; ++c) {
    // Most edges are clean in the later passes: skip them eight at a time.
    if ((c & 7) == 0 && c + 8 <= count) {
      std::uint64_t word = 0;
      std::memcpy(&word, dirty + c, sizeof word);
      if (word == 0) {
        c += 7;
        continue;
      }
    }
    if (dirty[c] == 0) continue;
    dirty[c] = 0;
    const int i = edge[c][0], j = edge[c][1];
    if (!shorten_edge(x, w, i, j, max_stretch * rest[c], rest[c],
                      settings_.strain_limit_relaxation))
      continue;
    any = true;
    // Every edge at a moved vertex may now be too long: a later one is seen in this pass, as in
    // a full pass, an earlier one in the next. This edge itself is now at the limit.
    for (int v : {i, j}) {
      touch(v);
      mark_edges_dirty(v);
    }
    dirty[c] = 0;
  }
  return any;
}

bool XpbdSolver::run_strain_limit(Eigen::Matrix3Xd& x, double max_stretch) {
  for (int col = 0; col < stretch_.color_count(); ++col) {
    limit_strain(stretch_.color_begin[static_cast<std::size_t>(col)],
                 stretch_.color_begin[static_cast<std::size_t>(col) + 1], x, max_stretch);
  }
  // After the last colour's implicit barrier every thread reads the same flag; the serial part
  // below resets it before its own implicit barrier ends.
  int corrected = 0;
#pragma omp atomic read
  corrected = limit_corrected_;
#pragma omp barrier
#pragma omp single
  {
    limit_corrected_ = 0;
    for (int v : limit_touched_list_) limit_touched_[static_cast<std::size_t>(v)] = 0;
    limit_touched_list_.clear();
    if (corrected != 0) {
      // The edges a second full pass could find too long: those at a vertex the first moved.
      for (std::size_t v = 0; v < limit_moved_.size(); ++v) {
        if (limit_moved_[v] == 0) continue;
        limit_moved_[v] = 0;
        touch(static_cast<int>(v));
        mark_edges_dirty(static_cast<int>(v));
      }
      bool again = true;
      int pass = 1;
      for (; pass < settings_.strain_limit_iterations && again; ++pass)
        again = limit_strain_dirty(x, max_stretch);
      limit_passes_ += pass;
      if (again) ++limit_capped_;
      std::fill(edge_dirty_.begin(), edge_dirty_.end(), 0);
    } else {
      ++limit_passes_;
    }
  }
  return corrected != 0;
}

// XPBD update with Rayleigh damping (Macklin 2016 eq. 26), for C = theta - theta0 with the
// dihedral-angle gradients:
//   dlambda = (-C - alpha~ lambda - gamma grad C . (x - x^n)) / ((1 + gamma) sum w |grad C|^2 +
//   alpha~), alpha~ = alpha / h^2, gamma = alpha~ beta~ / h with beta~ = h^2 beta_k and beta_k =
//   material.damping * k the constraint's damping stiffness, hence gamma = material.damping / h.
void XpbdSolver::solve_bend(int begin, int end, Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_prev,
                            double alpha_scale, double gamma) {
  const double* w = model_.inv_mass.data();
#pragma omp for schedule(static)
  for (int c = begin; c < end; ++c) {
    const std::size_t cu = static_cast<std::size_t>(c);
    const std::array<int, 4>& v = bend_.vertices[cu];
    const double wv[4] = {w[v[0]], w[v[1]], w[v[2]], w[v[3]]};
    if (wv[0] + wv[1] + wv[2] + wv[3] <= 0.0) continue;
    std::array<Vec3, 4> g;
    double theta = 0.0;
    if (!dihedral_angle(x.col(v[0]), x.col(v[1]), x.col(v[2]), x.col(v[3]), theta, g[0], g[1], g[2],
                        g[3])) {
      continue;
    }
    const double constraint = wrap_angle(theta - bend_.rest[cu]);
    double denom = 0.0, damping = 0.0;
    for (int k = 0; k < 4; ++k) {
      denom += wv[k] * g[static_cast<std::size_t>(k)].squaredNorm();
      damping += g[static_cast<std::size_t>(k)].dot(x.col(v[static_cast<std::size_t>(k)]) -
                                                    x_prev.col(v[static_cast<std::size_t>(k)]));
    }
    const double alpha = bend_.compliance[cu] * alpha_scale;
    const double dlambda = (-constraint - alpha * bend_.lambda[cu] - gamma * damping) /
                           ((1.0 + gamma) * denom + alpha);
    bend_.lambda[cu] += dlambda;
    for (int k = 0; k < 4; ++k)
      x.col(v[static_cast<std::size_t>(k)]) += (wv[k] * dlambda) * g[static_cast<std::size_t>(k)];
  }
}

StepReport XpbdSolver::step(ClothState& state, double dt, const StepInputs& inputs) {
  if (inputs.env == nullptr) throw std::invalid_argument("xpbd: StepInputs::env is required");
  if (!(dt > 0.0)) throw std::invalid_argument("xpbd: dt must be positive");
  const Eigen::Index n = model_.vertex_count();
  if (state.x.cols() != n || state.v.cols() != n) {
    throw std::invalid_argument("xpbd: state has " + std::to_string(state.x.cols()) +
                                " vertices, model has " + std::to_string(n));
  }
  const Eigen::Index kin = static_cast<Eigen::Index>(model_.kinematic.size());
  if (inputs.kinematic_targets.cols() != 0 && inputs.kinematic_targets.cols() != kin) {
    throw std::invalid_argument(
        "xpbd: kinematic_targets has " + std::to_string(inputs.kinematic_targets.cols()) +
        " columns, model has " + std::to_string(kin) + " kinematic vertices");
  }
  const Environment& env = *inputs.env;
  const ClothState saved = state;
  limit_passes_ = 0;
  limit_capped_ = 0;
  const Eigen::Matrix3Xd kin_start = kinematic_positions(model_, state.x);

  const int substeps = settings_.substeps;
  const double h = dt / substeps;
  const double inv_h = 1.0 / h;
  // alpha~ = alpha / h^2 (Macklin 2016 eq. 9) and gamma = damping / h (eq. 26, see solve_bend).
  const double alpha_scale = 1.0 / (h * h);
  const double gamma = model_.material.damping / h;
  const int stretch_sweeps = stretch_iterations();
  const int sweeps = sweeps_ ? std::max(settings_.iterations, stretch_sweeps) : 0;
  const double rho = sweeps_ ? settings_.chebyshev_rho : 0.0;
  if (rho > 0.0 && cheb_cur_.cols() != n) {
    cheb_prev_.resize(3, n);
    cheb_cur_.resize(3, n);
  }
  const double max_stretch = settings_.strain_limit > 0.0 ? 1.0 + settings_.strain_limit : 0.0;
  const Vec3 g = env.gravity;
  if (max_stretch > 0.0 && settings_.strain_limit_contact_rounds > 0) {
    // Copy-assigned into members, whose collider arrays keep their capacity: no allocation per
    // step after the first.
    round_env_ = env;
    round_env_.friction_static = round_env_.friction_kinetic = 0.0;
    surface_env_ = round_env_;
    surface_env_.collision_margin = 0.0;
  }
  // Linear air drag f = -c A_i v_i, integrated implicitly (v = (v + h g) / (1 + h c A_i / m_i)) so
  // that a large drag on a light vertex cannot make the velocity overshoot and grow.
  Eigen::VectorXd drag_factor(n);
  for (Eigen::Index i = 0; i < n; ++i)
    drag_factor[i] = 1.0 / (1.0 + h * env.air_drag * model_.vertex_area[i] * model_.inv_mass[i]);

  Eigen::Matrix3Xd x_prev(3, n);
  const int threads = settings_.threads;
  const double* w = model_.inv_mass.data();
  // The sub-step loop, run by every thread of one parallel region for the whole step: loops over
  // vertices and over each colour are shared out with `omp for` (whose implicit barriers order the
  // phases), and the serial part (pins, multipliers) runs on one thread under `omp single`.
  auto substep_loop = [&]() {
    for (int sub = 0; sub < substeps; ++sub) {
      const double s_start = static_cast<double>(sub) / substeps;
      const double s_end = static_cast<double>(sub + 1) / substeps;
      // Predict (Macklin 2016 alg. 1 lines 3-4): explicit gravity and drag on free vertices.
#pragma omp for schedule(static)
      for (Eigen::Index i = 0; i < n; ++i) {
        x_prev.col(i) = state.x.col(i);
        if (w[i] <= 0.0) continue;
        state.v.col(i) = (state.v.col(i) + h * g) * drag_factor[i];
        state.x.col(i) += h * state.v.col(i);
      }
#pragma omp single
      {
        place_kinematic(model_, kin_start, inputs, s_end, dt, state);
        // Multipliers start at zero every sub-step (alg. 1 line 5).
        std::fill(stretch_.lambda.begin(), stretch_.lambda.end(), 0.0);
        std::fill(bend_.lambda.begin(), bend_.lambda.end(), 0.0);
      }
      // Gauss-Seidel over colours, each colour's constraints in parallel (they share no vertex).
      // Bending first and stretch last in each sweep, so the positions a sub-step ends with are
      // those of a stretch projection; stretch may have more sweeps than bending.
      // Chebyshev weights (Wang 2015 eq. 12): omega_1 = 1, omega_2 = 2 / (2 - rho^2),
      // omega_k+1 = 4 / (4 - rho^2 omega_k). Every thread computes the same sequence.
      double omega = 1.0;
      if (rho > 0.0) {
#pragma omp for schedule(static)
        for (Eigen::Index i = 0; i < n; ++i) cheb_cur_.col(i) = state.x.col(i);
      }
      for (int it = 0; it < sweeps; ++it) {
        if (it < settings_.iterations) {
          for (int col = 0; col < bend_.color_count(); ++col) {
            solve_bend(bend_.color_begin[static_cast<std::size_t>(col)],
                       bend_.color_begin[static_cast<std::size_t>(col) + 1], state.x, x_prev,
                       alpha_scale, gamma);
          }
        }
        if (it < stretch_sweeps) {
          for (int col = 0; col < stretch_.color_count(); ++col) {
            solve_stretch(stretch_.color_begin[static_cast<std::size_t>(col)],
                          stretch_.color_begin[static_cast<std::size_t>(col) + 1], state.x,
                          alpha_scale);
          }
          if (rho > 0.0) {
            omega = it == 0   ? 1.0
                    : it == 1 ? 2.0 / (2.0 - rho * rho)
                              : 4.0 / (4.0 - rho * rho * omega);
            chebyshev_extrapolate(it, omega, state.x);
          }
        }
      }
      // Long-range attachments: pull a vertex back onto the sphere of its rest path around its
      // pin (unilateral: a vertex nearer than that is free).
#pragma omp for schedule(static)
      for (std::size_t t = 0; t < tether_vertex_.size(); ++t) {
        const int i = tether_vertex_[t];
        const Vec3 d = state.x.col(i) - state.x.col(tether_anchor_[t]);
        const double len = d.norm();
        if (len > tether_length_[t])
          state.x.col(i) = state.x.col(tether_anchor_[t]) + d * (tether_length_[t] / len);
      }
      // Strain limit (Provot 1995), after the tethers and before collisions, so contacts have the
      // last word on where a vertex is.
      // strain_limit_iterations is a cap: the passes stop after one that corrected no edge.
      if (max_stretch > 0.0) {
        // Contacts first, so the limit works on where the body puts the cloth; the collision pass
        // below then moves only the few vertices the limit pulled back into a collider, instead
        // of stretching every edge the body pushes on after the limit (the hem on a leg).
#pragma omp for schedule(static)
        for (Eigen::Index i = 0; i < n; ++i)
          resolve_vertex_collisions(state.x, x_prev, model_.inv_mass, i, env, s_end, s_start);
        run_strain_limit(state.x, max_stretch);
      }
      // Colliders at this sub-step's pose; friction measured against the surface's own motion
      // over the sub-step. Each vertex is resolved on its own, so the vertices are shared out.
#pragma omp for schedule(static)
      for (Eigen::Index i = 0; i < n; ++i)
        resolve_vertex_collisions(state.x, x_prev, model_.inv_mass, i, env, s_end, s_start);
      // Self-collision after the body's collision pass: cloth pressed between the body and another
      // layer is pushed apart last, so a layer the body moved cannot end the sub-step through the
      // one over it (which would then be taken as its side at the next sub-step). It may push the
      // inner layer into the body, at most kBodyGive thicknesses deep. Serial and in list order:
      // the same result for any thread count (self_collision.hpp).
      if (self_.thickness > 0.0) {
#pragma omp single
        {
          // The contacts may not push a vertex deep into the body (self_collision.hpp, kBodyGive):
          // the nearest surface of each vertex they move, found when they first move it.
          self_.body = &env;
          self_.body_pose = s_end;
          std::fill(self_.body_room.begin(), self_.body_room.end(), NAN);
          refresh_self_collision(self_, model_, state.x, x_prev);
          // Up to three Gauss-Seidel passes, until one projects no contact: a single pass left
          // crossings that the next sub-steps then kept (each pair's side is taken at the
          // sub-step's start), docs/notebook/self_collision.md, "Third round". More while the
          // body's room cuts contact moves short (self_collision.hpp, kContactPassesAtBody).
          const long cuts = self_.body_cuts;
          for (int pass = 0; pass < kContactPassesAtBody; ++pass) {
            if (pass >= kContactPasses && self_.body_cuts == cuts) break;
            if (project_self_collision(self_, model_, state.x, x_prev) == 0) break;
          }
          // A step run again to undo crossings: their ends held to their sides (below).
          if (!self_.untangle.empty()) project_untangle(self_, model_, state.x);
        }
      }
      // Contact rounds (docs/notebook/BENCHMARKS.md, "Contact rounds"): the collision pass above
      // pushed the cloth out of the body and so stretched the edges the body holds (the hem on a
      // thigh lifted into it: 11.7 % on the demo skirt with the limit at 2.5 %). Each round applies
      // the strain limit again; between rounds a frictionless projection puts the vertices the
      // limit moved back at the margin, so a held ring slides along the body to where it fits
      // (Gauss-Seidel on both sets of constraints). Friction is left to the pass above: it measures
      // slip over the whole sub-step, and repeating it would pin each vertex back where the
      // sub-step started. The last round is followed by a projection onto the body's surface rather
      // than the margin, so the strain bound has the last word at the cost of a vertex pulled into
      // the collision margin (4 mm on the bundled garments), never into the body.
      for (int round = 0; max_stretch > 0.0 && round < settings_.strain_limit_contact_rounds;
           ++round) {
        if (!run_strain_limit(state.x, max_stretch)) break;
        // Only the vertices the limit moved can have left the collision margin. After the last
        // round they are only kept out of the body itself (margin 0): within the margin the
        // limit keeps its word, but a limb that moved far in one sub-step cannot have cloth
        // pulled into it.
        const bool last = round + 1 == settings_.strain_limit_contact_rounds;
        const int touched = static_cast<int>(limit_touched_list_.size());
#pragma omp for schedule(static)
        for (int k = 0; k < touched; ++k)
          resolve_vertex_collisions(state.x, x_prev, model_.inv_mass,
                                    limit_touched_list_[static_cast<std::size_t>(k)],
                                    last ? surface_env_ : round_env_, s_end, s_start);
      }
      // Velocity update (alg. 1 line 16). Kinematic vertices keep place_kinematic's velocity.
#pragma omp for schedule(static)
      for (Eigen::Index i = 0; i < n; ++i) {
        if (w[i] <= 0.0) continue;
        state.v.col(i) = (state.x.col(i) - x_prev.col(i)) * inv_h;
      }
    }
  };
  // Single-threaded and outside any parallel region, the `omp for`/`omp single` constructs run
  // inline with no barriers (a team of one would still pay a futex system call per barrier). Inside
  // a caller's parallel region they would bind to the caller's team, so open our own team then.
  // A step that ends with the cloth through itself is run again from its start with the crossings'
  // ends held to their sides, up to kUntangleRedos times (self_collision.hpp, plan_untangle): the
  // contacts alone keep a crossing once it forms.
  self_.untangle.clear();
  for (int redo = 0;; ++redo) {
    if (threads > 1 || omp_in_parallel()) {
#pragma omp parallel num_threads(threads)
      substep_loop();
    } else {
      substep_loop();
    }
    if (!(self_.thickness > 0.0) || redo == kUntangleRedos ||
        plan_untangle(self_, model_, state.x, saved.x) == 0)
      break;
    state = saved;
    self_.built_at.resize(3, 0);  // rebuild: the motion bounds do not cover the step's start
  }
  self_.body = nullptr;  // the step's colliders, not to be read after it

  StepReport report;
  report.iterations = substeps * sweeps;
  report.strain_limit_passes = limit_passes_;
  report.strain_limit_capped = limit_capped_;
  if (!state_is_sane(state)) {
    state = saved;
    report.stable = false;
    report.message =
        "xpbd: the step produced non-finite or runaway velocities (over 200 m/s) with " +
        describe() + " at dt=" + std::to_string(dt) + " s; try more substeps or a smaller dt";
  }
  return report;
}

}  // namespace

std::unique_ptr<Solver> make_xpbd_solver(const ClothModel& model, const SolverSettings& s) {
  return std::make_unique<XpbdSolver>(model, s);
}

std::unique_ptr<Solver> make_xpbd_projection_solver(const ClothModel& model,
                                                    const SolverSettings& s) {
  return std::make_unique<XpbdSolver>(model, s, false);
}

}  // namespace clothdb
