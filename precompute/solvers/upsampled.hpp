// A coarse garment's XPBD solve driving a fine copy of it (Kavan, Gerszewski, Bargteil & Sloan
// 2011, "Physics-inspired upsampling for cloth simulation in games"): the fine mesh embedded
// barycentrically in the coarse rest mesh, each step the coarse solution interpolated to the fine
// vertices, then one fixed XPBD step of fine constraint passes (stretch, bending, strain limit,
// body collisions) with no gravity and no velocity, so that its inertial term is a tracking term
// that holds the fine vertices to the interpolated coarse positions (Macklin 2016 eq. 9 with
// x~ = the interpolation). The work per fine vertex does not depend on the resolution.
// docs/notebook/resolution.md, "Ninth round".
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

// The fine passes of an upsampled step (UpsampleSettings are the fine step's own; the coarse step
// uses the SolverSettings given to make_upsampled_solver).
struct UpsampleSettings {
  int bending_iterations = 1;        // bending sweeps of the fine step
  int stretch_iterations = 2;        // stretch sweeps of the fine step
  int strain_limit_iterations = 16;  // cap on the fine strain limit's passes
};

// `fine` is the model whose state step() takes (its kinematic targets in StepInputs); `coarse` a
// coarser mesh of the same garment (same rest surface). settings: the coarse XPBD solve's; the
// fine step takes its strain limit, relaxation, contact rounds, tethers, self-collision and
// threads with `fine_passes`. Throws std::invalid_argument when a coarse pin lies in no fine
// triangle with a fine pin (the coarse pins follow the fine ones).
std::unique_ptr<Solver> make_upsampled_solver(const ClothModel& fine, const ClothModel& coarse,
                                              const SolverSettings& settings,
                                              const UpsampleSettings& fine_passes);

}  // namespace clothdb
