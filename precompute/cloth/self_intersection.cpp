#include "cloth/self_intersection.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace clothdb {

long PointGrid::cell_index(double coordinate) const {
  // Clamped so a runaway coordinate cannot overflow the cast; such points share edge cells.
  const double c = std::floor(coordinate / cell);
  return static_cast<long>(std::clamp(c, -1e9, 1e9));
}

int PointGrid::bucket_of(long ix, long iy, long iz) const {
  // Teschner et al. 2003's primes.
  const std::uint64_t h = (static_cast<std::uint64_t>(ix) * 73856093ULL) ^
                          (static_cast<std::uint64_t>(iy) * 19349663ULL) ^
                          (static_cast<std::uint64_t>(iz) * 83492791ULL);
  return static_cast<int>(h % static_cast<std::uint64_t>(bucket_begin.size() - 1));
}

void PointGrid::build(const Eigen::Matrix3Xd& points, double cell_size) {
  if (!(cell_size > 0.0) || !std::isfinite(cell_size))
    throw std::invalid_argument("PointGrid: cell size must be a positive finite number, got " +
                                std::to_string(cell_size));
  cell = cell_size;
  const int count = static_cast<int>(points.cols());
  // Twice as many buckets as points: few collisions, and an empty table still has one bucket.
  const size_t table = static_cast<size_t>(2 * count + 1);
  bucket_begin.assign(table + 1, 0);
  std::vector<int> bucket(static_cast<size_t>(count));
  for (int i = 0; i < count; ++i) {
    const int b =
        bucket_of(cell_index(points(0, i)), cell_index(points(1, i)), cell_index(points(2, i)));
    bucket[static_cast<size_t>(i)] = b;
    ++bucket_begin[static_cast<size_t>(b) + 1];
  }
  for (size_t b = 0; b < table; ++b) bucket_begin[b + 1] += bucket_begin[b];
  items.assign(static_cast<size_t>(count), 0);
  std::vector<int> fill(bucket_begin.begin(), bucket_begin.end() - 1);
  for (int i = 0; i < count; ++i)
    items[static_cast<size_t>(fill[static_cast<size_t>(bucket[static_cast<size_t>(i)])]++)] = i;
}

namespace {

// Six times the signed volume of tetrahedron (a, b, c, d).
double orient(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  return (b - a).cross(c - a).dot(d - a);
}

}  // namespace

bool segment_crosses_triangle(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b,
                              const Vec3& c) {
  const double sp = orient(a, b, c, p), sq = orient(a, b, c, q);
  if (!((sp > 0.0 && sq < 0.0) || (sp < 0.0 && sq > 0.0))) return false;
  // The line p-q passes inside the triangle when it sees the three edges turning the same way.
  const double u = orient(p, q, a, b), v = orient(p, q, b, c), w = orient(p, q, c, a);
  return (u > 0.0 && v > 0.0 && w > 0.0) || (u < 0.0 && v < 0.0 && w < 0.0);
}

std::vector<std::array<int, 2>> edge_triangle_crossings(const ClothMesh& mesh,
                                                        const Eigen::Matrix3Xd& x) {
  if (x.cols() != mesh.vertex_count())
    throw std::invalid_argument("edge_triangle_crossings: " + std::to_string(x.cols()) +
                                " positions for a mesh of " + std::to_string(mesh.vertex_count()) +
                                " vertices");
  std::vector<std::array<int, 2>> out;
  const size_t edge_count = mesh.edges.size();
  if (edge_count == 0) return out;
  // Edges by midpoint, in cells as large as the longest edge: an edge that reaches a triangle has
  // its midpoint within half its length of the triangle's box.
  Eigen::Matrix3Xd mid(3, static_cast<Eigen::Index>(edge_count));
  double longest = 0.0;
  for (size_t e = 0; e < edge_count; ++e) {
    const Vec3 p = x.col(mesh.edges[e][0]), q = x.col(mesh.edges[e][1]);
    mid.col(static_cast<Eigen::Index>(e)) = 0.5 * (p + q);
    longest = std::max(longest, (p - q).norm());
  }
  if (!std::isfinite(longest))
    throw std::invalid_argument("edge_triangle_crossings: non-finite positions");
  if (!(longest > 0.0)) return out;
  PointGrid grid;
  grid.build(mid, longest);
  std::vector<int> stamp(edge_count, -1);
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const std::array<int, 3>& tri = mesh.triangles[t];
    const Vec3 a = x.col(tri[0]), b = x.col(tri[1]), c = x.col(tri[2]);
    const Vec3 reach = Vec3::Constant(0.5 * longest);
    const Vec3 lo = a.cwiseMin(b).cwiseMin(c) - reach, hi = a.cwiseMax(b).cwiseMax(c) + reach;
    grid.query(lo, hi, [&](int e) {
      int& seen = stamp[static_cast<size_t>(e)];
      if (seen == static_cast<int>(t)) return;
      seen = static_cast<int>(t);
      const int i = mesh.edges[static_cast<size_t>(e)][0],
                j = mesh.edges[static_cast<size_t>(e)][1];
      if (i == tri[0] || i == tri[1] || i == tri[2] || j == tri[0] || j == tri[1] || j == tri[2])
        return;
      if (segment_crosses_triangle(x.col(i), x.col(j), a, b, c))
        out.push_back({e, static_cast<int>(t)});
    });
  }
  return out;
}

int count_self_intersections(const ClothMesh& mesh, const Eigen::Matrix3Xd& x) {
  return static_cast<int>(edge_triangle_crossings(mesh, x).size());
}

}  // namespace clothdb
