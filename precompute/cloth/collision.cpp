#include "cloth/collision.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace clothdb {

namespace {

Vec3 lerp(const Vec3& a, const Vec3& b, double s) {
  return a + s * (b - a);
}

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

// Whether p is clearly (by more than rounding) farther than `reach` from the segment ab: the
// cheap test before capsule_point, with no square root.
bool far_from_capsule(const Vec3& a, const Vec3& b, double reach, const Vec3& p) {
  const Vec3 ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 1e-24 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).squaredNorm() > reach * reach * (1.0 + 1e-9);
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

// ColliderMotion::Swept, for one vertex against one capsule (a sphere is a capsule with a = b).
// Over a sub-step the vertex moves straight from p0 to p and the capsule's end points straight
// from (a0, b0) to (a1, b1). If the vertex starts outside and its path relative to the capsule
// enters it (the surface at `radius`; the margin is left to the projection), returns the entry
// point carried with the surface to the end pose, so the projection that follows pushes it out on
// the side it came from; otherwise returns p. The path is sampled in steps of at most a quarter
// radius of relative motion (distance to a segment moves no faster than the point and the end
// points), so a crossing of the capsule cannot fall between samples; the first sample inside is
// refined by bisection.
Vec3 swept_entry(const Vec3& p0, const Vec3& p, const Vec3& a0, const Vec3& b0, const Vec3& a1,
                 const Vec3& b1, double radius) {
  const double d0 = capsule_point(a0, b0, radius, p0).distance;
  const double reach = (p - p0).norm() + std::max((a1 - a0).norm(), (b1 - b0).norm());
  if (d0 < 0.0 || d0 > reach) return p;  // inside already (projection's job) or cannot touch
  auto at = [&](double u) {
    return capsule_point(lerp(a0, a1, u), lerp(b0, b1, u), radius, lerp(p0, p, u)).distance;
  };
  const int samples = std::clamp(static_cast<int>(std::ceil(reach / (0.25 * radius))), 1, 1024);
  double lo = 0.0, hi = -1.0;
  for (int k = 1; k <= samples; ++k) {
    const double u = static_cast<double>(k) / samples;
    if (at(u) < 0.0) {
      hi = u;
      break;
    }
    lo = u;
  }
  if (hi < 0.0) return p;  // never inside on the way
  for (int it = 0; it < 30; ++it) {
    const double mid = 0.5 * (lo + hi);
    (at(mid) < 0.0 ? hi : lo) = mid;
  }
  const Vec3 a = lerp(a0, a1, lo), b = lerp(b0, b1, lo);
  const double t = capsule_point(a, b, radius, lerp(p0, p, lo)).segment_t;
  return lerp(p0, p, lo) + (a1 + t * (b1 - a1)) - (a + t * (b - a));
}

// The pose fraction colliders are at: the end pose throughout for ColliderMotion::EndPose.
double pose_fraction(const Environment& env, double s) {
  return env.collider_motion == ColliderMotion::EndPose ? 1.0 : s;
}

}  // namespace

const char* collider_motion_name(ColliderMotion m) {
  switch (m) {
    case ColliderMotion::EndPose:
      return "end-pose";
    case ColliderMotion::Interpolated:
      return "interpolated";
    case ColliderMotion::Swept:
      return "swept";
  }
  return "?";
}

ColliderMotion parse_collider_motion(const std::string& name) {
  for (ColliderMotion m :
       {ColliderMotion::EndPose, ColliderMotion::Interpolated, ColliderMotion::Swept})
    if (name == collider_motion_name(m)) return m;
  throw std::invalid_argument("unknown collider motion '" + name +
                              "' (expected end-pose, interpolated or swept)");
}

Environment environment_at(const Environment& env, double s) {
  s = pose_fraction(env, s);
  Environment out = env;
  for (auto& sp : out.spheres) sp.center = sp.center_start = lerp(sp.center_start, sp.center, s);
  for (auto& c : out.capsules) {
    c.a = c.a_start = lerp(c.a_start, c.a, s);
    c.b = c.b_start = lerp(c.b_start, c.b, s);
  }
  return out;
}

bool resolve_vertex_collisions(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_start,
                               const Eigen::VectorXd& inv_mass, Eigen::Index i,
                               const Environment& env, double s, double s_start) {
  if (inv_mass[i] <= 0.0) return false;
  if (s_start < 0.0) s_start = s;
  s = pose_fraction(env, s);
  s_start = pose_fraction(env, s_start);
  const bool swept = env.collider_motion == ColliderMotion::Swept;
  Vec3 p = x.col(i);
  const Vec3 p0 = x_start.col(i);
  bool hit = false;
  for (const auto& c : env.planes) {
    const SurfacePoint sp = plane_point(c, p);
    hit |= respond(p, p0, sp, Vec3::Zero(), env);
  }
  for (const auto& c : env.spheres) {
    const Vec3 center = lerp(c.center_start, c.center, s);
    const Vec3 center0 = lerp(c.center_start, c.center, s_start);
    if (swept) p = swept_entry(p0, p, center0, center0, center, center, c.radius);
    const SurfacePoint sp = sphere_point(center, c.radius, p);
    hit |= respond(p, p0, sp, center - center0, env);
  }
  for (const auto& c : env.capsules) {
    const Vec3 a = lerp(c.a_start, c.a, s), b = lerp(c.b_start, c.b, s);
    const Vec3 a0 = lerp(c.a_start, c.a, s_start), b0 = lerp(c.b_start, c.b, s_start);
    if (swept) {
      p = swept_entry(p0, p, a0, b0, a, b, c.radius);
    } else if (far_from_capsule(a, b, c.radius + env.collision_margin, p)) {
      continue;  // respond would find no depth; skips the square root for most pairs
    }
    const SurfacePoint sp = capsule_point(a, b, c.radius, p);
    const Vec3 axis_now = a + sp.segment_t * (b - a);
    const Vec3 axis_before = a0 + sp.segment_t * (b0 - a0);
    hit |= respond(p, p0, sp, axis_now - axis_before, env);
  }
  // A swept entry point may sit exactly on the surface, where respond finds no depth (margin 0):
  // it is still where the vertex must go.
  if (hit || (swept && p != Vec3(x.col(i)))) x.col(i) = p;
  return hit;
}

int resolve_collisions(Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& x_start,
                       const Eigen::VectorXd& inv_mass, const Environment& env, double s,
                       double s_start) {
  int contacts = 0;
  for (Eigen::Index i = 0; i < x.cols(); ++i)
    contacts += resolve_vertex_collisions(x, x_start, inv_mass, i, env, s, s_start) ? 1 : 0;
  return contacts;
}

NearSurface nearest_surface(const Vec3& p, const Environment& env, double s, double reach) {
  s = pose_fraction(env, s);
  NearSurface near;
  // A response pushes a vertex out along the normal to the margin (friction moves it along the
  // surface), so its distance afterwards is at least the margin.
  auto note = [&](const SurfacePoint& sp) {
    const double d = std::max(sp.distance, env.collision_margin);
    if (sp.distance < reach && d < near.distance) {
      near.distance = d;
      near.normal = sp.normal;
    }
  };
  for (const auto& c : env.planes) note(plane_point(c, p));
  for (const auto& c : env.spheres)
    note(sphere_point(lerp(c.center_start, c.center, s), c.radius, p));
  for (const auto& c : env.capsules) {
    const Vec3 a = lerp(c.a_start, c.a, s), b = lerp(c.b_start, c.b, s);
    if (far_from_capsule(a, b, c.radius + reach, p)) continue;
    note(capsule_point(a, b, c.radius, p));
  }
  return near;
}

double penetration_depth(const Vec3& p, const Environment& env, double s) {
  s = pose_fraction(env, s);
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

double path_depth_fraction(const Vec3& x0, const Vec3& x1, const CapsuleCollider& c) {
  const double reach =
      (x1 - x0).norm() + std::max((c.a - c.a_start).norm(), (c.b - c.b_start).norm());
  if (capsule_point(c.a_start, c.b_start, c.radius, x0).distance > reach) return 0.0;
  const int samples = std::clamp(static_cast<int>(std::ceil(16.0 * reach / c.radius)), 1, 4096);
  double deepest = 0.0;
  for (int k = 0; k <= samples; ++k) {
    const double u = static_cast<double>(k) / samples;
    const double d =
        capsule_point(lerp(c.a_start, c.a, u), lerp(c.b_start, c.b, u), c.radius, lerp(x0, x1, u))
            .distance;
    deepest = std::max(deepest, -d / c.radius);
  }
  return std::min(deepest, 1.0);
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
