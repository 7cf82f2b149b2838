#include "cloth/self_intersection.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace clothdb {

long grid_cell_index(double coordinate, double cell) {
  return static_cast<long>(std::clamp(std::floor(coordinate / cell), -1e9, 1e9));
}

std::uint64_t grid_cell_hash(long ix, long iy, long iz) {
  return (static_cast<std::uint64_t>(ix) * 73856093ULL) ^
         (static_cast<std::uint64_t>(iy) * 19349663ULL) ^
         (static_cast<std::uint64_t>(iz) * 83492791ULL);
}

long PointGrid::cell_index(double coordinate) const {
  return grid_cell_index(coordinate, cell);
}

int PointGrid::bucket_of(long ix, long iy, long iz) const {
  return static_cast<int>(grid_cell_hash(ix, iy, iz) %
                          static_cast<std::uint64_t>(bucket_begin.size() - 1));
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

// segment_crosses_triangle with n = (b - a) x (c - a) given: the same operations in the same order
// (orient(a, b, c, d) is that cross product dotted with d - a), so the same answer to the bit, with
// the triangle's cross product made once for all the edges it is tested against.
bool crosses_with_normal(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b, const Vec3& c,
                         const Vec3& n) {
  const double sp = n.dot(p - a), sq = n.dot(q - a);
  if (!((sp > 0.0 && sq < 0.0) || (sp < 0.0 && sq > 0.0))) return false;
  // The line p-q passes inside the triangle when it sees the three edges turning the same way.
  const double u = orient(p, q, a, b), v = orient(p, q, b, c), w = orient(p, q, c, a);
  return (u > 0.0 && v > 0.0 && w > 0.0) || (u < 0.0 && v < 0.0 && w < 0.0);
}

}  // namespace

bool segment_crosses_triangle(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b,
                              const Vec3& c) {
  return crosses_with_normal(p, q, a, b, c, (b - a).cross(c - a));
}

std::vector<std::array<int, 2>> edge_triangle_crossings(const ClothMesh& mesh,
                                                        const Eigen::Matrix3Xd& x,
                                                        CrossingScratch* scratch) {
  if (x.cols() != mesh.vertex_count())
    throw std::invalid_argument("edge_triangle_crossings: " + std::to_string(x.cols()) +
                                " positions for a mesh of " + std::to_string(mesh.vertex_count()) +
                                " vertices");
  std::vector<std::array<int, 2>> out;
  const size_t edge_count = mesh.edges.size();
  if (edge_count == 0) return out;
  CrossingScratch local;
  CrossingScratch& work = scratch != nullptr ? *scratch : local;
  // Each edge is filed in every cell its box overlaps, the cells as large as the mean edge, and
  // each triangle visits the cells its box overlaps: an edge that crosses a triangle holds the
  // crossing point in its box and the triangle's, so it is met. (Edges by midpoint in cells as
  // large as the longest edge, as before, handed each triangle many more edges: 283 M against 80 M
  // instructions a call on the 12k long skirt's frames 30-190 of 01_01, callgrind;
  // docs/notebook/self_collision.md, "Eighth round".) An edge over more than kMaxCells cells (a
  // runaway vertex) is tested against every triangle instead.
  constexpr long kMaxCells = 64;
  // Raw pointers into the scratch: through references to its vectors every access reloaded the
  // vector's data pointer (the stores below may alias it).
  work.box.resize(edge_count);
  std::array<double, 6>* const box = work.box.data();
  double longest = 0.0, total = 0.0;
  for (size_t e = 0; e < edge_count; ++e) {
    const Vec3 p = x.col(mesh.edges[e][0]), q = x.col(mesh.edges[e][1]);
    const Vec3 lo = p.cwiseMin(q), hi = p.cwiseMax(q);
    box[e] = {lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]};
    const double length = (p - q).norm();
    longest = std::max(longest, length);
    total += length;
  }
  if (!std::isfinite(longest))
    throw std::invalid_argument("edge_triangle_crossings: non-finite positions");
  if (!(longest > 0.0)) return out;
  const double cell = total / static_cast<double>(edge_count);
  // Any cell index that does not decrease with the coordinate files an edge and a triangle whose
  // boxes share a point in a common cell, which is all the search needs: the coordinate times the
  // inverse cell, clamped, then truncated and moved down for negatives (a floor without a call;
  // grid_cell_index's division and floor were 10 % of the instructions).
  const double inverse_cell = 1.0 / cell;
  auto cell_of = [inverse_cell](double c) {
    const double v = std::clamp(c * inverse_cell, -1e9, 1e9);
    const long i = static_cast<long>(v);
    return i - static_cast<long>(v < static_cast<double>(i));
  };
  // Cells hashed (grid_cell_hash, then a multiplicative hash into 2^bits buckets).
  work.span.resize(edge_count);
  std::array<long, 6>* const span = work.span.data();
  std::vector<int>& big = work.big;
  big.clear();
  size_t entries = 0;
  for (size_t e = 0; e < edge_count; ++e) {
    auto& s = span[e];
    for (int k = 0; k < 3; ++k) {
      s[static_cast<size_t>(k)] = cell_of(box[e][static_cast<size_t>(k)]);
      s[static_cast<size_t>(k) + 3] = cell_of(box[e][static_cast<size_t>(k) + 3]);
    }
    const long nx = s[3] - s[0] + 1, ny = s[4] - s[1] + 1, nz = s[5] - s[2] + 1;
    const long cells =
        nx > kMaxCells || ny > kMaxCells || nz > kMaxCells ? kMaxCells + 1 : nx * ny * nz;
    if (cells > kMaxCells) {
      big.push_back(static_cast<int>(e));
      s[0] = 1, s[3] = 0;  // filed nowhere
    } else {
      entries += static_cast<size_t>(cells);
    }
  }
  int bits = 4;
  while ((size_t{1} << bits) < 2 * entries) ++bits;
  const int shift = 64 - bits;
  auto bucket_of = [shift](long ix, long iy, long iz) {
    return static_cast<size_t>((grid_cell_hash(ix, iy, iz) * 0x9E3779B97F4A7C15ULL) >> shift);
  };
  const size_t table = size_t{1} << bits;
  // Each entry holds its edge's box in floats moved outwards by far more than a float's rounding
  // (a millionth of the coordinate), so a test on them never rejects what the exact box keeps,
  // and a query reads its buckets in a row.
  using Entry = CrossingScratch::Entry;
  auto down = [](double d) { return static_cast<float>(d - (std::abs(d) * 1e-6 + 1e-20)); };
  auto up = [](double d) { return static_cast<float>(d + (std::abs(d) * 1e-6 + 1e-20)); };
  work.begin.assign(table + 1, 0);
  int* const begin = work.begin.data();
  work.items.resize(entries);
  Entry* const items = work.items.data();
  auto for_cells = [&](const std::array<long, 6>& s, auto&& f) {
    for (long ix = s[0]; ix <= s[3]; ++ix)
      for (long iy = s[1]; iy <= s[4]; ++iy)
        for (long iz = s[2]; iz <= s[5]; ++iz) f(bucket_of(ix, iy, iz));
  };
  for (size_t e = 0; e < edge_count; ++e) for_cells(span[e], [&](size_t b) { ++begin[b + 1]; });
  for (size_t b = 0; b < table; ++b) begin[b + 1] += begin[b];
  {
    work.fill.assign(work.begin.begin(), work.begin.end() - 1);
    int* const fill = work.fill.data();
    for (size_t e = 0; e < edge_count; ++e) {
      const auto& eb = box[e];
      const Entry entry{{down(eb[0]), down(eb[1]), down(eb[2])},
                        {up(eb[3]), up(eb[4]), up(eb[5])},
                        static_cast<int>(e)};
      for_cells(span[e], [&](size_t b) { items[static_cast<size_t>(fill[b]++)] = entry; });
    }
  }
  work.stamp.assign(edge_count, -1);
  int* const stamp = work.stamp.data();
  std::vector<int>& found = work.found;
  found.clear();
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const std::array<int, 3>& tri = mesh.triangles[t];
    const Vec3 a = x.col(tri[0]), b = x.col(tri[1]), c = x.col(tri[2]);
    const Vec3 n = (b - a).cross(c - a);
    const Vec3 lo = a.cwiseMin(b).cwiseMin(c) - Vec3::Constant(kCrossingBoxSlack),
               hi = a.cwiseMax(b).cwiseMax(c) + Vec3::Constant(kCrossingBoxSlack);
    found.clear();
    // Exact (double) box test, then the vertices, then the orientation signs.
    auto visit = [&](int e) {
      int& seen = stamp[static_cast<size_t>(e)];
      if (seen == static_cast<int>(t)) return;
      seen = static_cast<int>(t);
      const auto& eb = box[static_cast<size_t>(e)];
      if (eb[3] < lo[0] || eb[4] < lo[1] || eb[5] < lo[2] || eb[0] > hi[0] || eb[1] > hi[1] ||
          eb[2] > hi[2])
        return;
      const int i = mesh.edges[static_cast<size_t>(e)][0],
                j = mesh.edges[static_cast<size_t>(e)][1];
      if (i == tri[0] || i == tri[1] || i == tri[2] || j == tri[0] || j == tri[1] || j == tri[2])
        return;
      if (crosses_with_normal(x.col(i), x.col(j), a, b, c, n)) found.push_back(e);
    };
    const std::array<long, 6> query = {cell_of(lo[0]), cell_of(lo[1]), cell_of(lo[2]),
                                       cell_of(hi[0]), cell_of(hi[1]), cell_of(hi[2])};
    const float flo[3] = {down(lo[0]), down(lo[1]), down(lo[2])};
    const float fhi[3] = {up(hi[0]), up(hi[1]), up(hi[2])};
    for_cells(query, [&](size_t bucket) {
      for (int k = begin[bucket]; k < begin[bucket + 1]; ++k) {
        const Entry& en = items[static_cast<size_t>(k)];
        if (en.hi[0] < flo[0] || en.hi[1] < flo[1] || en.hi[2] < flo[2] || en.lo[0] > fhi[0] ||
            en.lo[1] > fhi[1] || en.lo[2] > fhi[2])
          continue;
        visit(en.edge);
      }
    });
    for (int e : big) visit(e);
    // The buckets hand the edges out in hash order: a triangle's crossings by edge index, so the
    // list (and the untangling's constraints made from it) does not depend on the table's size.
    std::sort(found.begin(), found.end());
    for (int e : found) out.push_back({e, static_cast<int>(t)});
  }
  return out;
}

int count_self_intersections(const ClothMesh& mesh, const Eigen::Matrix3Xd& x) {
  return static_cast<int>(edge_triangle_crossings(mesh, x).size());
}

}  // namespace clothdb
