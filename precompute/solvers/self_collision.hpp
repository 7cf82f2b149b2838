// Cloth self-collision for XPBD (docs/notebook/self_collision.md): vertex-triangle and edge-edge
// contacts that keep the cloth at least `thickness` from itself, as unilateral position constraints
// projected in each sub-step, up to three passes (xpbd.cpp) (Bridson, Fedkiw & Anderson 2002 sec. 7
// for the pair types and their closest points; Mueller et al. 2007 sec. 4.2 / Macklin 2016 for
// projecting C >= 0 with inverse-mass weights).
//
// Cost: candidates are found with a spatial hash (a grid of boxes, self_collision.cpp) only when
// needed. A build lists every pair closer than thickness + skin (a Verlet list); it stays
// complete until some vertex has moved more than skin / 2 since the build, relative to the
// garment's common motion (a pair's distance changes by at most the sum of two vertex
// displacements relative to any common vector), which is checked every sub-step in O(vertices). So
// a slowly moving garment is hashed once every few frames, a fast one a few times per frame, and
// every sub-step tests only the listed pairs, and of those only the ones whose distance at the
// build (less the thickness) is not more than their parts have moved since (`moved`): most listed
// pairs are flat-sheet neighbours that never come within the thickness. A build's lists are sorted
// by (first, second), so the contacts' Gauss-Seidel order does not depend on how the grid found
// them. Pairs nearer than the thickness in the rest shape (neighbours on the mesh) are found once,
// in make_self_collision, and skipped by a scan of a short row instead of a closest-point test at
// every build (docs/notebook/self_collision.md, "Cost, second round", also for why pairs up to
// thickness + skin apart at rest must stay listed).
//
// Side: each contact is pushed to the side its pair was on at the start of the sub-step, so a
// pair that went through within one sub-step is put back, not pushed further through.
//
// Determinism: the build and the projection are serial, in index order (Gauss-Seidel over the
// contact list), so the result does not depend on the thread count. The rest neighbours left out
// cannot be pushed apart (they are nearer than the thickness by construction) and are held by the
// stretch and bending constraints instead.
#pragma once

#include <Eigen/Core>
#include <array>
#include <vector>

#include "cloth/model.hpp"

namespace clothdb {

struct SelfCollision {
  double thickness = 0.0;  // m
  double skin = 0.0;       // m: how much farther than thickness a listed pair may be at build
  double mean_edge = 0.0;  // m, mean rest edge length (sets the hash's cell size)
  // m: pairs nearer than this in the rest shape (the thickness) are neighbours on the mesh and
  // never listed.
  double rest_gap = 0.0;
  // Those rest neighbours, found once: for triangle t the vertices rest_vt[rest_vt_begin[t] ..
  // rest_vt_begin[t + 1]), for edge e the edges after it likewise in rest_ee.
  std::vector<int> rest_vt_begin, rest_vt, rest_ee_begin, rest_ee;
  // Candidate pairs of the last build: (triangle, vertex) and (edge, edge) with edge indices into
  // mesh.edges, the first less than the second.
  std::vector<std::array<int, 2>> vertex_triangle;
  std::vector<std::array<int, 2>> edge_edge;
  // Per listed pair, its distance at the build minus the thickness (m, rounded down to float): how
  // far its parts must still move towards each other before it can be in contact.
  std::vector<float> vertex_triangle_gap, edge_edge_gap;
  Eigen::Matrix3Xd built_at;  // positions at the last build (empty: never built)
  // Per vertex, a bound (m) on how far it has moved since the build relative to the garment's
  // common motion, over every position a pass may see (the sub-step's start and now, and each move
  // of the passes): a pair whose gap exceeds the sum of its parts' bounds cannot be in contact and
  // is skipped (docs/notebook/self_collision.md, "Fourth round").
  std::vector<double> moved;
  long builds = 0;  // how many builds so far (reported by describe / benchmarks)
};

// A SelfCollision for `model` with thickness (m) > 0. The skin is half the mean rest edge length,
// but at least the thickness: enough that a build lasts several sub-steps, small enough that the
// lists hold a few pairs per vertex.
SelfCollision make_self_collision(const ClothModel& model, double thickness);

// Rebuilds the candidate lists if they may be incomplete for positions x (or were never built), and
// brings the per-vertex motion bounds up to x and x_start (the sub-step's start). Returns whether
// it rebuilt.
bool refresh_self_collision(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                            const Eigen::Matrix3Xd& x_start);

// One Gauss-Seidel pass over the listed pairs at positions x (moved in place), with x_start the
// positions at the start of the sub-step (which side each pair was on). Returns the number of
// contacts projected.
int project_self_collision(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x,
                           const Eigen::Matrix3Xd& x_start);

}  // namespace clothdb
