// Simple colliders and the collision response shared by all four solvers: projection out of each
// collider to a thickness margin, with Coulomb friction (static and kinetic).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cloth/mesh.hpp"

namespace clothdb {

struct PlaneCollider {
  Vec3 normal{0, 1, 0};  // unit normal; the free side is normal . x >= offset
  double offset = 0.0;
};

// Spheres and capsules may move during a step: `*_start` is the pose at the start of the step and
// the plain members the pose at its end. Solvers interpolate linearly for sub-steps (so a fast
// limb sweeps through the sub-step poses instead of jumping: no tunnelling).
struct SphereCollider {
  Vec3 center{0, 0, 0};
  Vec3 center_start{0, 0, 0};
  double radius = 0.1;
};

struct CapsuleCollider {
  Vec3 a{0, 0, 0}, b{0, 1, 0};              // segment end points at the end of the step
  Vec3 a_start{0, 0, 0}, b_start{0, 1, 0};  // at the start of the step
  double radius = 0.05;
  int bone = -1;  // skeleton joint it belongs to, for reports (-1: none)
};

struct Environment {
  Vec3 gravity{0, -9.81, 0};
  // Linear air drag, N*s/m^3: force on vertex i is -air_drag * vertex_area_i * v_i.
  double air_drag = 0.0;
  std::vector<PlaneCollider> planes;
  std::vector<SphereCollider> spheres;
  std::vector<CapsuleCollider> capsules;
  double collision_margin = 1.0e-3;  // thickness margin kept between cloth and collider surface, m
  double friction_static = 0.4;      // Coulomb static coefficient
  double friction_kinetic = 0.3;     // Coulomb kinetic coefficient
};

// Colliders interpolated to fraction `s` of the step (0 = start, 1 = end).
Environment environment_at(const Environment& env, double s);

// Projects every vertex with inv_mass > 0 out of every collider (at pose fraction `s` of the step)
// to distance >= collision_margin from its surface. Friction acts on the tangential displacement
// over the step relative to the collider surface's own motion: if it is below friction_static times
// the normal correction it is removed (stick), otherwise reduced by friction_kinetic times it.
// `x_start` are the positions at the start of the (sub)step, which began at pose fraction
// `s_start` (default: s, i.e. the surface is taken as still over the sub-step). Returns the number
// of contacts.
int resolve_collisions(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_start,
                       const Eigen::VectorXd& inv_mass, const Environment& env, double s,
                       double s_start = -1.0);

// Depth of p below the deepest collider surface at pose fraction `s`: metres inside, 0 if outside
// every collider. The margin is not counted. The one measure of penetration every report uses
// (max_penetration, mean_penetration, precompute/quality/clip_quality.hpp).
double penetration_depth(const Vec3& p, const Environment& env, double s = 1.0);

// Deepest penetration of any vertex (with inv_mass > 0, or all if inv_mass is empty) into any
// collider surface at pose fraction `s`: metres inside the surface, 0 if none. The margin is not
// counted: a vertex resting at the margin has penetration 0.
double max_penetration(const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                       const Environment& env, double s = 1.0);
// Mean over penetrating vertices (0 if none).
double mean_penetration(const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                        const Environment& env, double s = 1.0);

}  // namespace clothdb
