// The point of a triangle nearest a given point, as a position and as barycentric weights: the one
// copy of Ericson's Voronoi-region test, for the self-contacts' lists (solvers/self_collision.cpp)
// and the fine garment's embedding in a coarse one (solvers/upsampled.cpp).
#pragma once

#include <array>

#include "cloth/mesh.hpp"

namespace clothdb {

struct TrianglePoint {
  Vec3 point;                    // the nearest point
  std::array<double, 3> weight;  // point = weight[0] a + weight[1] b + weight[2] c (up to rounding)
};

// Nearest point to p on triangle (a, b, c) (Ericson 2005, "Real-Time Collision Detection",
// sec. 5.1.5, by Voronoi regions). At a corner its weight is exactly 1; `point` is computed as
// Ericson writes it (from a corner along the edges), not from the weights.
inline TrianglePoint closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b,
                                         const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {a, {1.0, 0.0, 0.0}};
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {b, {0.0, 1.0, 0.0}};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return {a + v * ab, {1.0 - v, v, 0.0}};
  }
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {c, {0.0, 0.0, 1.0}};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return {a + w * ac, {1.0 - w, 0.0, w}};
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {b + w * (c - b), {0.0, 1.0 - w, w}};
  }
  const double denom = 1.0 / (va + vb + vc);
  const double v = vb * denom, w = vc * denom;
  return {a + ab * v + ac * w, {1.0 - v - w, v, w}};
}

}  // namespace clothdb
