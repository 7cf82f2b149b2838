// What every solver shares: names, state checks, kinematic pins and the diagnostics.
#include <cmath>
#include <limits>
#include <stdexcept>

#include "solvers/solver.hpp"

namespace clothdb {

ClothState rest_state(const ClothModel& model) {
  ClothState s;
  s.x = model.mesh.rest;
  s.v = Eigen::Matrix3Xd::Zero(3, model.vertex_count());
  return s;
}

bool state_is_sane(const ClothState& state, double max_speed) {
  if (!state.x.allFinite() || !state.v.allFinite()) return false;
  const double max_speed2 = max_speed * max_speed;
  for (Eigen::Index i = 0; i < state.v.cols(); ++i)
    if (state.v.col(i).squaredNorm() > max_speed2) return false;
  return true;
}

void place_kinematic(const ClothModel& model, const Eigen::Matrix3Xd& start,
                     const StepInputs& inputs, double s, double dt, ClothState& state) {
  const bool moving =
      inputs.kinematic_targets.cols() == static_cast<Eigen::Index>(model.kinematic.size());
  for (size_t k = 0; k < model.kinematic.size(); ++k) {
    const int i = model.kinematic[k];
    const Eigen::Index kk = static_cast<Eigen::Index>(k);
    if (moving) {
      state.x.col(i) = start.col(kk) + s * (inputs.kinematic_targets.col(kk) - start.col(kk));
      state.v.col(i) = (inputs.kinematic_targets.col(kk) - start.col(kk)) / dt;
    } else {
      state.x.col(i) = start.col(kk);
      state.v.col(i).setZero();
    }
  }
}

Eigen::Matrix3Xd kinematic_positions(const ClothModel& model, const Eigen::Matrix3Xd& x) {
  Eigen::Matrix3Xd out(3, static_cast<Eigen::Index>(model.kinematic.size()));
  for (size_t k = 0; k < model.kinematic.size(); ++k)
    out.col(static_cast<Eigen::Index>(k)) = x.col(model.kinematic[k]);
  return out;
}

double max_edge_strain(const ClothModel& model, const Eigen::Matrix3Xd& x) {
  double worst = 0.0;
  const auto& edges = model.mesh.edges;
  for (size_t e = 0; e < edges.size(); ++e) {
    const double l0 = model.edge_rest_length[e];
    if (l0 <= 0.0) continue;
    const double l = (x.col(edges[e][0]) - x.col(edges[e][1])).norm();
    worst = std::max(worst, (l - l0) / l0);
  }
  return worst;
}

EdgeStrainMax append_edge_strains(const ClothModel& model, const Eigen::Matrix3Xd& x,
                                  std::vector<double>& out) {
  const auto& edges = model.mesh.edges;
  EdgeStrainMax worst{-std::numeric_limits<double>::infinity(), edges.size()};
  for (size_t e = 0; e < edges.size(); ++e) {
    const double l0 = model.edge_rest_length[e];
    if (l0 <= 0.0) continue;
    const double strain = ((x.col(edges[e][0]) - x.col(edges[e][1])).norm() - l0) / l0;
    out.push_back(strain);
    if (strain > worst.strain) worst = {strain, e};
  }
  return worst;
}

double kinetic_energy(const ClothModel& model, const Eigen::Matrix3Xd& v) {
  double e = 0.0;
  for (Eigen::Index i = 0; i < v.cols(); ++i)
    if (model.inv_mass[i] > 0.0) e += 0.5 * model.mass[i] * v.col(i).squaredNorm();
  return e;
}

double gravity_potential(const ClothModel& model, const Eigen::Matrix3Xd& x, const Vec3& g) {
  double e = 0.0;
  for (Eigen::Index i = 0; i < x.cols(); ++i)
    if (model.inv_mass[i] > 0.0) e -= model.mass[i] * g.dot(x.col(i));
  return e;
}

}  // namespace clothdb
