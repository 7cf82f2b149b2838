// A coarse garment's XPBD solve driving a fine copy of it (Kavan, Gerszewski, Bargteil & Sloan
// 2011, "Physics-inspired upsampling for cloth simulation in games"): the fine mesh embedded
// barycentrically in the coarse rest mesh, each step the coarse solution interpolated to the fine
// vertices, then one fixed pass of the fine strain limit, tethers and collisions, which add no
// motion of their own: each step starts again from the interpolation, so the fine garment's low
// frequencies are the coarse solution's by construction (the role of Kavan et al.'s tracking
// constraints). Bending and stretch sweeps on the fine mesh were measured and left out: from an
// interpolated state with in-plane compression they stretched edges to 12-24 %. The work per fine
// vertex does not depend on the resolution.
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

// `fine` is the model whose state step() takes (its kinematic targets in StepInputs); `coarse` a
// coarser mesh of the same garment (the same rest surface; its pins on the fine pins' band).
// `settings` are the coarse XPBD solve's; the fine pass is make_xpbd_projection_solver's with one
// sub-step and the same strain limit, passes, relaxation, contact rounds, tethers, self-collision
// and threads. Throws std::invalid_argument when a coarse pin lies in no fine triangle with a fine
// pin (the coarse pins follow the fine ones).
std::unique_ptr<Solver> make_upsampled_solver(const ClothModel& fine, const ClothModel& coarse,
                                              const SolverSettings& settings);

}  // namespace clothdb
