#include "solvers/upsampled.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "cloth/closest_point.hpp"
#include "cloth/self_intersection.hpp"

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

namespace {

class UpsampledSolver final : public Solver {
 public:
  UpsampledSolver(const ClothModel& fine, const ClothModel& coarse, const SolverSettings& settings)
      : fine_(fine), coarse_(coarse), settings_(settings) {
    coarse_solver_ = make_xpbd_solver(coarse_, settings_);
    SolverSettings f = settings_;
    f.substeps = 1;
    f.chebyshev_rho = 0.0;
    f.coarse_vertices = 0;
    fine_solver_ = make_xpbd_projection_solver(fine_, f);
    prolong_ = embed_in_mesh(fine_.mesh.rest, coarse_.mesh);
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
    StepInputs coarse_inputs;
    coarse_inputs.env = inputs.env;
    if (inputs.kinematic_targets.cols() > 0)
      interpolate(pin_map_, inputs.kinematic_targets, coarse_inputs.kinematic_targets);
    StepReport report = coarse_solver_->step(coarse_state_, dt, coarse_inputs);
    if (!report.stable) return report;
    // The fine pass: from the interpolated coarse solution, at rest (no velocity, no gravity, no
    // drag), so that it only projects: the tethers, the strain limit and its contact rounds, the
    // body (still at the end pose, frictionless: the coarse step had the friction) and
    // self-collision. It starts from the interpolation every step and keeps no state, so the fine
    // garment cannot drift from the coarse one.
    ClothState& fine = fine_state_;  // kept between steps: no allocation per step
    interpolate(prolong_, coarse_state_.x, fine.x);
    fine.v.setZero(3, fine.x.cols());
    Environment env = *inputs.env;
    env.gravity = Vec3::Zero();
    env.air_drag = 0.0;
    env.friction_static = env.friction_kinetic = 0.0;
    for (auto& c : env.capsules) {
      c.a_start = c.a;
      c.b_start = c.b;
    }
    StepInputs fine_inputs;
    fine_inputs.env = &env;
    fine_inputs.kinematic_targets = inputs.kinematic_targets;
    const StepReport f = fine_solver_->step(fine, dt, fine_inputs);
    if (!f.stable) {
      // The caller keeps its state: the coarse one is taken from it again at the next step.
      have_coarse_ = false;
      return f;
    }
    report.strain_limit_passes += f.strain_limit_passes;
    report.strain_limit_capped += f.strain_limit_capped;
    state.v = (fine.x - state.x) / dt;
    state.x = fine.x;
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
  std::unique_ptr<Solver> coarse_solver_, fine_solver_;
  BarycentricEmbedding prolong_, restrict_, pin_map_;
  ClothState coarse_state_, fine_state_;
  bool have_coarse_ = false;
  Eigen::Matrix3Xd last_x_, last_v_;
};

}  // namespace

std::unique_ptr<Solver> make_upsampled_solver(const ClothModel& fine, const ClothModel& coarse,
                                              const SolverSettings& settings) {
  return std::make_unique<UpsampledSolver>(fine, coarse, settings);
}

}  // namespace clothdb
