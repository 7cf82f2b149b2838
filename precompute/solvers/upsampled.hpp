// A coarse garment's XPBD solve driving a fine copy of it (Kavan, Gerszewski, Bargteil & Sloan
// 2011, "Physics-inspired upsampling for cloth simulation in games"): the fine mesh embedded
// barycentrically in the coarse rest mesh, each step the coarse solution projected onto the fine
// garment's constraints at the coarse scale and interpolated to the fine vertices, then one fixed
// pass of the fine strain limit and collisions (FinePass), which add no motion of their own: each
// step starts again from the coarse solution, so the fine garment's low frequencies are the coarse
// solution's by construction (the role of Kavan et al.'s tracking constraints). Bending and
// stretch sweeps on the fine mesh were measured and left out: from an interpolated state with
// in-plane compression they stretched edges to 12-24 %. The fine pass's strain-limit passes
// converge at the same rate at 12k and 30k vertices (tests/test_upsampled.cpp).
// docs/notebook/resolution.md, "Ninth round" and "Tenth round".
#pragma once

#include <array>
#include <memory>
#include <vector>

#include "solvers/solver.hpp"

namespace clothdb {

// Each point as a convex combination of the three vertices of its nearest triangle of a mesh.
struct BarycentricEmbedding {
  std::vector<std::array<int, 3>> vertex;
  std::vector<std::array<double, 3>> weight;
  int size() const { return static_cast<int>(vertex.size()); }
};

// Embeds `points` in `mesh`'s rest surface: the nearest point of the nearest triangle (ties: the
// lower triangle index). A point at a mesh vertex gets that vertex with weight exactly 1, so a mesh
// embedded in itself interpolates positions exactly.
BarycentricEmbedding embed_in_mesh(const Eigen::Matrix3Xd& points, const ClothMesh& mesh);

// to.col(i) = sum_k weight[i][k] from.col(vertex[i][k]); `to` is resized.
void interpolate(const BarycentricEmbedding& e, const Eigen::Matrix3Xd& from, Eigen::Matrix3Xd& to);

// The fine pass of a coarse-driven garment: fine positions from the coarse solve's. Two levels
// (docs/notebook/resolution.md, "Tenth round"): the fine garment's own constraints (each fine
// edge's strain limit, each fine vertex kept out of the body) are first projected onto the coarse
// vertices through the embedding, so that the interpolated fine surface already meets them at the
// coarse scale; then the fine projection (make_xpbd_projection_solver: strain limit, contact
// round, body, self-collision) removes what the coarse vertices cannot carry. Its passes then
// converge at a rate that does not depend on the fine resolution.
class FinePass {
 public:
  // `fine` and `coarse` must outlive the pass. `settings` as for make_upsampled_solver: the fine
  // projection runs the block's strain limit, strain_limit_iterations passes, relaxation, contact
  // rounds, self-collision and threads, without tethers (FinePass::FinePass says why).
  FinePass(const ClothModel& fine, const ClothModel& coarse, const SolverSettings& settings);
  ~FinePass();
  FinePass(const FinePass&) = delete;
  FinePass& operator=(const FinePass&) = delete;
  // `coarse_x`: the coarse garment's positions at the step's end; `env` its colliders (taken at
  // their end pose, frictionless, with no margin: project_on_coarse says why); `fine_targets`:
  // the fine pins' targets. Writes `fine_x`.
  // Returns the fine projection's report (stable false: fine_x is not to be used).
  StepReport run(const Eigen::Matrix3Xd& coarse_x, const Environment& env,
                 const Eigen::Matrix3Xd& fine_targets, double dt, Eigen::Matrix3Xd& fine_x);

 private:
  // Each fine edge's vector as a combination of at most six coarse vertices (the difference of
  // its ends' weights).
  struct EdgeOnCoarse {
    std::array<int, 6> vertex{};
    std::array<double, 6> weight{};
    int count = 0;
  };
  void project_on_coarse(Eigen::Matrix3Xd& y, const Environment& env);
  const ClothModel& fine_;
  const ClothModel& coarse_;
  SolverSettings settings_;
  BarycentricEmbedding prolong_;
  std::vector<EdgeOnCoarse> edges_;
  std::unique_ptr<Solver> projection_;
  Eigen::Matrix3Xd y_, point_;
  Eigen::VectorXd point_mass_;  // the one embedded point's inverse mass (1) for the body's test
  Environment still_;           // the colliders at their end pose (run)
  StepInputs inputs_;
  ClothState state_;
  std::vector<unsigned char> moved_, moved_next_;
};

// `fine` is the model whose state step() takes (its kinematic targets in StepInputs); `coarse` a
// coarser mesh of the same garment (the same rest surface; its pins on the fine pins' band).
// `settings` are the coarse XPBD solve's; the fine pass is FinePass with the same settings.
// Throws std::invalid_argument when a coarse pin lies in no fine triangle with a fine
// pin (the coarse pins follow the fine ones).
std::unique_ptr<Solver> make_upsampled_solver(const ClothModel& fine, const ClothModel& coarse,
                                              const SolverSettings& settings);

}  // namespace clothdb
