// Cloth self-collision for XPBD (docs/notebook/self_collision.md): vertex-triangle and edge-edge
// contacts that keep the cloth at least `thickness` from itself, as unilateral position constraints
// projected once per sub-step (Bridson, Fedkiw & Anderson 2002 sec. 7 for the pair types and their
// closest points; Mueller et al. 2007 sec. 4.2 / Macklin 2016 for projecting C >= 0 with
// inverse-mass weights).
//
// Cost: candidates are found with a spatial hash (cloth/self_intersection.hpp, PointGrid) only
// when needed. A build lists every pair closer than thickness + skin (a Verlet list); it stays
// complete until some vertex has moved more than skin / 2 since the build, relative to the
// garment's common motion (a pair's distance changes by at most the sum of two vertex
// displacements relative to any common vector), which is checked every sub-step in O(vertices). So
// a slowly moving garment is hashed once every few frames, a fast one a few times per frame, and
// every sub-step tests only the listed pairs.
//
// Side: each contact is pushed to the side its pair was on at the start of the sub-step, so a
// pair that went through within one sub-step is put back, not pushed further through.
//
// Determinism: the build and the projection are serial, in index order (Gauss-Seidel over the
// contact list), so the result does not depend on the thread count. Pairs of parts that are
// nearer than `thickness` at rest (neighbours on the mesh) are never listed: they cannot be moved
// apart and are held by the stretch and bending constraints instead.
#pragma once

#include <Eigen/Core>
#include <array>
#include <vector>

#include "cloth/model.hpp"

namespace clothdb {

struct SelfCollision {
  double thickness = 0.0;  // m
  double skin = 0.0;       // m: how much farther than thickness a listed pair may be at build
  // Candidate pairs of the last build: (vertex, triangle) and (edge, edge) with edge indices into
  // mesh.edges, the first less than the second.
  std::vector<std::array<int, 2>> vertex_triangle;
  std::vector<std::array<int, 2>> edge_edge;
  Eigen::Matrix3Xd built_at;  // positions at the last build (empty: never built)
  long builds = 0;            // how many builds so far (reported by describe / benchmarks)
  // Per-sub-step scratch: unit triangle normals now and at the sub-step's start.
  std::vector<Vec3> normal, normal_start;
};

// A SelfCollision for `model` with thickness (m) > 0. The skin is half the mean rest edge length,
// but at least the thickness: enough that a build lasts several sub-steps, small enough that the
// lists hold a few pairs per vertex.
SelfCollision make_self_collision(const ClothModel& model, double thickness);

// Rebuilds the candidate lists if they may be incomplete for positions x (or were never built).
// Returns whether it rebuilt.
bool refresh_self_collision(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x);

// One Gauss-Seidel pass over the listed pairs at positions x (moved in place), with x_start the
// positions at the start of the sub-step (which side each pair was on). Returns the number of
// contacts projected.
int project_self_collision(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x,
                           const Eigen::Matrix3Xd& x_start);

}  // namespace clothdb
