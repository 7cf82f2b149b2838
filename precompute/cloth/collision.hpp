// Simple colliders and the collision response shared by all four solvers: projection out of each
// collider to a thickness margin, with Coulomb friction (static and kinetic).
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <string>
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

// Where a moving sphere or capsule is during a (sub)step, and how a vertex is tested against it.
// This is the "no tunnelling for fast limbs" choice;
// docs/notebook/BENCHMARKS.md#fast-limbs-on-the-boxing-clip-sub-steps-against-swept-capsules
// compares the three on the boxing clip.
enum class ColliderMotion {
  // At the end pose for every sub-step, as if the limb jumped there at the start of the step.
  // Only for comparison: a limb faster than its radius per step can pass through cloth.
  EndPose,
  // At each sub-step's pose, interpolated linearly between start and end (the default): a vertex
  // is projected out of the collider where it is at the end of the sub-step, so a limb moving
  // less than about its radius per sub-step cannot jump over a vertex.
  Interpolated,
  // Interpolated, plus a continuous test of each sub-step: a vertex whose straight path relative
  // to the moving collider enters it during the sub-step is put back on the side it entered from
  // (carried along with the surface) before it is projected, however far the limb moved.
  Swept,
};
const char* collider_motion_name(ColliderMotion m);  // "end-pose", "interpolated", "swept"
// Parses a name as above; throws std::invalid_argument naming the accepted values.
ColliderMotion parse_collider_motion(const std::string& name);

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
  ColliderMotion collider_motion = ColliderMotion::Interpolated;
};

// Colliders interpolated to fraction `s` of the step (0 = start, 1 = end); with
// ColliderMotion::EndPose, at the end pose whatever `s` is.
Environment environment_at(const Environment& env, double s);

// Projects every vertex with inv_mass > 0 out of every collider (at pose fraction `s` of the step)
// to distance >= collision_margin from its surface. Friction acts on the tangential displacement
// over the step relative to the collider surface's own motion: if it is below friction_static times
// the normal correction it is removed (stick), otherwise reduced by friction_kinetic times it.
// `x_start` are the positions at the start of the (sub)step, which began at pose fraction
// `s_start` (default: s, i.e. the surface is taken as still over the sub-step). With
// ColliderMotion::Swept, a vertex whose path from x_start to x relative to a sphere or capsule
// moving from pose s_start to s enters it is first moved to its entry point carried with the
// surface. Returns the number of contacts.
int resolve_collisions(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_start,
                       const Eigen::VectorXd& inv_mass, const Environment& env, double s,
                       double s_start = -1.0);

// resolve_collisions for vertex i alone (it reads and writes only column i of x), for callers that
// share the vertices out among threads; the result is the same whatever the sharing. Returns true
// on contact.
bool resolve_vertex_collisions(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_start,
                               const Eigen::VectorXd& inv_mass, Eigen::Index i,
                               const Environment& env, double s, double s_start = -1.0);

// The collider surface nearest p at pose fraction s, if one is nearer than `reach`: its outward
// normal and p's distance from it (m), at least the margin (where a response leaves a vertex it
// pushed out). For the cloth's self-contacts, which must not push a vertex deep into the body
// (solvers/self_collision.hpp, kBodyGive); asked only for the few vertices they move.
struct NearSurface {
  double distance = INFINITY;  // +infinity if no surface is within reach
  Vec3 normal = Vec3::Zero();  // the nearest one's outward normal
};
NearSurface nearest_surface(const Vec3& p, const Environment& env, double s, double reach);

// Depth of p below the deepest collider surface at pose fraction `s`: metres inside, 0 if outside
// every collider. The margin is not counted. The one measure of penetration every report uses
// (max_penetration, mean_penetration, precompute/quality/clip_quality.hpp).
double penetration_depth(const Vec3& p, const Environment& env, double s = 1.0);

// Deepest penetration of any vertex (with inv_mass > 0, or all if inv_mass is empty) into any
// collider surface at pose fraction `s`: metres inside the surface, 0 if none. The margin is not
// counted: a vertex resting at the margin has penetration 0.
double max_penetration(const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                       const Environment& env, double s = 1.0);
// How deep the straight path of a point from x0 to x1 reaches into capsule `c` while the capsule
// moves linearly from its start pose to its end pose over the same interval, as a fraction of its
// radius: 0 if the path stays outside, 1 if it crosses the axis. Tunnelling shows here: a vertex
// a limb swept through ends on the far side of it and its path crosses the limb (near 1), while
// a vertex carried along the surface stays near 0. Sampled in steps of 1/16 radius of relative
// motion.
double path_depth_fraction(const Vec3& x0, const Vec3& x1, const CapsuleCollider& c);

// Mean over penetrating vertices (0 if none).
double mean_penetration(const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                        const Environment& env, double s = 1.0);

}  // namespace clothdb
