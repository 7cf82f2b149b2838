#include "cloth/collision.hpp"

#include <algorithm>
#include <cmath>

namespace clothdb {

namespace {

Vec3 lerp(const Vec3& a, const Vec3& b, double s) { return a + s * (b - a); }

// Signed distance from p to a collider surface, the outward normal there, and the point of the
// collider that carries the contact (for the surface's own motion). One function per shape.
struct SurfacePoint {
  double distance;  // > 0 outside, < 0 inside
  Vec3 normal;
  double segment_t;  // capsule: parameter of the closest axis point; else 0
};

SurfacePoint plane_point(const PlaneCollider& c, const Vec3& p) {
  return {c.normal.dot(p) - c.offset, c.normal, 0.0};
}

SurfacePoint sphere_point(const Vec3& center, double radius, const Vec3& p) {
  Vec3 d = p - center;
  const double len = d.norm();
  // At the exact centre any direction is as good as another; pick +y so the result is defined.
  const Vec3 n = len > 1e-12 ? Vec3(d / len) : Vec3(0, 1, 0);
  return {len - radius, n, 0.0};
}

SurfacePoint capsule_point(const Vec3& a, const Vec3& b, double radius, const Vec3& p) {
  const Vec3 ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 1e-24 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  SurfacePoint sp = sphere_point(a + t * ab, radius, p);
  sp.segment_t = t;
  return sp;
}

// Pushes x out to the margin along n and applies Coulomb friction to its tangential motion over
// the sub-step relative to the surface (surface_motion). Returns true on contact.
bool respond(Vec3& x, const Vec3& x_start, const SurfacePoint& sp, const Vec3& surface_motion,
             const Environment& env) {
  const double depth = env.collision_margin - sp.distance;
  if (depth <= 0.0) return false;
  x += depth * sp.normal;
  Vec3 rel = x - x_start - surface_motion;
  const Vec3 tangential = rel - rel.dot(sp.normal) * sp.normal;
  const double slide = tangential.norm();
  if (slide <= env.friction_static * depth) {
    x -= tangential;  // static friction: stick to the surface
  } else {
    x -= tangential * std::min(1.0, env.friction_kinetic * depth / slide);
  }
  return true;
}

}  // namespace

Environment environment_at(const Environment& env, double s) {
  Environment out = env;
  for (auto& sp : out.spheres) sp.center = sp.center_start = lerp(sp.center_start, sp.center, s);
  for (auto& c : out.capsules) {
    c.a = c.a_start = lerp(c.a_start, c.a, s);
    c.b = c.b_start = lerp(c.b_start, c.b, s);
  }
  return out;
}

int resolve_collisions(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_start,
                       const Eigen::VectorXd& inv_mass, const Environment& env, double s,
                       double s_start) {
  if (s_start < 0.0) s_start = s;
  int contacts = 0;
  const Eigen::Index n = x.cols();
  for (Eigen::Index i = 0; i < n; ++i) {
    if (inv_mass[i] <= 0.0) continue;
    Vec3 p = x.col(i);
    const Vec3 p0 = x_start.col(i);
    bool hit = false;
    for (const auto& c : env.planes) hit |= respond(p, p0, plane_point(c, p), Vec3::Zero(), env);
    for (const auto& c : env.spheres) {
      const Vec3 center = lerp(c.center_start, c.center, s);
      const Vec3 motion = center - lerp(c.center_start, c.center, s_start);
      hit |= respond(p, p0, sphere_point(center, c.radius, p), motion, env);
    }
    for (const auto& c : env.capsules) {
      const Vec3 a = lerp(c.a_start, c.a, s), b = lerp(c.b_start, c.b, s);
      const SurfacePoint sp = capsule_point(a, b, c.radius, p);
      const Vec3 axis_now = a + sp.segment_t * (b - a);
      const Vec3 a0 = lerp(c.a_start, c.a, s_start), b0 = lerp(c.b_start, c.b, s_start);
      const Vec3 axis_before = a0 + sp.segment_t * (b0 - a0);
      hit |= respond(p, p0, sp, axis_now - axis_before, env);
    }
    if (hit) {
      x.col(i) = p;
      ++contacts;
    }
  }
  return contacts;
}

double penetration_depth(const Vec3& p, const Environment& env, double s) {
  double depth = 0.0;
  for (const auto& c : env.planes) depth = std::max(depth, -plane_point(c, p).distance);
  for (const auto& c : env.spheres)
    depth = std::max(depth, -sphere_point(lerp(c.center_start, c.center, s), c.radius, p).distance);
  for (const auto& c : env.capsules) {
    const Vec3 a = lerp(c.a_start, c.a, s), b = lerp(c.b_start, c.b, s);
    depth = std::max(depth, -capsule_point(a, b, c.radius, p).distance);
  }
  return depth;
}

double max_penetration(const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                       const Environment& env, double s) {
  double worst = 0.0;
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    if (inv_mass.size() > 0 && inv_mass[i] <= 0.0) continue;
    worst = std::max(worst, penetration_depth(x.col(i), env, s));
  }
  return worst;
}

double mean_penetration(const Eigen::Matrix3Xd& x, const Eigen::VectorXd& inv_mass,
                        const Environment& env, double s) {
  double sum = 0.0;
  int count = 0;
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    if (inv_mass.size() > 0 && inv_mass[i] <= 0.0) continue;
    const double d = penetration_depth(x.col(i), env, s);
    if (d > 0.0) {
      sum += d;
      ++count;
    }
  }
  return count > 0 ? sum / count : 0.0;
}

}  // namespace clothdb
