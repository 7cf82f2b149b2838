#include "solvers/self_collision.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cloth/self_intersection.hpp"

namespace clothdb {

namespace {

// Closest point to p on triangle (a, b, c) (Ericson 2005, "Real-Time Collision Detection",
// sec. 5.1.5, by Voronoi regions).
Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + (d1 / (d1 - d3)) * ab;
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + (d2 / (d2 - d6)) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0)
    return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

// Parameters s, t in [0, 1] of the closest points p1 + s (q1 - p1) and p2 + t (q2 - p2) of two
// segments (Ericson 2005, sec. 5.1.9).
void closest_on_segments(const Vec3& p1, const Vec3& q1, const Vec3& p2, const Vec3& q2, double& s,
                         double& t) {
  const Vec3 d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  constexpr double eps = 1e-30;
  if (a <= eps && e <= eps) {
    s = t = 0.0;
    return;
  }
  if (a <= eps) {
    s = 0.0;
    t = std::clamp(f / e, 0.0, 1.0);
    return;
  }
  const double c = d1.dot(r);
  if (e <= eps) {
    t = 0.0;
    s = std::clamp(-c / a, 0.0, 1.0);
    return;
  }
  const double b = d1.dot(d2), denom = a * e - b * b;
  s = denom > 0.0 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
  t = (b * s + f) / e;
  if (t < 0.0) {
    t = 0.0;
    s = std::clamp(-c / a, 0.0, 1.0);
  } else if (t > 1.0) {
    t = 1.0;
    s = std::clamp((b - c) / a, 0.0, 1.0);
  }
}

double segment_distance_sq(const Vec3& p1, const Vec3& q1, const Vec3& p2, const Vec3& q2) {
  double s = 0.0, t = 0.0;
  closest_on_segments(p1, q1, p2, q2, s, t);
  return ((p1 + s * (q1 - p1)) - (p2 + t * (q2 - p2))).squaredNorm();
}

// True if the boxes of segments p1-q1 and p2-q2 are more than `gap` apart along some axis: then
// the segments are too (the cheap test before the closest points, which most listed pairs fail).
bool boxes_apart(const Vec3& p1, const Vec3& q1, const Vec3& p2, const Vec3& q2, double gap) {
  for (int k = 0; k < 3; ++k) {
    const double lo1 = std::min(p1[k], q1[k]), hi1 = std::max(p1[k], q1[k]);
    const double lo2 = std::min(p2[k], q2[k]), hi2 = std::max(p2[k], q2[k]);
    if (lo2 > hi1 + gap || lo1 > hi2 + gap) return true;
  }
  return false;
}

Vec3 unit_normal(const Eigen::Matrix3Xd& x, const std::array<int, 3>& t) {
  const Vec3 n = (x.col(t[1]) - x.col(t[0])).cross(x.col(t[2]) - x.col(t[0]));
  const double len = n.norm();
  return len > 0.0 ? Vec3(n / len) : Vec3::Zero();
}

void build_candidates(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x) {
  const ClothMesh& mesh = model.mesh;
  const Eigen::Matrix3Xd& rest = mesh.rest;
  const double* w = model.inv_mass.data();
  const double reach = sc.thickness + sc.skin, reach_sq = reach * reach;
  const double rest_sq = sc.thickness * sc.thickness;
  sc.vertex_triangle.clear();
  sc.edge_edge.clear();
  double longest = 0.0;
  const size_t edge_count = mesh.edges.size();
  Eigen::Matrix3Xd mid(3, static_cast<Eigen::Index>(edge_count));
  for (size_t e = 0; e < edge_count; ++e) {
    const Vec3 p = x.col(mesh.edges[e][0]), q = x.col(mesh.edges[e][1]);
    mid.col(static_cast<Eigen::Index>(e)) = 0.5 * (p + q);
    longest = std::max(longest, (p - q).norm());
  }
  if (!std::isfinite(longest) || !(longest > 0.0)) return;  // the solver's sanity check reports it
  // Cells about the size of a triangle's box grown by the reach: each query visits a few cells.
  const double cell = longest + 2.0 * reach;

  // Vertex-triangle pairs.
  PointGrid grid;
  grid.build(x, cell);
  std::vector<int> stamp(static_cast<size_t>(x.cols()), -1);
  for (size_t ti = 0; ti < mesh.triangles.size(); ++ti) {
    const std::array<int, 3>& t = mesh.triangles[ti];
    const int tri = static_cast<int>(ti);
    const Vec3 a = x.col(t[0]), b = x.col(t[1]), c = x.col(t[2]);
    const Vec3 lo = a.cwiseMin(b).cwiseMin(c) - Vec3::Constant(reach);
    const Vec3 hi = a.cwiseMax(b).cwiseMax(c) + Vec3::Constant(reach);
    const bool triangle_free = w[t[0]] + w[t[1]] + w[t[2]] > 0.0;
    grid.query(lo, hi, [&](int v) {
      int& seen = stamp[static_cast<size_t>(v)];
      if (seen == tri) return;
      seen = tri;
      if (v == t[0] || v == t[1] || v == t[2]) return;
      if (!triangle_free && w[v] <= 0.0) return;
      const Vec3 p = x.col(v);
      if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) return;
      if ((closest_on_triangle(p, a, b, c) - p).squaredNorm() >= reach_sq) return;
      const Vec3 pr = rest.col(v);
      if ((closest_on_triangle(pr, rest.col(t[0]), rest.col(t[1]), rest.col(t[2])) - pr)
              .squaredNorm() < rest_sq)
        return;
      sc.vertex_triangle.push_back({v, tri});
    });
  }

  // Edge-edge pairs: edges by midpoint; another edge's midpoint is within half the longest edge
  // of any of its points.
  grid.build(mid, cell);
  stamp.assign(edge_count, -1);
  const Vec3 grow = Vec3::Constant(reach + 0.5 * longest);
  for (size_t ei = 0; ei < edge_count; ++ei) {
    const std::array<int, 2>& e1 = mesh.edges[ei];
    const int first = static_cast<int>(ei);
    const Vec3 p1 = x.col(e1[0]), q1 = x.col(e1[1]);
    const bool first_free = w[e1[0]] + w[e1[1]] > 0.0;
    grid.query(p1.cwiseMin(q1) - grow, p1.cwiseMax(q1) + grow, [&](int e) {
      if (e <= first) return;
      int& seen = stamp[static_cast<size_t>(e)];
      if (seen == first) return;
      seen = first;
      const std::array<int, 2>& e2 = mesh.edges[static_cast<size_t>(e)];
      if (e2[0] == e1[0] || e2[0] == e1[1] || e2[1] == e1[0] || e2[1] == e1[1]) return;
      if (!first_free && w[e2[0]] + w[e2[1]] <= 0.0) return;
      if (boxes_apart(p1, q1, x.col(e2[0]), x.col(e2[1]), reach)) return;
      if (segment_distance_sq(p1, q1, x.col(e2[0]), x.col(e2[1])) >= reach_sq) return;
      if (segment_distance_sq(rest.col(e1[0]), rest.col(e1[1]), rest.col(e2[0]), rest.col(e2[1])) <
          rest_sq)
        return;
      sc.edge_edge.push_back({first, e});
    });
  }
  sc.built_at = x;
  ++sc.builds;
}

}  // namespace

SelfCollision make_self_collision(const ClothModel& model, double thickness) {
  if (!(thickness > 0.0) || !std::isfinite(thickness))
    throw std::invalid_argument("self-collision: thickness must be a positive finite number, got " +
                                std::to_string(thickness));
  SelfCollision sc;
  sc.thickness = thickness;
  double mean_edge = 0.0;
  for (double l : model.edge_rest_length) mean_edge += l;
  if (!model.edge_rest_length.empty()) mean_edge /= double(model.edge_rest_length.size());
  sc.skin = std::max(thickness, 0.5 * mean_edge);
  return sc;
}

bool refresh_self_collision(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x) {
  bool stale = sc.built_at.cols() != x.cols();
  if (!stale && x.cols() > 0) {
    // A pair's distance changes by at most |d_i - d_j| <= |d_i - m| + |d_j - m| for the vertex
    // displacements d since the build and any common m: measured from the centre of the
    // displacements' box, a garment carried along by the body (a walk, a jump) keeps its lists
    // for as long as its shape changes by less than skin / 2.
    const Eigen::Matrix3Xd d = x - sc.built_at;
    const Vec3 m = 0.5 * (d.rowwise().minCoeff() + d.rowwise().maxCoeff());
    stale = !((d.colwise() - m).colwise().squaredNorm().maxCoeff() <= 0.25 * sc.skin * sc.skin);
  }
  if (stale) build_candidates(sc, model, x);
  return stale;
}

int project_self_collision(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x,
                           const Eigen::Matrix3Xd& x_start) {
  const ClothMesh& mesh = model.mesh;
  const double* w = model.inv_mass.data();
  const double h = sc.thickness;
  const size_t tri_count = mesh.triangles.size();
  sc.normal.resize(tri_count);
  sc.normal_start.resize(tri_count);
  // Normals once per pass (the pass moves each vertex by at most about the thickness).
  for (size_t t = 0; t < tri_count; ++t) {
    sc.normal[t] = unit_normal(x, mesh.triangles[t]);
    sc.normal_start[t] = unit_normal(x_start, mesh.triangles[t]);
  }
  int contacts = 0;
  // Vertex-triangle: C = sigma (p - q) . n - h >= 0 with q = sum b_k x_k the projection of p onto
  // the triangle's plane, sigma the side p was on at the sub-step's start. Gradients sigma n for p
  // and -sigma b_k n for the corners (the normal's own derivative is left out, as usual for
  // contacts); the PBD step moves each by -C w grad / sum w |grad|^2 (Mueller 2007 eq. 4-5).
  for (const std::array<int, 2>& pair : sc.vertex_triangle) {
    const int v = pair[0];
    const std::array<int, 3>& t = mesh.triangles[static_cast<size_t>(pair[1])];
    const Vec3& n = sc.normal[static_cast<size_t>(pair[1])];
    const Vec3& n0 = sc.normal_start[static_cast<size_t>(pair[1])];
    const Vec3 a = x.col(t[0]);
    const double dist = (x.col(v) - a).dot(n);
    const double dist_start = (x_start.col(v) - x_start.col(t[0])).dot(n0);
    const double sigma =
        dist_start != 0.0 ? (dist_start > 0.0 ? 1.0 : -1.0) : (dist >= 0.0 ? 1.0 : -1.0);
    const double c = sigma * dist - h;
    if (c >= 0.0 || n.isZero()) continue;
    // Barycentric coordinates of the projection (Ericson 2005 sec. 3.4); only a vertex over the
    // triangle's interior touches its face (the edges' own pairs take the rest).
    const Vec3 e0 = x.col(t[1]) - a, e1 = x.col(t[2]) - a, ep = x.col(v) - dist * n - a;
    const double d00 = e0.dot(e0), d01 = e0.dot(e1), d11 = e1.dot(e1);
    const double d20 = ep.dot(e0), d21 = ep.dot(e1);
    const double det = d00 * d11 - d01 * d01;
    if (!(det > 0.0)) continue;
    const double b1 = (d11 * d20 - d01 * d21) / det, b2 = (d00 * d21 - d01 * d20) / det;
    const double b0 = 1.0 - b1 - b2;
    if (b0 < 0.0 || b1 < 0.0 || b2 < 0.0) continue;
    const double wv = w[v], w0 = w[t[0]], w1 = w[t[1]], w2 = w[t[2]];
    const double denom = wv + w0 * b0 * b0 + w1 * b1 * b1 + w2 * b2 * b2;
    if (!(denom > 0.0)) continue;
    const Vec3 step = (-c / denom * sigma) * n;
    x.col(v) += wv * step;
    x.col(t[0]) -= (w0 * b0) * step;
    x.col(t[1]) -= (w1 * b1) * step;
    x.col(t[2]) -= (w2 * b2) * step;
    ++contacts;
  }
  // Edge-edge: C = (P - Q) . n - h >= 0 with P, Q the closest points, n their unit direction, or,
  // when the interior closest points have swapped sides since the sub-step's start (the edges
  // went through each other), the direction they had then. Gradients (1 - s) n, s n, -(1 - t) n,
  // -t n.
  for (const std::array<int, 2>& pair : sc.edge_edge) {
    const std::array<int, 2>& e1 = mesh.edges[static_cast<size_t>(pair[0])];
    const std::array<int, 2>& e2 = mesh.edges[static_cast<size_t>(pair[1])];
    const Vec3 p1 = x.col(e1[0]), q1 = x.col(e1[1]), p2 = x.col(e2[0]), q2 = x.col(e2[1]);
    // Most listed pairs are farther apart than the thickness both now and at the sub-step's
    // start: skip them before the closest points (a pair that went through each other and on by
    // more than the thickness within one sub-step, 8 mm at 4 mm and 3.6 m/s relative at 15
    // sub-steps of 1/30 s, is missed here, as it would be by the vertex-triangle test).
    if (boxes_apart(p1, q1, p2, q2, h) && boxes_apart(x_start.col(e1[0]), x_start.col(e1[1]),
                                                      x_start.col(e2[0]), x_start.col(e2[1]), h))
      continue;
    double s = 0.0, t = 0.0;
    closest_on_segments(p1, q1, p2, q2, s, t);
    const Vec3 d = (p1 + s * (q1 - p1)) - (p2 + t * (q2 - p2));
    const double dist_sq = d.squaredNorm();
    const bool interior = s > 0.0 && s < 1.0 && t > 0.0 && t < 1.0;
    Vec3 n;
    double c = 0.0;
    const Vec3 d0 = (x_start.col(e1[0]) + s * (x_start.col(e1[1]) - x_start.col(e1[0]))) -
                    (x_start.col(e2[0]) + t * (x_start.col(e2[1]) - x_start.col(e2[0])));
    if (interior && d.dot(d0) < 0.0 && d0.squaredNorm() > 0.0) {
      n = d0.normalized();
      c = d.dot(n) - h;
    } else {
      if (dist_sq >= h * h || !(dist_sq > 0.0)) continue;
      const double dist = std::sqrt(dist_sq);
      n = d / dist;
      c = dist - h;
    }
    if (c >= 0.0) continue;
    const double w0 = w[e1[0]], w1 = w[e1[1]], w2 = w[e2[0]], w3 = w[e2[1]];
    const double denom = w0 * (1 - s) * (1 - s) + w1 * s * s + w2 * (1 - t) * (1 - t) + w3 * t * t;
    if (!(denom > 0.0)) continue;
    const Vec3 step = (-c / denom) * n;
    x.col(e1[0]) += (w0 * (1 - s)) * step;
    x.col(e1[1]) += (w1 * s) * step;
    x.col(e2[0]) -= (w2 * (1 - t)) * step;
    x.col(e2[1]) -= (w3 * t) * step;
    ++contacts;
  }
  return contacts;
}

}  // namespace clothdb
