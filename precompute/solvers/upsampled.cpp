#include "solvers/upsampled.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "cloth/closest_point.hpp"
#include "cloth/self_intersection.hpp"
#include "solvers/strain_limit.hpp"

namespace clothdb {

BarycentricEmbedding embed_in_mesh(const Eigen::Matrix3Xd& points, const ClothMesh& mesh) {
  if (mesh.triangles.empty()) throw std::invalid_argument("embed_in_mesh: the mesh has no faces");
  const Eigen::Matrix3Xd& r = mesh.rest;
  // Triangles bucketed by their boxes in a grid of cells of the longest edge's size; a point's
  // nearest triangle is searched in the cells within `reach` of it, then everywhere if none is.
  double cell = 0.0;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) cell = std::max(cell, (r.col(t[k]) - r.col(t[(k + 1) % 3])).norm());
  if (!(cell > 0.0)) throw std::invalid_argument("embed_in_mesh: degenerate mesh");
  const Vec3 origin = r.rowwise().minCoeff();
  auto key = [&](const Vec3& p) {
    const Vec3 q = p - origin;
    return std::array<long, 3>{grid_cell_index(q.x(), cell), grid_cell_index(q.y(), cell),
                               grid_cell_index(q.z(), cell)};
  };
  auto hash = [](const std::array<long, 3>& k) { return grid_cell_hash(k[0], k[1], k[2]); };
  std::unordered_map<std::uint64_t, std::vector<int>> grid;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    Vec3 lo = r.col(tri[0]), hi = lo;
    for (int k = 1; k < 3; ++k) {
      lo = lo.cwiseMin(Vec3(r.col(tri[k])));
      hi = hi.cwiseMax(Vec3(r.col(tri[k])));
    }
    const auto a = key(lo), b = key(hi);
    for (long i = a[0]; i <= b[0]; ++i)
      for (long j = a[1]; j <= b[1]; ++j)
        for (long k = a[2]; k <= b[2]; ++k) grid[hash({i, j, k})].push_back(static_cast<int>(t));
  }
  BarycentricEmbedding e;
  e.vertex.resize(static_cast<std::size_t>(points.cols()));
  e.weight.resize(static_cast<std::size_t>(points.cols()));
  std::vector<int> candidates;
  for (Eigen::Index i = 0; i < points.cols(); ++i) {
    const Vec3 p = points.col(i);
    candidates.clear();
    const auto c = key(p);
    for (long di = -1; di <= 1; ++di)
      for (long dj = -1; dj <= 1; ++dj)
        for (long dk = -1; dk <= 1; ++dk) {
          const auto it = grid.find(hash({c[0] + di, c[1] + dj, c[2] + dk}));
          if (it != grid.end())
            candidates.insert(candidates.end(), it->second.begin(), it->second.end());
        }
    // Sorted so that ties go to the lower triangle index whatever the grid's order.
    std::sort(candidates.begin(), candidates.end());
    candidates.erase(std::unique(candidates.begin(), candidates.end()), candidates.end());
    double best = std::numeric_limits<double>::infinity();
    auto consider = [&](int t) {
      const auto& tri = mesh.triangles[static_cast<std::size_t>(t)];
      const std::array<double, 3> w =
          closest_on_triangle(p, r.col(tri[0]), r.col(tri[1]), r.col(tri[2])).weight;
      const Vec3 q = w[0] * r.col(tri[0]) + w[1] * r.col(tri[1]) + w[2] * r.col(tri[2]);
      const double d = (q - p).squaredNorm();
      if (d < best) {
        best = d;
        e.vertex[static_cast<std::size_t>(i)] = tri;
        e.weight[static_cast<std::size_t>(i)] = w;
      }
    };
    for (int t : candidates) consider(t);
    // Within one cell of a triangle's box means within one cell of the triangle: a point farther
    // than that from every candidate may have a nearer triangle elsewhere.
    if (!(best <= cell * cell))
      for (std::size_t t = 0; t < mesh.triangles.size(); ++t) consider(static_cast<int>(t));
    // A point at a vertex: that vertex alone, so that interpolation reproduces it to the bit.
    auto& w = e.weight[static_cast<std::size_t>(i)];
    auto& v = e.vertex[static_cast<std::size_t>(i)];
    for (int k = 0; k < 3; ++k)
      if (r.col(v[k]) == points.col(i)) {
        v = {v[k], v[k], v[k]};
        w = {1.0, 0.0, 0.0};
        break;
      }
  }
  return e;
}

void interpolate(const BarycentricEmbedding& e, const Eigen::Matrix3Xd& from,
                 Eigen::Matrix3Xd& to) {
  to.resize(3, e.size());
  for (int i = 0; i < e.size(); ++i) {
    const auto& v = e.vertex[static_cast<std::size_t>(i)];
    const auto& w = e.weight[static_cast<std::size_t>(i)];
    if (w[0] == 1.0) {
      to.col(i) = from.col(v[0]);
    } else {
      to.col(i) = w[0] * from.col(v[0]) + w[1] * from.col(v[1]) + w[2] * from.col(v[2]);
    }
  }
}

// Gauss-Seidel rounds of the coarse projection: each round visits the fine constraints at a coarse
// vertex the previous round moved. It projects a fine edge only when it is more than kCoarseSlack
// (relative) over the strain limit and leaves the last half percent to the fine passes, whose
// work it is (local): on the 12k skirt driven by 3k over frames 1-129 of 01_01 (16 rounds), 604
// edge projections and 2.3 CPU ms a frame instead of 9,870 and 6.2 ms with no slack, the same
// largest strain to 0.02 %. 8 rounds left more over the coarse skirt's own strain after 4 fine
// passes than the test allows (0.63 %), 32 rounds 0.40 % (docs/notebook/resolution.md, "Tenth
// round").
constexpr int kCoarseRounds = 32;
constexpr double kCoarseSlack = 0.005;

FinePass::FinePass(const ClothModel& fine, const ClothModel& coarse, const SolverSettings& settings)
    : fine_(fine), coarse_(coarse), settings_(settings) {
  prolong_ = embed_in_mesh(fine_.mesh.rest, coarse_.mesh);
  SolverSettings f = settings_;
  f.substeps = 1;
  f.chebyshev_rho = 0.0;
  f.coarse_vertices = 0;
  // No tethers: their rest paths along the fine mesh are shorter than along the coarse one, whose
  // tethers the coarse solution obeys, so the fine ones pulled interpolated vertices in and
  // stretched the edges beside them (with them the test below left 6.1 % at 12k and 8.3 % at 30k
  // after one fine pass, without 4.2 % at both: tests/test_upsampled.cpp, FinePassConverges...).
  // The coarse solve's tethers carry the long-range bound.
  f.tethers = false;
  projection_ = make_xpbd_projection_solver(fine_, f);
  edges_.reserve(fine_.mesh.edges.size());
  for (const auto& edge : fine_.mesh.edges) {
    EdgeOnCoarse on;
    for (int end = 0; end < 2; ++end) {
      const std::size_t fv = static_cast<std::size_t>(edge[static_cast<std::size_t>(end)]);
      for (std::size_t k = 0; k < 3; ++k) {
        const double w = (end == 0 ? 1.0 : -1.0) * prolong_.weight[fv][k];
        if (w == 0.0) continue;
        const int c = prolong_.vertex[fv][k];
        int q = 0;
        while (q < on.count && on.vertex[static_cast<std::size_t>(q)] != c) ++q;
        if (q == on.count) {
          on.vertex[static_cast<std::size_t>(q)] = c;
          ++on.count;
        }
        on.weight[static_cast<std::size_t>(q)] += w;
      }
    }
    edges_.push_back(on);
  }
  moved_.assign(static_cast<std::size_t>(coarse_.vertex_count()), 0);
  moved_next_ = moved_;
  point_.resize(3, 1);
  point_mass_ = Eigen::VectorXd::Ones(1);
}

FinePass::~FinePass() = default;

// The fine constraints projected onto the coarse positions y (Gauss-Seidel, serial, in index
// order: the same for any thread count). A constraint on the embedded point p = sum_k w_k y_k
// (or on an embedded edge d = sum_k c_k y_k) is projected as a PBD constraint of the coarse
// vertices with gradient w_k n on vertex k and generalized inverse mass sum_k w_k^2 invm_k
// (Mueller et al. 2007, "Position based dynamics", sec. 3.3, the projection weighted by inverse
// mass; Macklin et al. 2016, eq. 18 with alpha = 0): the coarse vertices move as little as mass
// allows for the fine point or edge to meet its bound. Edges: the strain limit with the block's
// relaxation (xpbd.cpp, shorten_edge). Points: out of the body's surface (no margin: the coarse
// solve's contact round leaves its own vertices anywhere between the surface and the margin, and
// pushing the fine ones out to the margin stretched the hem where the body holds it: 6.2 % at 12k
// and 5.4 % at 30k left after 16 fine passes in tests/test_upsampled.cpp's FinePassConverges...,
// against 3.9 % and 3.7 %).
void FinePass::project_on_coarse(Eigen::Matrix3Xd& y, const Environment& env) {
  const double* w = coarse_.inv_mass.data();
  const double max_stretch = 1.0 + settings_.strain_limit;
  const double relax = settings_.strain_limit_relaxation;
  std::fill(moved_.begin(), moved_.end(), 1);
  for (int round = 0; round < kCoarseRounds; ++round) {
    std::fill(moved_next_.begin(), moved_next_.end(), 0);
    bool any = false;
    for (int i = 0; i < fine_.vertex_count(); ++i) {
      if (fine_.inv_mass[i] <= 0.0) continue;
      const auto& v = prolong_.vertex[static_cast<std::size_t>(i)];
      const auto& wt = prolong_.weight[static_cast<std::size_t>(i)];
      if (!moved_[static_cast<std::size_t>(v[0])] && !moved_[static_cast<std::size_t>(v[1])] &&
          !moved_[static_cast<std::size_t>(v[2])])
        continue;
      point_.col(0) = wt[0] * y.col(v[0]) + wt[1] * y.col(v[1]) + wt[2] * y.col(v[2]);
      const Vec3 before = point_.col(0);
      if (!resolve_vertex_collisions(point_, point_, point_mass_, 0, env, 1.0)) continue;
      double mass = 0.0;
      for (std::size_t k = 0; k < 3; ++k) mass += wt[k] * wt[k] * w[v[k]];
      if (!(mass > 0.0)) continue;
      const Vec3 d = (point_.col(0) - before) / mass;
      for (std::size_t k = 0; k < 3; ++k) {
        if (!(w[v[k]] * wt[k] > 0.0)) continue;
        y.col(v[k]) += (w[v[k]] * wt[k]) * d;
        moved_next_[static_cast<std::size_t>(v[k])] = 1;
      }
      any = true;
    }
    for (std::size_t e = 0; e < edges_.size(); ++e) {
      const EdgeOnCoarse& on = edges_[e];
      bool touched = false;
      for (int q = 0; q < on.count; ++q)
        touched |= moved_[static_cast<std::size_t>(on.vertex[static_cast<std::size_t>(q)])] != 0;
      if (!touched) continue;
      Vec3 d = Vec3::Zero();
      for (int q = 0; q < on.count; ++q)
        d += on.weight[static_cast<std::size_t>(q)] * y.col(on.vertex[static_cast<std::size_t>(q)]);
      const double rest = fine_.edge_rest_length[e];
      const double limit = max_stretch * rest;
      const double trigger = limit * (1.0 + kCoarseSlack);
      const double len_sq = d.squaredNorm();
      if (len_sq <= trigger * trigger) continue;
      double mass = 0.0;
      for (int q = 0; q < on.count; ++q) {
        const double c = on.weight[static_cast<std::size_t>(q)];
        mass += c * c * w[on.vertex[static_cast<std::size_t>(q)]];
      }
      if (!(mass > 0.0)) continue;
      const double len = std::sqrt(len_sq);
      const double target = strain_limit_target(len, limit, rest, relax);
      const Vec3 correction = d * ((len - target) / (len * mass));
      for (int q = 0; q < on.count; ++q) {
        const int c = on.vertex[static_cast<std::size_t>(q)];
        const double step = w[c] * on.weight[static_cast<std::size_t>(q)];
        if (step == 0.0) continue;
        y.col(c) -= step * correction;
        moved_next_[static_cast<std::size_t>(c)] = 1;
      }
      any = true;
    }
    if (!any) break;
    moved_.swap(moved_next_);
  }
}

StepReport FinePass::run(const Eigen::Matrix3Xd& coarse_x, const Environment& env,
                         const Eigen::Matrix3Xd& fine_targets, double dt,
                         Eigen::Matrix3Xd& fine_x) {
  // The fine pass is a projection at the end pose: no velocity, gravity or drag, the colliders
  // still and frictionless (the coarse step had the friction), and no margin (above).
  // Members reused every step, so the pass allocates nothing after the first.
  Environment& still = still_;
  still = env;
  still.gravity = Vec3::Zero();
  still.air_drag = 0.0;
  still.friction_static = still.friction_kinetic = 0.0;
  still.collision_margin = 0.0;
  still.collider_motion = ColliderMotion::Interpolated;
  for (auto& c : still.capsules) {
    c.a_start = c.a;
    c.b_start = c.b;
  }
  for (auto& c : still.spheres) c.center_start = c.center;
  y_ = coarse_x;
  project_on_coarse(y_, still);
  interpolate(prolong_, y_, state_.x);
  state_.v.setZero(3, state_.x.cols());
  inputs_.env = &still;
  inputs_.kinematic_targets = fine_targets;
  const StepReport report = projection_->step(state_, dt, inputs_);
  fine_x = state_.x;
  return report;
}

namespace {

class UpsampledSolver final : public Solver {
 public:
  UpsampledSolver(const ClothModel& fine, const ClothModel& coarse, const SolverSettings& settings)
      : fine_(fine), coarse_(coarse), settings_(settings) {
    coarse_solver_ = make_xpbd_solver(coarse_, settings_);
    fine_pass_ = std::make_unique<FinePass>(fine_, coarse_, settings_);
    restrict_ = embed_in_mesh(coarse_.mesh.rest, fine_.mesh);
    // The coarse pins follow the fine ones: each as its embedding's fine pins, reweighted.
    std::vector<int> fine_kin_index(static_cast<std::size_t>(fine_.vertex_count()), -1);
    for (std::size_t k = 0; k < fine_.kinematic.size(); ++k)
      fine_kin_index[static_cast<std::size_t>(fine_.kinematic[k])] = static_cast<int>(k);
    for (int c : coarse_.kinematic) {
      const auto& v = restrict_.vertex[static_cast<std::size_t>(c)];
      const auto& w = restrict_.weight[static_cast<std::size_t>(c)];
      std::array<int, 3> kv{};
      std::array<double, 3> kw{};
      double sum = 0.0;
      for (int k = 0; k < 3; ++k) {
        const int index = fine_kin_index[static_cast<std::size_t>(v[k])];
        kv[static_cast<std::size_t>(k)] = std::max(index, 0);
        kw[static_cast<std::size_t>(k)] = index >= 0 ? w[static_cast<std::size_t>(k)] : 0.0;
        sum += kw[static_cast<std::size_t>(k)];
      }
      if (!(sum > 0.0))
        throw std::invalid_argument("upsampled solver: coarse pin " + std::to_string(c) +
                                    " is not on a fine triangle with a fine pin");
      for (double& x : kw) x /= sum;
      pin_map_.vertex.push_back(kv);
      pin_map_.weight.push_back(kw);
    }
  }

  StepReport step(ClothState& state, double dt, const StepInputs& inputs) override {
    if (inputs.env == nullptr)
      throw std::invalid_argument("upsampled: StepInputs::env is required");
    // The coarse state is the solver's own; it is taken from the fine state whenever that is not
    // what this solver left (a new run, or velocities set by the caller, e.g. settling's end).
    if (!have_coarse_ || state.x.cols() != last_x_.cols() || state.x != last_x_) {
      interpolate(restrict_, state.x, coarse_state_.x);
      have_coarse_ = true;
    }
    if (coarse_state_.v.cols() != coarse_state_.x.cols() || state.v.cols() != last_v_.cols() ||
        state.v != last_v_)
      interpolate(restrict_, state.v, coarse_state_.v);
    coarse_inputs_.env = inputs.env;
    if (inputs.kinematic_targets.cols() > 0)
      interpolate(pin_map_, inputs.kinematic_targets, coarse_inputs_.kinematic_targets);
    else
      coarse_inputs_.kinematic_targets.resize(3, 0);
    StepReport report = coarse_solver_->step(coarse_state_, dt, coarse_inputs_);
    if (!report.stable) return report;
    // The fine pass (FinePass): it starts from the coarse solution every step and keeps no
    // state, so the fine garment cannot drift from the coarse one.
    const StepReport f =
        fine_pass_->run(coarse_state_.x, *inputs.env, inputs.kinematic_targets, dt, fine_x_);
    if (!f.stable) {
      // The caller keeps its state: the coarse one is taken from it again at the next step.
      have_coarse_ = false;
      return f;
    }
    report.strain_limit_passes += f.strain_limit_passes;
    report.strain_limit_capped += f.strain_limit_capped;
    state.v = (fine_x_ - state.x) / dt;
    state.x = fine_x_;
    last_x_ = state.x;
    last_v_ = state.v;
    return report;
  }

  std::string describe() const override {
    return "upsampled coarse=" + std::to_string(coarse_.vertex_count()) + " " +
           coarse_solver_->describe();
  }

 private:
  const ClothModel fine_, coarse_;
  SolverSettings settings_;
  std::unique_ptr<Solver> coarse_solver_;
  std::unique_ptr<FinePass> fine_pass_;
  BarycentricEmbedding restrict_, pin_map_;
  ClothState coarse_state_;
  StepInputs coarse_inputs_;  // reused every step: no allocation after the first
  Eigen::Matrix3Xd fine_x_;   // kept between steps: no allocation per step
  bool have_coarse_ = false;
  Eigen::Matrix3Xd last_x_, last_v_;
};

}  // namespace

std::unique_ptr<Solver> make_upsampled_solver(const ClothModel& fine, const ClothModel& coarse,
                                              const SolverSettings& settings) {
  return std::make_unique<UpsampledSolver>(fine, coarse, settings);
}

}  // namespace clothdb
