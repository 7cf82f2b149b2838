// Where a cloth mesh passes through itself, and the spatial hash that finds near pairs of its
// parts (docs/guide/self_collision.md). The one definition of a self-intersection that every report
// uses (the self_intersections clip metric, `simulate`, `bench character`, the hard cases): a mesh
// edge that crosses the interior of a triangle it does not touch (shares no vertex with). A sheet
// folded through itself shows as such pairs along the line where the two layers cross.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "cloth/mesh.hpp"

namespace clothdb {

// The cell of a uniform grid (cells of size `cell`) that holds `coordinate`, clamped so a runaway
// coordinate cannot overflow the cast (such points share the edge cells).
long grid_cell_index(double coordinate, double cell);
// A grid cell's hash before it is reduced to a table's size (Teschner et al. 2003's primes).
std::uint64_t grid_cell_hash(long ix, long iy, long iz);

// Points in a uniform grid of cubic cells, hashed into a table (Teschner et al. 2003, "Optimized
// Spatial Hashing for Collision Detection of Deformable Objects"): build once, then visit the
// points in every cell a box overlaps. Two cells may share a bucket, so a query can visit a point
// that is not in the box (callers test exactly) and a point twice when the box spans both cells
// (callers that must not see one twice use a stamp). Serial and deterministic: points are listed
// in index order within a bucket.
struct PointGrid {
  double cell = 1.0;
  std::vector<int> bucket_begin;  // table size + 1
  std::vector<int> items;         // point indices, grouped by bucket

  // points: 3 x count. cell > 0.
  void build(const Eigen::Matrix3Xd& points, double cell_size);
  int bucket_of(long ix, long iy, long iz) const;
  // Calls visit(point) for the points of every bucket of the cells the box [lo, hi] overlaps.
  template <class F>
  void query(const Vec3& lo, const Vec3& hi, F&& visit) const {
    const long x0 = cell_index(lo[0]), x1 = cell_index(hi[0]);
    const long y0 = cell_index(lo[1]), y1 = cell_index(hi[1]);
    const long z0 = cell_index(lo[2]), z1 = cell_index(hi[2]);
    for (long ix = x0; ix <= x1; ++ix)
      for (long iy = y0; iy <= y1; ++iy)
        for (long iz = z0; iz <= z1; ++iz) {
          const int b = bucket_of(ix, iy, iz);
          for (int k = bucket_begin[static_cast<size_t>(b)];
               k < bucket_begin[static_cast<size_t>(b) + 1]; ++k)
            visit(items[static_cast<size_t>(k)]);
        }
  }
  long cell_index(double coordinate) const;
};

// True if the segment p-q crosses the triangle a-b-c: its end points lie strictly on opposite
// sides of the triangle's plane and the line through them passes strictly inside the triangle
// (signs of the five orientation determinants). Touching and coplanar cases do not count.
bool segment_crosses_triangle(const Vec3& p, const Vec3& q, const Vec3& a, const Vec3& b,
                              const Vec3& c);

// How much a triangle's box is grown before it is tested against an edge's (m): far above
// rounding, so the box test never decides a case the orientation signs would count. Searches that
// must find exactly edge_triangle_crossings' pairs (the solver's, self_collision.hpp) use it too.
constexpr double kCrossingBoxSlack = 1e-9;

// The search's working arrays (edge boxes, the hashed cells' entries, stamps), kept by a caller
// that searches the same mesh often (the solver, once a step) so that a search allocates nothing:
// fresh arrays of a few MB a call were page faults (1.9 % of all samples of `bench character` on
// the 12k skirt; docs/notebook/self_collision.md, "Eleventh round").
struct CrossingScratch {
  struct Entry {  // an edge's box in floats, moved outwards (self_intersection.cpp)
    float lo[3], hi[3];
    int edge;
  };
  std::vector<std::array<double, 6>> box;
  std::vector<std::array<long, 6>> span;
  std::vector<int> big, begin, fill, stamp, found;
  std::vector<Entry> items;
};

// Pairs (edge index in mesh.edges, triangle index in mesh.triangles) where the edge crosses a
// triangle it shares no vertex with, by triangle, a triangle's by edge. x: 3 x vertex_count
// positions. The scratch, when given, is reused (the result does not depend on it).
std::vector<std::array<int, 2>> edge_triangle_crossings(const ClothMesh& mesh,
                                                        const Eigen::Matrix3Xd& x,
                                                        CrossingScratch* scratch = nullptr);
// Their number: the self_intersections metric of one frame.
int count_self_intersections(const ClothMesh& mesh, const Eigen::Matrix3Xd& x);

}  // namespace clothdb
