#include "solvers/self_collision.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

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

// Largest float not above d, and smallest not below it (gaps and boxes must not overstate a
// distance).
float float_below(double d) {
  float f = static_cast<float>(d);
  if (static_cast<double>(f) > d) f = std::nextafter(f, -INFINITY);
  return f;
}
float float_above(double d) {
  float f = static_cast<float>(d);
  if (static_cast<double>(f) < d) f = std::nextafter(f, INFINITY);
  return f;
}

// Boxes of mesh parts (vertices or edges) in a uniform grid of cubic cells hashed into a table of
// 2^k buckets (Teschner et al. 2003, with a multiplicative hash so the table index is a shift, not
// a division). Each entry keeps its cell's key and its box next to each other, so a query reads a
// bucket's entries in a row and skips those of other cells sharing the bucket by key: no stamps,
// and no part is visited twice. An entry is filed under the cell of its box's lower corner; a query
// reaches down by the largest box extent to find the boxes that start below it. Entries of a
// bucket are in index order (a stable counting sort): the same pairs in the same order for any
// thread count.
struct BoxGrid {
  // Boxes in float, rounded outwards (a superset of the double boxes: the exact tests decide): 40
  // bytes an entry instead of 64, and a query reads ~150 of them per edge.
  struct Entry {
    std::uint64_t key;
    int index;
    float lo[3], hi[3];
  };
  double inv_cell = 1.0;
  int shift = 63;
  Vec3 extent = Vec3::Zero();  // largest box extent along each axis
  std::vector<int> bucket_begin;
  std::vector<Entry> entries;

  static long cell_of(double coordinate, double inv_cell) {
    // Clamped to the key's 21 bits per axis (far-apart parts may share a cell: the box test
    // decides).
    return static_cast<long>(std::clamp(std::floor(coordinate * inv_cell), -1048575.0, 1048575.0));
  }
  static std::uint64_t key_of(long ix, long iy, long iz) {
    constexpr long bias = 1L << 20;
    return (static_cast<std::uint64_t>(ix + bias) << 42) |
           (static_cast<std::uint64_t>(iy + bias) << 21) | static_cast<std::uint64_t>(iz + bias);
  }
  std::size_t bucket_of(std::uint64_t key) const {
    return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ULL) >> shift);  // Fibonacci hashing
  }

  // box(i, lo, hi) gives part i's box; count parts; cell > 0.
  template <class Box>
  void build(int count, double cell, Box&& box) {
    inv_cell = 1.0 / cell;
    int bits = 1;
    while ((1L << bits) < 2L * count + 1) ++bits;  // at least twice as many buckets as parts
    shift = 64 - bits;
    const std::size_t table = std::size_t(1) << bits;
    bucket_begin.assign(table + 1, 0);
    std::vector<Entry> unsorted(static_cast<std::size_t>(count));
    extent.setZero();
    for (int i = 0; i < count; ++i) {
      Entry& e = unsorted[static_cast<std::size_t>(i)];
      Vec3 lo, hi;
      box(i, lo, hi);
      extent = extent.cwiseMax(hi - lo);
      for (int k = 0; k < 3; ++k) {
        e.lo[k] = float_below(lo[k]);
        e.hi[k] = float_above(hi[k]);
      }
      e.index = i;
      e.key = key_of(cell_of(lo[0], inv_cell), cell_of(lo[1], inv_cell), cell_of(lo[2], inv_cell));
      ++bucket_begin[bucket_of(e.key) + 1];
    }
    for (std::size_t b = 0; b < table; ++b) bucket_begin[b + 1] += bucket_begin[b];
    entries.resize(static_cast<std::size_t>(count));
    std::vector<int> fill(bucket_begin.begin(), bucket_begin.end() - 1);
    for (const Entry& e : unsorted) entries[static_cast<std::size_t>(fill[bucket_of(e.key)]++)] = e;
  }

  // Calls visit(index) for every part whose box overlaps [lo, hi].
  template <class F>
  void query(const Vec3& lo, const Vec3& hi, F&& visit) const {
    const Vec3 from = lo - extent;
    const long x0 = cell_of(from[0], inv_cell), x1 = cell_of(hi[0], inv_cell);
    const long y0 = cell_of(from[1], inv_cell), y1 = cell_of(hi[1], inv_cell);
    const long z0 = cell_of(from[2], inv_cell), z1 = cell_of(hi[2], inv_cell);
    for (long ix = x0; ix <= x1; ++ix)
      for (long iy = y0; iy <= y1; ++iy)
        for (long iz = z0; iz <= z1; ++iz) {
          const std::uint64_t key = key_of(ix, iy, iz);
          const std::size_t b = bucket_of(key);
          for (int k = bucket_begin[b]; k < bucket_begin[b + 1]; ++k) {
            const Entry& e = entries[static_cast<std::size_t>(k)];
            if (e.key != key || e.lo[0] > hi[0] || e.hi[0] < lo[0] || e.lo[1] > hi[1] ||
                e.hi[1] < lo[1] || e.lo[2] > hi[2] || e.hi[2] < lo[2])
              continue;
            visit(e.index);
          }
        }
  }
};

bool listed(const std::vector<int>& begin, const std::vector<int>& items, int owner, int other) {
  for (int k = begin[static_cast<std::size_t>(owner)];
       k < begin[static_cast<std::size_t>(owner) + 1]; ++k)
    if (items[static_cast<std::size_t>(k)] == other) return true;
  return false;
}

// Every vertex-triangle and edge-edge pair nearer than `reach` at positions x, except pairs that
// share a vertex, pairs of only fixed vertices and the rest neighbours listed in sc (when
// skip_rest_neighbours). Pairs in (triangle, vertex) and (first edge, second edge) order.
void find_pairs(const SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                double reach, bool skip_rest_neighbours, std::vector<std::array<int, 2>>& vt,
                std::vector<std::array<int, 2>>& ee, std::vector<float>* vt_dist = nullptr,
                std::vector<float>* ee_dist = nullptr) {
  const ClothMesh& mesh = model.mesh;
  const double* w = model.inv_mass.data();
  const double reach_sq = reach * reach;
  vt.clear();
  ee.clear();
  if (vt_dist) vt_dist->clear();
  if (ee_dist) ee_dist->clear();
  if (!x.allFinite() || mesh.edges.empty()) return;  // the solver's sanity check reports it
  // Cells about as large as a query's box (a mean edge grown by the reach on both sides): each
  // query reads a few cells of a few parts.
  const double cell = sc.mean_edge + 2.0 * reach;
  const Vec3 grow = Vec3::Constant(reach);

  // Vertex-triangle pairs: each triangle's box grown by the reach, against the vertices.
  BoxGrid grid;
  grid.build(static_cast<int>(x.cols()), cell,
             [&](int i, Vec3& lo, Vec3& hi) { lo = hi = x.col(i); });
  for (std::size_t ti = 0; ti < mesh.triangles.size(); ++ti) {
    const std::array<int, 3>& t = mesh.triangles[ti];
    const int tri = static_cast<int>(ti);
    const Vec3 a = x.col(t[0]), b = x.col(t[1]), c = x.col(t[2]);
    const bool triangle_free = w[t[0]] + w[t[1]] + w[t[2]] > 0.0;
    grid.query(a.cwiseMin(b).cwiseMin(c) - grow, a.cwiseMax(b).cwiseMax(c) + grow, [&](int v) {
      if (v == t[0] || v == t[1] || v == t[2]) return;
      if (!triangle_free && w[v] <= 0.0) return;
      if (skip_rest_neighbours && listed(sc.rest_vt_begin, sc.rest_vt, tri, v)) return;
      const Vec3 p = x.col(v);
      const double d_sq = (closest_on_triangle(p, a, b, c) - p).squaredNorm();
      if (d_sq >= reach_sq) return;
      vt.push_back({tri, v});
      if (vt_dist) vt_dist->push_back(float_below(std::sqrt(d_sq) - sc.thickness));
    });
  }

  // Edge-edge pairs: each edge's box grown by the reach, against the edges' boxes.
  const size_t edge_count = mesh.edges.size();
  grid.build(static_cast<int>(edge_count), cell, [&](int e, Vec3& lo, Vec3& hi) {
    const Vec3 p = x.col(mesh.edges[static_cast<std::size_t>(e)][0]);
    const Vec3 q = x.col(mesh.edges[static_cast<std::size_t>(e)][1]);
    lo = p.cwiseMin(q);
    hi = p.cwiseMax(q);
  });
  // Queried per run of edges that share their first vertex (a vertex's star, about three edges in
  // the mesh's order): one query of the run's box instead of one per edge, so each entry read is
  // tested against the run's edges while in cache (docs/notebook/self_collision.md, "Fourth
  // round").
  for (size_t run = 0; run < edge_count;) {
    size_t run_end = run + 1;
    while (run_end < edge_count && mesh.edges[run_end][0] == mesh.edges[run][0]) ++run_end;
    Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
    for (size_t ei = run; ei < run_end; ++ei) {
      const Vec3 p = x.col(mesh.edges[ei][0]), q = x.col(mesh.edges[ei][1]);
      lo = lo.cwiseMin(p.cwiseMin(q));
      hi = hi.cwiseMax(p.cwiseMax(q));
    }
    grid.query(lo - grow, hi + grow, [&](int e) {
      const std::array<int, 2>& e2 = mesh.edges[static_cast<size_t>(e)];
      const Vec3 p2 = x.col(e2[0]), q2 = x.col(e2[1]);
      const Vec3 lo2 = p2.cwiseMin(q2) - grow, hi2 = p2.cwiseMax(q2) + grow;
      const bool second_free = w[e2[0]] + w[e2[1]] > 0.0;
      for (size_t ei = run; ei < run_end && static_cast<int>(ei) < e; ++ei) {
        const std::array<int, 2>& e1 = mesh.edges[ei];
        const int first = static_cast<int>(ei);
        const Vec3 p1 = x.col(e1[0]), q1 = x.col(e1[1]);
        if ((p1.cwiseMin(q1).array() > hi2.array()).any() ||
            (p1.cwiseMax(q1).array() < lo2.array()).any())
          continue;
        if (e2[0] == e1[0] || e2[0] == e1[1] || e2[1] == e1[0] || e2[1] == e1[1]) continue;
        if (!second_free && w[e1[0]] + w[e1[1]] <= 0.0) continue;
        if (skip_rest_neighbours && listed(sc.rest_ee_begin, sc.rest_ee, first, e)) continue;
        const double d_sq = segment_distance_sq(p1, q1, p2, q2);
        if (d_sq >= reach_sq) continue;
        ee.push_back({first, e});
        if (ee_dist) ee_dist->push_back(float_below(std::sqrt(d_sq) - sc.thickness));
      }
    });
    run = run_end;
  }
}

// Pairs (owner, other) sorted by owner as compressed rows: begin[owner] .. begin[owner + 1].
void to_rows(const std::vector<std::array<int, 2>>& pairs, int owners, std::vector<int>& begin,
             std::vector<int>& items) {
  begin.assign(static_cast<std::size_t>(owners) + 1, 0);
  for (const auto& p : pairs) ++begin[static_cast<std::size_t>(p[0]) + 1];
  for (int o = 0; o < owners; ++o)
    begin[static_cast<std::size_t>(o) + 1] += begin[static_cast<std::size_t>(o)];
  items.assign(pairs.size(), 0);
  std::vector<int> fill(begin.begin(), begin.end() - 1);
  for (const auto& p : pairs)
    items[static_cast<std::size_t>(fill[static_cast<std::size_t>(p[0])]++)] = p[1];
}

// Sorts pairs (and their gaps) by (first, second): a counting sort by the first index (owners of
// them), then insertion sort within each owner's few pairs. The Gauss-Seidel order of the contacts
// is then the pairs' own order, whatever order the grid found them in (the crossings left depend on
// that order: docs/notebook/self_collision.md, "Fourth round").
void sort_pairs(std::vector<std::array<int, 2>>& pairs, std::vector<float>& gaps, int owners,
                std::vector<int>& begin, std::vector<std::array<int, 2>>& pairs_out,
                std::vector<float>& gaps_out) {
  begin.assign(static_cast<std::size_t>(owners) + 1, 0);
  for (const auto& p : pairs) ++begin[static_cast<std::size_t>(p[0]) + 1];
  for (int o = 0; o < owners; ++o)
    begin[static_cast<std::size_t>(o) + 1] += begin[static_cast<std::size_t>(o)];
  pairs_out.resize(pairs.size());
  gaps_out.resize(gaps.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const auto slot = static_cast<std::size_t>(begin[static_cast<std::size_t>(pairs[k][0])]++);
    pairs_out[slot] = pairs[k];
    gaps_out[slot] = gaps[k];
  }
  // begin[o] now holds the end of owner o's run, which is the start of o + 1's; sort each run.
  std::size_t start = 0;
  for (int o = 0; o < owners; ++o) {
    const auto end = static_cast<std::size_t>(begin[static_cast<std::size_t>(o)]);
    for (std::size_t a = start + 1; a < end; ++a)
      for (std::size_t b = a; b > start && pairs_out[b][1] < pairs_out[b - 1][1]; --b) {
        std::swap(pairs_out[b], pairs_out[b - 1]);
        std::swap(gaps_out[b], gaps_out[b - 1]);
      }
    start = end;
  }
  pairs.swap(pairs_out);
  gaps.swap(gaps_out);
}

void build_candidates(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x) {
  find_pairs(sc, model, x, sc.thickness + sc.skin, true, sc.vertex_triangle, sc.edge_edge,
             &sc.vertex_triangle_gap, &sc.edge_edge_gap);
  std::vector<int> begin;
  std::vector<std::array<int, 2>> pairs_out;
  std::vector<float> gaps_out;
  sort_pairs(sc.vertex_triangle, sc.vertex_triangle_gap,
             static_cast<int>(model.mesh.triangles.size()), begin, pairs_out, gaps_out);
  sort_pairs(sc.edge_edge, sc.edge_edge_gap, static_cast<int>(model.mesh.edges.size()), begin,
             pairs_out, gaps_out);
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
  sc.mean_edge = mean_edge;
  // Only pairs nearer than the thickness at rest: leaving out all pairs within thickness + skin at
  // rest (a list of a few hundred pairs instead of 160,000 on the 12k skirt) let pairs two rings
  // apart cross in tight folds: 20 crossings at worst and 615 of 687 frames with any on the 3k
  // skirt over 01_01, against 4 and 71 (docs/notebook/self_collision.md, "Cost, second round").
  sc.rest_gap = thickness;
  // The rest neighbours: every pair nearer than rest_gap in the rest shape, found once.
  std::vector<std::array<int, 2>> vt, ee;
  find_pairs(sc, model, model.mesh.rest, sc.rest_gap, false, vt, ee);
  to_rows(vt, static_cast<int>(model.mesh.triangles.size()), sc.rest_vt_begin, sc.rest_vt);
  to_rows(ee, static_cast<int>(model.mesh.edges.size()), sc.rest_ee_begin, sc.rest_ee);
  return sc;
}

namespace {

// The centre of the box of the displacements x - built: the common motion m the bounds are taken
// relative to (any common vector keeps |d_i - d_j| <= |d_i - m| + |d_j - m|).
Vec3 common_motion(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& built) {
  Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    const Vec3 d = x.col(i) - built.col(i);
    lo = lo.cwiseMin(d);
    hi = hi.cwiseMax(d);
  }
  return 0.5 * (lo + hi);
}

// moved[i] = max(moved[i], |x_i - built_i - m|) for m the common motion of x (common_motion).
void raise_moved(std::vector<double>& moved, const Eigen::Matrix3Xd& x,
                 const Eigen::Matrix3Xd& built, const Vec3& m) {
  for (Eigen::Index i = 0; i < x.cols(); ++i)
    moved[static_cast<std::size_t>(i)] =
        std::max(moved[static_cast<std::size_t>(i)], (x.col(i) - built.col(i) - m).norm());
}

}  // namespace

bool refresh_self_collision(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                            const Eigen::Matrix3Xd& x_start) {
  bool stale = sc.built_at.cols() != x.cols() || sc.moved.size() != std::size_t(x.cols());
  Vec3 m = Vec3::Zero();
  if (!stale && x.cols() > 0) {
    // A pair's distance changes by at most |d_i - d_j| <= |d_i - m| + |d_j - m| for the vertex
    // displacements d since the build and any common m: measured from the centre of the
    // displacements' box, a garment carried along by the body (a walk, a jump) keeps its lists
    // for as long as its shape changes by less than skin / 2. No scratch matrix: this runs every
    // sub-step.
    m = common_motion(x, sc.built_at);
    const double limit = 0.25 * sc.skin * sc.skin;
    double worst = 0.0;
    for (Eigen::Index i = 0; i < x.cols(); ++i)
      worst = std::max(worst, (x.col(i) - sc.built_at.col(i) - m).squaredNorm());
    stale = !(worst <= limit);  // NaN positions rebuild (and the solver's check reports them)
  }
  if (stale) {
    build_candidates(sc, model, x);
    sc.moved.assign(static_cast<std::size_t>(x.cols()), 0.0);
    m = common_motion(x, sc.built_at);
  }
  // The bounds cover the sub-step's start too (its side decides a contact), and the positions left
  // by the constraints after the last pass. (x's common motion is the staleness check's: measured
  // once a sub-step.)
  raise_moved(sc.moved, x, sc.built_at, m);
  raise_moved(sc.moved, x_start, sc.built_at, common_motion(x_start, sc.built_at));
  return stale;
}

int project_self_collision(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x,
                           const Eigen::Matrix3Xd& x_start) {
  const ClothMesh& mesh = model.mesh;
  const double* w = model.inv_mass.data();
  const double h = sc.thickness;
  int contacts = 0;
  // Vertex-triangle: C = sigma (p - q) . n - h >= 0 with q = sum b_k x_k the projection of p onto
  // the triangle's plane, sigma the side p was on at the sub-step's start. Gradients sigma n for p
  // and -sigma b_k n for the corners (the normal's own derivative is left out, as usual for
  // contacts); the PBD step moves each by -C w grad / sum w |grad|^2 (Mueller 2007 eq. 4-5).
  double* moved = sc.moved.data();
  // A vertex moved by `step` moves its pairs' distances by at most |step|.
  auto move = [&](int i, const Vec3& step) {
    x.col(i) += step;
    moved[i] += step.norm();
  };
  for (std::size_t k = 0; k < sc.vertex_triangle.size(); ++k) {
    const std::array<int, 2>& pair = sc.vertex_triangle[k];
    const int v = pair[1];
    const std::array<int, 3>& t = mesh.triangles[static_cast<size_t>(pair[0])];
    // Farther than the thickness now and at the sub-step's start (the distance to a triangle moves
    // by at most its farthest-moved corner's motion): no contact, and no crossing within the
    // sub-step by less than the thickness.
    if (double(sc.vertex_triangle_gap[k]) >
        moved[v] + std::max({moved[t[0]], moved[t[1]], moved[t[2]]}))
      continue;
    // Normals per pair, not cached per triangle: on the 12k skirt about twice as many normals
    // (51k listed pairs, 24k triangles); not measured apart.
    const Vec3 n = unit_normal(x, t), n0 = unit_normal(x_start, t);
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
    move(v, wv * step);
    move(t[0], -(w0 * b0) * step);
    move(t[1], -(w1 * b1) * step);
    move(t[2], -(w2 * b2) * step);
    ++contacts;
  }
  // Edge-edge: C = (P - Q) . n - h >= 0 with P, Q the closest points, n their unit direction, or,
  // when the interior closest points have swapped sides since the sub-step's start (the edges
  // went through each other), the direction they had then. Gradients (1 - s) n, s n, -(1 - t) n,
  // -t n.
  for (std::size_t k = 0; k < sc.edge_edge.size(); ++k) {
    const std::array<int, 2>& pair = sc.edge_edge[k];
    const std::array<int, 2>& e1 = mesh.edges[static_cast<size_t>(pair[0])];
    const std::array<int, 2>& e2 = mesh.edges[static_cast<size_t>(pair[1])];
    if (double(sc.edge_edge_gap[k]) >
        std::max(moved[e1[0]], moved[e1[1]]) + std::max(moved[e2[0]], moved[e2[1]]))
      continue;
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
    move(e1[0], (w0 * (1 - s)) * step);
    move(e1[1], (w1 * s) * step);
    move(e2[0], -(w2 * (1 - t)) * step);
    move(e2[1], -(w3 * t) * step);
    ++contacts;
  }
  return contacts;
}

}  // namespace clothdb
