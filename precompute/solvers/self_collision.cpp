#include "solvers/self_collision.hpp"

#include <algorithm>
#include <bit>
#include <climits>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <stdexcept>
#include <string>

#include "cloth/closest_point.hpp"
#include "cloth/collision.hpp"
#include "cloth/self_intersection.hpp"

namespace clothdb {

namespace {

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

// Squared distance from vertex v to triangle `tri` at positions x (the build's search lists a pair
// by it, and a partial build computes a kept pair's gap from it).
double vertex_triangle_distance_sq(const ClothMesh& mesh, const Eigen::Matrix3Xd& x, int tri,
                                   int v) {
  const auto& t = mesh.triangles[static_cast<std::size_t>(tri)];
  const Vec3 p = x.col(v);
  return (closest_on_triangle(p, x.col(t[0]), x.col(t[1]), x.col(t[2])).point - p).squaredNorm();
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

// Barycentric coordinates b1, b2 (b0 = 1 - b1 - b2) of the point a + ep in the plane of the
// triangle (a, a + e0, a + e1) (Ericson 2005 sec. 3.4); false for a degenerate triangle.
bool barycentric(const Vec3& e0, const Vec3& e1, const Vec3& ep, double& b1, double& b2) {
  const double d00 = e0.dot(e0), d01 = e0.dot(e1), d11 = e1.dot(e1);
  const double d20 = ep.dot(e0), d21 = ep.dot(e1);
  const double det = d00 * d11 - d01 * d01;
  if (!(det > 0.0)) return false;
  b1 = (d11 * d20 - d01 * d21) / det;
  b2 = (d00 * d21 - d01 * d20) / det;
  return true;
}

// One contact's PBD step (Mueller 2007 eq. 4-5) for a constraint c = C(x) < 0 whose gradient for
// vertex who[k] is coef[k] n: each vertex moves by w coef_k (-c / denom) n, denom = sum w coef^2.
// A vertex near the body (SelfCollision::body_room) is not moved farther into the body than its
// room: the part of its move along the body's normal beyond the room is dropped, and the contact is
// left partly unresolved for the next pass, which moves the other layer (the multiplier is not
// recomputed with that vertex's weight taken out: with every other weight small, as for an
// edge-edge contact whose only free vertex sits at the end of its edge, that divides by a lever
// near 0 and threw the twisted skirt apart; docs/notebook/self_collision.md, "Known gaps").
// `moved` (the contacts' motion bounds; null before the first refresh) grows by each vertex's move.
// False when nothing can move.
bool push_apart(Eigen::Matrix3Xd& x, SelfCollision& sc, const double* w, double* moved,
                const int* who, const double* coef, int count, const Vec3& n, double c) {
  double denom = 0.0;
  for (int k = 0; k < count; ++k) denom += w[who[k]] * coef[k] * coef[k];
  if (!(denom > 0.0)) return false;
  const bool body = sc.body != nullptr && sc.body_room.size() == std::size_t(x.cols());
  // Rounded as the contacts always were (w coef times this), so that where the body's room does
  // not cut a move the frames are those of the code before it.
  const Vec3 unit = (-c / denom) * n;
  for (int k = 0; k < count; ++k) {
    const int v = who[k];
    if (w[v] <= 0.0) continue;
    Vec3 step = (w[v] * coef[k]) * unit;
    double* room = body ? &sc.body_room[std::size_t(v)] : nullptr;
    if (room && std::isnan(*room)) {
      // The vertex's first move in this sub-step: it is where the collision pass left it.
      const NearSurface near =
          nearest_surface(x.col(v), *sc.body, sc.body_pose, kBodyReach * sc.thickness);
      *room = near.distance + kBodyGive * sc.thickness;
      sc.body_normal.col(v) = near.normal;
    }
    if (room && *room < INFINITY) {
      const auto nb = sc.body_normal.col(v);
      const double along = step.dot(nb);
      if (-along > *room) {
        step -= (along + std::max(*room, 0.0)) * nb;
        ++sc.body_cuts;
      }
      *room += step.dot(nb);
    }
    x.col(v) += step;
    if (moved) moved[v] += step.norm();
  }
  return true;
}

// One vertex-triangle PBD step for C = sigma (x_v - q) . n - h < 0, q = sum b_k x_k: gradients
// sigma n for v and -sigma b_k n for the corners (the normal's own derivative left out, as usual
// for contacts).
bool push_vertex_off_triangle(Eigen::Matrix3Xd& x, SelfCollision& sc, const double* w,
                              double* moved, int v, const std::array<int, 3>& t, double b0,
                              double b1, double b2, const Vec3& n, double sigma, double c) {
  const int who[4] = {v, t[0], t[1], t[2]};
  const double coef[4] = {sigma, -sigma * b0, -sigma * b1, -sigma * b2};
  return push_apart(x, sc, w, moved, who, coef, 4, n, c);
}

// Largest float not above d, and smallest not below it (gaps and boxes must not overstate a
// distance).
float float_below(double d) {
  const float f = static_cast<float>(d);
  // The next float down, as std::nextafter(f, -INFINITY) gives it, without its library call or a
  // branch (the rounding goes either way at random; partial builds lower tens of thousands of
  // gaps and slacks a sub-step): bits - 1 above zero, bits + 1 below, the smallest negative float
  // for either zero. Masks, not conditionals: the compiler made the conditionals branches, which
  // mispredicted about every second slack and gap a partial build carried
  // (docs/notebook/self_collision.md, "Fifteenth round: exact watches").
  const auto bits = std::bit_cast<std::uint32_t>(f);
  const std::uint32_t negative = bits >> 31;
  const std::uint32_t zero = 0u - static_cast<std::uint32_t>((bits & 0x7fffffffu) == 0u);
  const std::uint32_t over = 0u - static_cast<std::uint32_t>(static_cast<double>(f) > d);
  const std::uint32_t down = (zero & 0x80000001u) | (~zero & (bits + 2u * negative - 1u));
  return std::bit_cast<float>((over & down) | (~over & bits));
}
bool listed(const std::vector<int>& begin, const std::vector<int>& items, int owner, int other) {
  for (int k = begin[static_cast<std::size_t>(owner)];
       k < begin[static_cast<std::size_t>(owner) + 1]; ++k)
    if (items[static_cast<std::size_t>(k)] == other) return true;
  return false;
}

// ---- The patch hierarchy (self_collision.hpp, top) ----

constexpr int kLeafTriangles = 8;
// Half-angle of the normal cone under which a patch (a disk with a simple projected contour) is
// taken as flat. Below pi/2 it cannot pass through itself (Volino & Magnenat-Thalmann 1994); pi/5
// leaves room for the patch to bend between builds, where the list is reused. pi/3 was tried
// (1.35x instead of about 1.6x the run without on the 12k skirt's frames 1-39) and put back: over
// all of 01_01 the 12k skirt then crossed itself (2 crossings at worst, frame 340, in 14 frames;
// none at pi/5), because a flat patch's own pairs are not listed until the next build
// (docs/notebook/self_collision.md, "Sixth round" and after).
constexpr double kFlatAngle = 3.14159265358979323846 / 5.0;
// cos(pi/5) = (1 + sqrt 5) / 4, as a literal (std::cos is not constexpr here).
constexpr double kFlatCos = 0.80901699437494742410;
// Contours longer than this are not tested (the test is quadratic): such a patch is searched.
constexpr int kMaxContour = 512;

// Splitting a patch so that its halves stay edge-connected (docs/notebook/self_collision.md, "Sixth
// round"): the median split alone left 32 % of the 12k skirt's leaves not edge-connected, so not
// disks, which the flat test cannot skip. The median split is kept (its halves are compact, so
// their boxes are tight) and repaired along the mesh: a half that falls into pieces keeps its
// largest piece and hands the others to the other half, which they touch.
struct PatchSplitter {
  const std::vector<std::array<int, 3>>& neighbours;  // per triangle, across each edge; -1: none
  const std::vector<Vec3>& centre;                    // rest centroids
  std::vector<int> in_patch;  // per triangle, the patch being split that holds it (a stamp)
  std::vector<int> side;  // per triangle of that patch: its half (1, 2), or -piece while counting
  std::vector<int> seen;  // per triangle, the breadth-first walk that reached it (a stamp)
  std::vector<int> queue;
  int walks = 0;

  // Labels the piece of triangles with side == label that holds t0 (breadth-first across edges
  // within patch id) with a new walk stamp; returns its size.
  int walk(int t0, int id, int label) {
    const int stamp = ++walks;
    queue.assign(1, t0);
    seen[static_cast<std::size_t>(t0)] = stamp;
    for (std::size_t head = 0; head < queue.size(); ++head)
      for (int n : neighbours[static_cast<std::size_t>(queue[head])])
        if (n >= 0 && in_patch[static_cast<std::size_t>(n)] == id &&
            side[static_cast<std::size_t>(n)] == label &&
            seen[static_cast<std::size_t>(n)] != stamp) {
          seen[static_cast<std::size_t>(n)] = stamp;
          queue.push_back(n);
        }
    return static_cast<int>(queue.size());
  }

  // Splits order[begin, end) (patch id) into halves, the first returned as order[begin, mid).
  // A connected patch: at the median of the rest centroids along the longest axis of their box
  // (ties by index), then each half in turn (first, then second) keeps its largest piece (the
  // first found on a tie) and hands its other pieces to the other half. A piece handed over touches
  // only the other half within the patch, so after the first half's turn it is one piece, and the
  // second half's pieces join it: both halves are edge-connected. A patch of several pieces (a mesh
  // of several parts): whole pieces, each to the smaller half. Deterministic: only the rest shape,
  // the indices and the fixed order decide.
  int split(std::vector<int>& order, int begin, int end, int id) {
    auto at = [&](int k) { return order[static_cast<std::size_t>(k)]; };
    for (int k = begin; k < end; ++k) {
      in_patch[static_cast<std::size_t>(at(k))] = id;
      side[static_cast<std::size_t>(at(k))] = 0;
    }
    // The patch's pieces, by their first triangle in order.
    std::vector<int> pieces;  // first walk stamp of each piece, and its size
    std::vector<int> sizes;
    for (int k = begin; k < end; ++k) {
      const int t = at(k);
      if (!pieces.empty() && seen[static_cast<std::size_t>(t)] >= pieces.front()) continue;
      sizes.push_back(walk(t, id, 0));
      pieces.push_back(walks);
    }
    if (pieces.size() > 1) {
      std::vector<int> half(pieces.size(), 1);
      int size_a = 0, size_b = 0;
      for (std::size_t c = 0; c < pieces.size(); ++c) {
        half[c] = c == 0 || size_a <= size_b ? 1 : 2;
        (half[c] == 1 ? size_a : size_b) += sizes[c];
      }
      for (int k = begin; k < end; ++k) {
        const int stamp = seen[static_cast<std::size_t>(at(k))];
        side[static_cast<std::size_t>(at(k))] = half[static_cast<std::size_t>(stamp - pieces[0])];
      }
    } else {
      Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
      for (int k = begin; k < end; ++k) {
        lo = lo.cwiseMin(centre[static_cast<std::size_t>(at(k))]);
        hi = hi.cwiseMax(centre[static_cast<std::size_t>(at(k))]);
      }
      int axis = 0;
      (hi - lo).maxCoeff(&axis);
      const int mid = begin + (end - begin) / 2;
      std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                       [&](int a, int b) {
                         const double ca = centre[static_cast<std::size_t>(a)][axis];
                         const double cb = centre[static_cast<std::size_t>(b)][axis];
                         return ca < cb || (ca == cb && a < b);
                       });
      for (int k = begin; k < end; ++k) side[static_cast<std::size_t>(at(k))] = k < mid ? 1 : 2;
      for (int label : {1, 2}) {
        const int first = walks + 1;
        int best = -1, best_size = 0;
        for (int k = begin; k < end; ++k) {
          const int t = at(k);
          if (side[static_cast<std::size_t>(t)] != label ||
              seen[static_cast<std::size_t>(t)] >= first)
            continue;
          const int size = walk(t, id, label);
          if (size > best_size) {
            best_size = size;
            best = walks;
          }
        }
        for (int k = begin; k < end; ++k) {
          const auto t = static_cast<std::size_t>(at(k));
          if (side[t] == label && seen[t] != best) side[t] = 3 - label;
        }
      }
    }
    // The first half's triangles first, each half in its old order.
    const auto mid = std::stable_partition(order.begin() + begin, order.begin() + end, [&](int t) {
      return side[static_cast<std::size_t>(t)] == 1;
    });
    return static_cast<int>(mid - order.begin());
  }
};

// Node `id` over tri_order[begin, end), split along the mesh (PatchSplitter); leaves of at most
// kLeafTriangles triangles.
int build_patch(std::vector<Patch>& patches, std::vector<int>& order, PatchSplitter& splitter,
                int begin, int end) {
  const int id = static_cast<int>(patches.size());
  patches.emplace_back();
  patches.back().tri_begin = begin;
  patches.back().tri_end = end;
  if (end - begin <= kLeafTriangles) return id;
  int mid = splitter.split(order, begin, end, id);
  if (mid == begin || mid == end) mid = begin + (end - begin) / 2;  // never: a split has two sides
  const int left = build_patch(patches, order, splitter, begin, mid);
  const int right = build_patch(patches, order, splitter, mid, end);
  patches[static_cast<std::size_t>(id)].left = left;
  patches[static_cast<std::size_t>(id)].right = right;
  return id;
}

// The hierarchy's topology, once, from the rest shape: the tree, each patch's own vertices and
// edges, whether it is a disk, and its contour.
void make_patches(SelfCollision& sc, const ClothMesh& mesh) {
  const int nt = static_cast<int>(mesh.triangles.size());
  const int nv = mesh.vertex_count();
  const int ne = static_cast<int>(mesh.edges.size());
  sc.patches.clear();
  sc.tri_order.resize(static_cast<std::size_t>(nt));
  std::vector<Vec3> centre(static_cast<std::size_t>(nt));
  for (int t = 0; t < nt; ++t) {
    const auto& tri = mesh.triangles[static_cast<std::size_t>(t)];
    centre[static_cast<std::size_t>(t)] =
        (mesh.rest.col(tri[0]) + mesh.rest.col(tri[1]) + mesh.rest.col(tri[2])) / 3.0;
    sc.tri_order[static_cast<std::size_t>(t)] = t;
  }
  if (nt == 0) return;

  // Each triangle's three edges (by the edges starting at each vertex).
  std::vector<int> from_begin(static_cast<std::size_t>(nv) + 1, 0);
  for (const auto& e : mesh.edges) ++from_begin[static_cast<std::size_t>(e[0]) + 1];
  for (int v = 0; v < nv; ++v)
    from_begin[static_cast<std::size_t>(v) + 1] += from_begin[static_cast<std::size_t>(v)];
  std::vector<int> from(static_cast<std::size_t>(ne));
  {
    std::vector<int> fill(from_begin.begin(), from_begin.end() - 1);
    for (int e = 0; e < ne; ++e)
      from[static_cast<std::size_t>(
          fill[static_cast<std::size_t>(mesh.edges[static_cast<std::size_t>(e)][0])]++)] = e;
  }
  auto edge_of = [&](int a, int b) {
    if (a > b) std::swap(a, b);
    for (int k = from_begin[static_cast<std::size_t>(a)];
         k < from_begin[static_cast<std::size_t>(a) + 1]; ++k)
      if (mesh.edges[static_cast<std::size_t>(from[static_cast<std::size_t>(k)])][1] == b)
        return from[static_cast<std::size_t>(k)];
    throw std::logic_error("self-collision: a triangle's edge is not in the mesh's edges");
  };
  std::vector<std::array<int, 3>> tri_edges(static_cast<std::size_t>(nt));
  for (int t = 0; t < nt; ++t) {
    const auto& tri = mesh.triangles[static_cast<std::size_t>(t)];
    tri_edges[static_cast<std::size_t>(t)] = {edge_of(tri[0], tri[1]), edge_of(tri[1], tri[2]),
                                              edge_of(tri[2], tri[0])};
  }

  // Neighbours across each edge (a manifold edge has at most two triangles), then the tree.
  std::vector<std::array<int, 3>> neighbours(static_cast<std::size_t>(nt), {-1, -1, -1});
  {
    std::vector<int> first_of(static_cast<std::size_t>(ne), -1);
    for (int t = 0; t < nt; ++t)
      for (int j = 0; j < 3; ++j) {
        const auto e = static_cast<std::size_t>(tri_edges[static_cast<std::size_t>(t)][j]);
        const int other = first_of[e];
        if (other < 0) {
          first_of[e] = t;
          continue;
        }
        neighbours[static_cast<std::size_t>(t)][j] = other;
        for (int i = 0; i < 3; ++i)
          if (tri_edges[static_cast<std::size_t>(other)][i] == static_cast<int>(e))
            neighbours[static_cast<std::size_t>(other)][i] = t;
      }
  }
  PatchSplitter splitter{neighbours,
                         centre,
                         std::vector<int>(static_cast<std::size_t>(nt), -1),
                         std::vector<int>(static_cast<std::size_t>(nt), 0),
                         std::vector<int>(static_cast<std::size_t>(nt), 0),
                         {},
                         0};
  build_patch(sc.patches, sc.tri_order, splitter, 0, nt);

  // Owners: each vertex and edge belongs to the first triangle holding it in tri_order; sorted by
  // that position, a patch's own ones are a range.
  std::vector<int> vert_owner(static_cast<std::size_t>(nv), -1),
      edge_owner(static_cast<std::size_t>(ne), -1);
  for (int k = 0; k < nt; ++k) {
    const int t = sc.tri_order[static_cast<std::size_t>(k)];
    for (int j = 0; j < 3; ++j) {
      int& vo =
          vert_owner[static_cast<std::size_t>(mesh.triangles[static_cast<std::size_t>(t)][j])];
      if (vo < 0) vo = k;
      int& eo = edge_owner[static_cast<std::size_t>(tri_edges[static_cast<std::size_t>(t)][j])];
      if (eo < 0) eo = k;
    }
  }
  // Counting sort by owner position; before[k] = how many have an owner before position k.
  auto order_by_owner = [nt](const std::vector<int>& owner, std::vector<int>& order,
                             std::vector<int>& before) {
    before.assign(static_cast<std::size_t>(nt) + 1, 0);
    for (int o : owner)
      if (o >= 0) ++before[static_cast<std::size_t>(o) + 1];
    for (int k = 0; k < nt; ++k)
      before[static_cast<std::size_t>(k) + 1] += before[static_cast<std::size_t>(k)];
    order.assign(static_cast<std::size_t>(before[static_cast<std::size_t>(nt)]), 0);
    std::vector<int> fill(before.begin(), before.end() - 1);
    for (std::size_t i = 0; i < owner.size(); ++i)
      if (owner[i] >= 0)
        order[static_cast<std::size_t>(fill[static_cast<std::size_t>(owner[i])]++)] =
            static_cast<int>(i);
  };
  std::vector<int> vert_before, edge_before;
  order_by_owner(vert_owner, sc.vert_order, vert_before);
  order_by_owner(edge_owner, sc.edge_order, edge_before);

  // For contour_across: each triangle's position in tri_order.
  std::vector<int> tri_position(static_cast<std::size_t>(nt));
  for (int k = 0; k < nt; ++k)
    tri_position[static_cast<std::size_t>(sc.tri_order[static_cast<std::size_t>(k)])] = k;

  // Per patch: own ranges, disk (edge-connected, V - E + F = 1), contour (edges in one of its
  // triangles). Stamps keep it O(triangles) per level.
  std::vector<int> vert_stamp(static_cast<std::size_t>(nv), -1),
      edge_stamp(static_cast<std::size_t>(ne), -1), edge_uses(static_cast<std::size_t>(ne), 0),
      edge_first(static_cast<std::size_t>(ne), -1);
  std::vector<int> parent;  // union-find over the patch's triangles (local positions)
  sc.contour.clear();
  sc.contour_across.clear();
  for (std::size_t id = 0; id < sc.patches.size(); ++id) {
    Patch& p = sc.patches[id];
    p.vert_begin = vert_before[static_cast<std::size_t>(p.tri_begin)];
    p.vert_end = vert_before[static_cast<std::size_t>(p.tri_end)];
    p.edge_begin = edge_before[static_cast<std::size_t>(p.tri_begin)];
    p.edge_end = edge_before[static_cast<std::size_t>(p.tri_end)];
    const int stamp = static_cast<int>(id);
    const int count = p.tri_end - p.tri_begin;
    parent.resize(static_cast<std::size_t>(count));
    for (int i = 0; i < count; ++i) parent[static_cast<std::size_t>(i)] = i;
    auto root = [&](int i) {
      while (parent[static_cast<std::size_t>(i)] != i)
        i = parent[static_cast<std::size_t>(i)] =
            parent[static_cast<std::size_t>(parent[static_cast<std::size_t>(i)])];
      return i;
    };
    int vertices = 0, edges = 0, components = count;
    for (int i = 0; i < count; ++i) {
      const int t = sc.tri_order[static_cast<std::size_t>(p.tri_begin + i)];
      for (int j = 0; j < 3; ++j) {
        const int v = mesh.triangles[static_cast<std::size_t>(t)][j];
        if (vert_stamp[static_cast<std::size_t>(v)] != stamp) {
          vert_stamp[static_cast<std::size_t>(v)] = stamp;
          ++vertices;
        }
        const int e = tri_edges[static_cast<std::size_t>(t)][j];
        if (edge_stamp[static_cast<std::size_t>(e)] != stamp) {
          edge_stamp[static_cast<std::size_t>(e)] = stamp;
          edge_uses[static_cast<std::size_t>(e)] = 1;
          edge_first[static_cast<std::size_t>(e)] = i;
          ++edges;
        } else {
          ++edge_uses[static_cast<std::size_t>(e)];
          const int a = root(i), b = root(edge_first[static_cast<std::size_t>(e)]);
          if (a != b) {
            parent[static_cast<std::size_t>(a)] = b;
            --components;
          }
        }
      }
    }
    p.disk = components == 1 && vertices - edges + count == 1;
    p.contour_begin = static_cast<int>(sc.contour.size());
    for (int i = 0; i < count; ++i) {
      const int t = sc.tri_order[static_cast<std::size_t>(p.tri_begin + i)];
      for (int j = 0; j < 3; ++j) {
        const int e = tri_edges[static_cast<std::size_t>(t)][j];
        if (edge_uses[static_cast<std::size_t>(e)] != 1) continue;
        sc.contour.push_back(e);
        const int across = neighbours[static_cast<std::size_t>(t)][j];
        sc.contour_across.push_back(across < 0 ? -1
                                               : tri_position[static_cast<std::size_t>(across)]);
      }
    }
    p.contour_end = static_cast<int>(sc.contour.size());
  }
  sc.patch_bounds.resize(sc.patches.size());
  // The edges' ends in edge_order, once; the boxes are refit at each build.
  sc.edge_boxes.resize(sc.edge_order.size());
  for (std::size_t i = 0; i < sc.edge_order.size(); ++i) {
    EdgeBox& box = sc.edge_boxes[i];
    box.edge = sc.edge_order[i];
    box.v0 = mesh.edges[static_cast<std::size_t>(box.edge)][0];
    box.v1 = mesh.edges[static_cast<std::size_t>(box.edge)][1];
  }
  sc.triangle_boxes.resize(sc.tri_order.size());
  // Each leaf's vertices (of its triangles, each once), for the test of the watches.
  sc.leaf_vertex_begin.assign(sc.patches.size() + 1, 0);
  sc.leaf_vertices.clear();
  std::vector<int> seen(static_cast<std::size_t>(nv), -1);
  for (std::size_t id = 0; id < sc.patches.size(); ++id) {
    const Patch& p = sc.patches[id];
    if (p.left < 0)
      for (int k = p.tri_begin; k < p.tri_end; ++k)
        for (int v :
             mesh.triangles[static_cast<std::size_t>(sc.tri_order[static_cast<std::size_t>(k)])])
          if (seen[static_cast<std::size_t>(v)] != static_cast<int>(id)) {
            seen[static_cast<std::size_t>(v)] = static_cast<int>(id);
            sc.leaf_vertices.push_back(v);
          }
    sc.leaf_vertex_begin[id + 1] = static_cast<int>(sc.leaf_vertices.size());
  }
}

// Which of two patches a descent over pairs of patches splits (the build's search and the
// crossing search): the larger by triangles of those that can be split, a's on a tie. True: a.
bool split_first(const Patch& pa, const Patch& pb) {
  return pb.left < 0 || (pa.left >= 0 && pa.tri_end - pa.tri_begin >= pb.tri_end - pb.tri_begin);
}

// One past the last patch of `root`'s subtree: the tree is made depth first (build_patch), so a
// subtree is the range of ids [root, subtree_end(root)), its last leaf reached by right children.
int subtree_end(const SelfCollision& sc, int root) {
  while (sc.patches[static_cast<std::size_t>(root)].right >= 0)
    root = sc.patches[static_cast<std::size_t>(root)].right;
  return root + 1;
}

// Boxes and normal cones at positions x of patches [begin, end) into `bounds`, bottom-up (children
// after parents in sc.patches, and a range that holds a patch holds its subtree). A parent's cone
// holds its children's: half-angle max(angle(axis, child axis) + child half-angle). A cone at least
// `flat_angle` wide (cos `flat_cos`) is stored as pi: every test compares a cone with that angle,
// and one that wide decides nothing else (PatchBounds::angle). When `triangle_boxes` is given, the
// leaves' triangle boxes are refit too (the build's; the crossing search has its own bounds and
// angle, hierarchy_crossings).
void refit_bounds(const SelfCollision& sc, const ClothMesh& mesh, const Eigen::Matrix3Xd& x,
                  int begin, int end, double flat_angle, double flat_cos,
                  std::vector<PatchBounds>& bounds, TriangleBox* triangle_boxes) {
  constexpr double pi = 3.14159265358979323846;
  auto angle_between = [](const Vec3& a, const Vec3& b) { return acos_above(a.dot(b)); };
  for (auto id = static_cast<std::size_t>(end); id-- > static_cast<std::size_t>(begin);) {
    const Patch& p = sc.patches[id];
    PatchBounds& b = bounds[id];
    if (p.left < 0) {
      b.lo = Vec3::Constant(INFINITY);
      b.hi = Vec3::Constant(-INFINITY);
      b.normal_sum.setZero();
      Vec3 normals[kLeafTriangles];
      bool degenerate = false;
      for (int k = p.tri_begin; k < p.tri_end; ++k) {
        const auto& t =
            mesh.triangles[static_cast<std::size_t>(sc.tri_order[static_cast<std::size_t>(k)])];
        const Vec3 a = x.col(t[0]), c1 = x.col(t[1]), c2 = x.col(t[2]);
        if (triangle_boxes != nullptr) {
          TriangleBox& tb = triangle_boxes[k];
          for (int i = 0; i < 3; ++i) {
            tb.lo[i] = std::min(std::min(a[i], c1[i]), c2[i]);
            tb.hi[i] = std::max(std::max(a[i], c1[i]), c2[i]);
          }
        }
        b.lo = b.lo.cwiseMin(a.cwiseMin(c1).cwiseMin(c2));
        b.hi = b.hi.cwiseMax(a.cwiseMax(c1).cwiseMax(c2));
        const Vec3 n = (c1 - a).cross(c2 - a);
        b.normal_sum += n;
        const double len = n.norm();
        degenerate = degenerate || !(len > 0.0);
        normals[k - p.tri_begin] = len > 0.0 ? Vec3(n / len) : Vec3::Zero();
      }
      const double len = b.normal_sum.norm();
      b.axis = len > 0.0 ? Vec3(b.normal_sum / len) : Vec3::Zero();
      double lowest = 1.0;
      for (int k = 0; k < p.tri_end - p.tri_begin; ++k)
        lowest = std::min(lowest, normals[k].dot(b.axis));
      // A cone surely at least flat_angle wide (acos_above is within 1e-7 above acos, and the
      // margin keeps this test to cones that are) is stored as pi without its acos.
      b.angle = degenerate || !(len > 0.0) || lowest < flat_cos - 1e-9 ? pi : acos_above(lowest);
    } else {
      const PatchBounds& l = bounds[static_cast<std::size_t>(p.left)];
      const PatchBounds& r = bounds[static_cast<std::size_t>(p.right)];
      b.lo = l.lo.cwiseMin(r.lo);
      b.hi = l.hi.cwiseMax(r.hi);
      b.normal_sum = l.normal_sum + r.normal_sum;
      const double len = b.normal_sum.norm();
      b.axis = len > 0.0 ? Vec3(b.normal_sum / len) : Vec3::Zero();
      // A child's cone at least flat_angle wide makes the parent's so (it holds the child's): pi,
      // without the two acos.
      b.angle = !(len > 0.0) || l.angle >= flat_angle || r.angle >= flat_angle
                    ? pi
                    : std::min(pi, std::max(angle_between(b.axis, l.axis) + l.angle,
                                            angle_between(b.axis, r.axis) + r.angle));
    }
  }
}

// The build's bounds (sc.patch_bounds, against kFlatAngle) and its edge and triangle boxes at
// positions x, for the subtree of patch `root` (0: all).
void refit_patches(SelfCollision& sc, const ClothMesh& mesh, const Eigen::Matrix3Xd& x,
                   int root = 0) {
  const Patch& top = sc.patches[static_cast<std::size_t>(root)];
  for (int i = top.edge_begin; i < top.edge_end; ++i) {
    EdgeBox& box = sc.edge_boxes[static_cast<std::size_t>(i)];
    for (int k = 0; k < 3; ++k) {
      box.lo[k] = std::min(x(k, box.v0), x(k, box.v1));
      box.hi[k] = std::max(x(k, box.v0), x(k, box.v1));
    }
  }
  refit_bounds(sc, mesh, x, root, subtree_end(sc, root), kFlatAngle, kFlatCos, sc.patch_bounds,
               sc.triangle_boxes.data());
}

// Whether segments ab and cd of the plane meet (touching and collinear overlap count: a patch
// whose contour only touches itself is not taken as flat).
bool segments_meet(const double* a, const double* b, const double* c, const double* d) {
  auto orient = [](const double* p, const double* q, const double* r) {
    return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
  };
  if (std::max(a[0], b[0]) < std::min(c[0], d[0]) || std::max(c[0], d[0]) < std::min(a[0], b[0]) ||
      std::max(a[1], b[1]) < std::min(c[1], d[1]) || std::max(c[1], d[1]) < std::min(a[1], b[1]))
    return false;
  const double o1 = orient(a, b, c), o2 = orient(a, b, d);
  const double o3 = orient(c, d, a), o4 = orient(c, d, b);
  return !(o1 * o2 > 0.0) && !(o3 * o4 > 0.0);
}

using ProjectedEdge = FlatTestScratch::ProjectedEdge;

// Whether the contour edges `contour[0, k)`, projected onto the plane normal to `axis`, keep
// apart (edges sharing a vertex excepted). A sweep along the coordinate of the plane in which the
// projected contour is longer (fewer edges overlap there): the edges sorted by their lowest value,
// each tested only against those that start before it ends, and of those only the ones whose
// ranges in the other coordinate meet too. Only the answer is used, and it does not depend on the
// sweep (segments_meet tests both ranges first, and swapping the coordinates negates each
// orientation exactly, so its products keep their signs).
bool contour_is_simple(const ClothMesh& mesh, const Eigen::Matrix3Xd& x, const int* contour, int k,
                       const Vec3& axis, FlatTestScratch& scratch) {
  if (k > kMaxContour) return false;
  // A basis (u, v) of the plane normal to the axis.
  const Vec3 helper = std::abs(axis[0]) < 0.6 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
  const Vec3 u = axis.cross(helper).normalized(), v = axis.cross(u);
  std::vector<ProjectedEdge>& edges = scratch.edges;
  std::vector<std::pair<double, int>>& by_low = scratch.by_low;
  edges.resize(static_cast<std::size_t>(k));
  by_low.resize(static_cast<std::size_t>(k));
  double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
  for (int i = 0; i < k; ++i) {
    const auto& e = mesh.edges[static_cast<std::size_t>(contour[i])];
    const Vec3 a = x.col(e[0]), c = x.col(e[1]);
    ProjectedEdge& s = edges[static_cast<std::size_t>(i)];
    s.a[0] = a.dot(u);
    s.a[1] = a.dot(v);
    s.b[0] = c.dot(u);
    s.b[1] = c.dot(v);
    for (int j = 0; j < 2; ++j) {
      lo[j] = std::min({lo[j], s.a[j], s.b[j]});
      hi[j] = std::max({hi[j], s.a[j], s.b[j]});
    }
    s.v0 = e[0];
    s.v1 = e[1];
  }
  const bool along_v = hi[1] - lo[1] > hi[0] - lo[0];
  for (int i = 0; i < k; ++i) {
    ProjectedEdge& s = edges[static_cast<std::size_t>(i)];
    if (along_v) {
      std::swap(s.a[0], s.a[1]);
      std::swap(s.b[0], s.b[1]);
    }
    by_low[static_cast<std::size_t>(i)] = {std::min(s.a[0], s.b[0]), i};
    s.high = std::max(s.a[0], s.b[0]);
    s.cross_low = std::min(s.a[1], s.b[1]);
    s.cross_high = std::max(s.a[1], s.b[1]);
  }
  std::sort(by_low.begin(), by_low.end());
  for (int a = 0; a < k; ++a) {
    const ProjectedEdge& si =
        edges[static_cast<std::size_t>(by_low[static_cast<std::size_t>(a)].second)];
    for (int b = a + 1; b < k && by_low[static_cast<std::size_t>(b)].first <= si.high; ++b) {
      const ProjectedEdge& sj =
          edges[static_cast<std::size_t>(by_low[static_cast<std::size_t>(b)].second)];
      if ((sj.cross_high < si.cross_low) | (si.cross_high < sj.cross_low) | (si.v0 == sj.v0) |
          (si.v0 == sj.v1) | (si.v1 == sj.v0) | (si.v1 == sj.v1))
        continue;
      if (segments_meet(si.a, si.b, sj.a, sj.b)) return false;
    }
  }
  return true;
}

// Volino & Magnenat-Thalmann 1994's test: a disk whose normals lie within a cone of half-angle
// below flat_angle (< pi/2, so it projects onto the plane normal to the axis without folding
// locally) and whose contour projects onto that plane without crossing itself projects one to
// one: a height field, which cannot pass through itself. `bounds`: the patches' at x (the build's
// sc.patch_bounds against kFlatAngle, or the crossing search's own against kCrossingFlatAngle).
bool patch_is_flat(const SelfCollision& sc, const ClothMesh& mesh, const Eigen::Matrix3Xd& x,
                   const std::vector<PatchBounds>& bounds, double flat_angle, int id,
                   FlatTestScratch& scratch) {
  const Patch& p = sc.patches[static_cast<std::size_t>(id)];
  const PatchBounds& b = bounds[static_cast<std::size_t>(id)];
  if (!p.disk || !(b.angle < flat_angle)) return false;
  return contour_is_simple(mesh, x, sc.contour.data() + p.contour_begin,
                           p.contour_end - p.contour_begin, b.axis, scratch);
}

// Whether patches a and b share an edge (SelfCollision::contour_across).
bool patches_share_an_edge(const SelfCollision& sc, int a, int b) {
  const Patch* p = &sc.patches[static_cast<std::size_t>(a)];
  const Patch* q = &sc.patches[static_cast<std::size_t>(b)];
  if (p->contour_end - p->contour_begin > q->contour_end - q->contour_begin) std::swap(p, q);
  for (int k = p->contour_begin; k < p->contour_end; ++k) {
    const int across = sc.contour_across[static_cast<std::size_t>(k)];
    if ((across >= q->tri_begin) & (across < q->tri_end)) return true;
  }
  return false;
}

// Whether two disks that border each other form a flat disk (the same test as patch_is_flat, on
// their union): a pair of patches split apart high in the tree along a flat stretch of cloth is
// then not descended to the leaves along their border (Volino & Magnenat-Thalmann 1994 treat
// adjacent patches so). The union of two disks is a disk when they share a path: shared edges
// E_s >= 1 and shared vertices V_s = E_s + 1 (chi = 1 + 1 - (V_s - E_s)); its contour is the
// two contours without the shared edges.
bool union_is_flat(const SelfCollision& sc, const ClothMesh& mesh, const Eigen::Matrix3Xd& x,
                   const std::vector<PatchBounds>& bounds, double flat_angle, int a, int b,
                   FlatTestScratch& scratch) {
  const Patch& pa = sc.patches[static_cast<std::size_t>(a)];
  const Patch& pb = sc.patches[static_cast<std::size_t>(b)];
  if (!pa.disk || !pb.disk) return false;
  const PatchBounds& ba = bounds[static_cast<std::size_t>(a)];
  const PatchBounds& bb = bounds[static_cast<std::size_t>(b)];
  // The union's cone holds each part's, so a part's cone at least flat_angle wide decides it
  // before the acos below.
  if (!(ba.angle < flat_angle) || !(bb.angle < flat_angle)) return false;
  // Most pairs tested share no edge (they meet across a fold, or at a corner): the shorter
  // contour's edges across which lies a triangle of the other patch say so before the acos and
  // the stamps below.
  if (!patches_share_an_edge(sc, a, b)) return false;
  const Vec3 sum = ba.normal_sum + bb.normal_sum;
  const double len = sum.norm();
  if (!(len > 0.0)) return false;
  const Vec3 axis = sum / len;
  const double angle =
      std::max(acos_above(axis.dot(ba.axis)) + ba.angle, acos_above(axis.dot(bb.axis)) + bb.angle);
  if (!(angle < flat_angle)) return false;
  std::vector<int>& vertex_stamp = scratch.vertex_stamp;
  std::vector<int>& edge_stamp = scratch.edge_stamp;
  std::vector<int>& union_contour = scratch.union_contour;
  if (vertex_stamp.size() != static_cast<std::size_t>(mesh.vertex_count()) ||
      edge_stamp.size() != mesh.edges.size() || scratch.stamp == INT_MAX) {
    vertex_stamp.assign(static_cast<std::size_t>(mesh.vertex_count()), 0);
    edge_stamp.assign(mesh.edges.size(), 0);
    scratch.stamp = 0;
  }
  const int stamp = ++scratch.stamp;
  for (int k = pa.contour_begin; k < pa.contour_end; ++k) {
    const int e = sc.contour[static_cast<std::size_t>(k)];
    edge_stamp[static_cast<std::size_t>(e)] = stamp;
    for (int v : mesh.edges[static_cast<std::size_t>(e)])
      vertex_stamp[static_cast<std::size_t>(v)] = stamp;
  }
  // Shared vertices counted once each: re-stamped with -stamp when seen from b.
  int shared_vertices = 0, shared_edges = 0;
  union_contour.clear();
  for (int k = pb.contour_begin; k < pb.contour_end; ++k) {
    const int e = sc.contour[static_cast<std::size_t>(k)];
    if (edge_stamp[static_cast<std::size_t>(e)] == stamp) {
      ++shared_edges;
      edge_stamp[static_cast<std::size_t>(e)] = -stamp;
    } else {
      union_contour.push_back(e);
    }
    for (int v : mesh.edges[static_cast<std::size_t>(e)])
      if (vertex_stamp[static_cast<std::size_t>(v)] == stamp) {
        ++shared_vertices;
        vertex_stamp[static_cast<std::size_t>(v)] = -stamp;
      }
  }
  if (shared_edges < 1 || shared_vertices != shared_edges + 1) return false;
  for (int k = pa.contour_begin; k < pa.contour_end; ++k) {
    const int e = sc.contour[static_cast<std::size_t>(k)];
    if (edge_stamp[static_cast<std::size_t>(e)] == stamp) union_contour.push_back(e);
  }
  return contour_is_simple(mesh, x, union_contour.data(), static_cast<int>(union_contour.size()),
                           axis, scratch);
}

// The search over the hierarchy: a patch's own pairs (unless flat), then pairs of patches whose
// boxes come within the reach, down to pairs of leaves, where each own vertex meets the other's
// triangles and each own edge the other's own edges.
struct PairSearch {
  const SelfCollision& sc;
  const ClothMesh& mesh;
  const Eigen::Matrix3Xd& x;
  const double* w;
  double reach, reach_sq, thickness;
  // Squared distance beyond which the exact tests surely leave a pair out: the reach, plus a margin
  // far above their rounding (a few ulps of the largest coordinate; find_pairs).
  double far_sq;
  bool skip_rest, skip_flat;
  std::vector<std::array<int, 2>>& vt;
  std::vector<std::array<int, 2>>& ee;
  std::vector<float>* vt_gap;
  std::vector<float>* ee_gap;
  // At a build, per pair found, the index its region's watch gets: each leaf or pair of leaves
  // searched lists its pairs and then leaves its watch (own, between).
  std::vector<int>* vt_region = nullptr;
  std::vector<int>* ee_region = nullptr;
  FlatTestScratch& flat;
  // At a build: what keeps the lists complete, one watch per region the search settles
  // (PatchWatch); null for the searches that only list pairs.
  std::vector<PatchWatch>* watches = nullptr;
  void watch(int a, int b, double slack, bool found_apart = false) {
    if (watches) watches->push_back({a, b, float_below(slack), found_apart});
  }

  const Patch& patch(int id) const { return sc.patches[static_cast<std::size_t>(id)]; }

  // The largest separation of the two patches' boxes along an axis: a lower bound on the distance
  // between any parts of the two.
  double separation(int a, int b) const {
    const PatchBounds& p = sc.patch_bounds[static_cast<std::size_t>(a)];
    const PatchBounds& q = sc.patch_bounds[static_cast<std::size_t>(b)];
    double sep = -INFINITY;
    for (int k = 0; k < 3; ++k) sep = std::max({sep, p.lo[k] - q.hi[k], q.lo[k] - p.hi[k]});
    return sep;
  }

  bool apart(int a, int b) const {
    const PatchBounds& p = sc.patch_bounds[static_cast<std::size_t>(a)];
    const PatchBounds& q = sc.patch_bounds[static_cast<std::size_t>(b)];
    return (p.lo[0] > q.hi[0] + reach) | (q.lo[0] > p.hi[0] + reach) | (p.lo[1] > q.hi[1] + reach) |
           (q.lo[1] > p.hi[1] + reach) | (p.lo[2] > q.hi[2] + reach) | (q.lo[2] > p.hi[2] + reach);
  }

  void vertex_triangle(int tri, int v) {
    const auto& t = mesh.triangles[static_cast<std::size_t>(tri)];
    if (v == t[0] || v == t[1] || v == t[2]) return;
    if (w[v] <= 0.0 && !(w[t[0]] + w[t[1]] + w[t[2]] > 0.0)) return;
    if (skip_rest && listed(sc.rest_vt_begin, sc.rest_vt, tri, v)) return;
    const double d_sq = vertex_triangle_distance_sq(mesh, x, tri, v);
    if (d_sq >= reach_sq) return;
    vt.push_back({tri, v});
    if (vt_gap) vt_gap->push_back(float_below(std::sqrt(d_sq) - thickness));
    if (vt_region) vt_region->push_back(static_cast<int>(watches->size()));
  }

  // Triangles of leaf `tris` against the vertices owned by leaf `verts`: first the vertices
  // within reach of the first leaf's box, then each triangle against those (at a pair of leaves
  // that only border each other, most of both are out of reach of the other).
  void triangles_vertices(int tris, int verts) {
    const Patch& pt = patch(tris);
    const Patch& pv = patch(verts);
    const PatchBounds& bt = sc.patch_bounds[static_cast<std::size_t>(tris)];
    const double near_lo[3] = {bt.lo[0] - reach, bt.lo[1] - reach, bt.lo[2] - reach};
    const double near_hi[3] = {bt.hi[0] + reach, bt.hi[1] + reach, bt.hi[2] + reach};
    int near[3 * kLeafTriangles];
    int count = 0;
    for (int j = pv.vert_begin; j < pv.vert_end; ++j) {
      const int v = sc.vert_order[static_cast<std::size_t>(j)];
      near[count] = v;  // kept only if inside (no branch)
      count += !outside(&x(0, v), near_lo, near_hi);
    }
    if (count == 0) return;
    for (int k = pt.tri_begin; k < pt.tri_end; ++k) {
      const TriangleBox& box = sc.triangle_boxes[static_cast<std::size_t>(k)];
      const double lo[3] = {box.lo[0] - reach, box.lo[1] - reach, box.lo[2] - reach};
      const double hi[3] = {box.hi[0] + reach, box.hi[1] + reach, box.hi[2] + reach};
      int inside[3 * kLeafTriangles];  // those near vertices within reach of this triangle's box
      int count_inside = 0;
      for (int j = 0; j < count; ++j) {
        inside[count_inside] = near[j];
        count_inside += !outside(&x(0, near[j]), lo, hi);
      }
      for (int j = 0; j < count_inside; ++j)
        vertex_triangle(sc.tri_order[static_cast<std::size_t>(k)], inside[j]);
    }
  }

  // The box tests below combine their six comparisons with | rather than ||: the outcomes are
  // close to random along a leaf pair, and one branch on the result mispredicts less than a chain
  // of six (with ||, 17 % fewer instructions a build bought 2 % of CPU time).
  // Whether point p lies outside the box [lo, hi].
  static bool outside(const double* p, const double* lo, const double* hi) {
    return (p[0] < lo[0]) | (p[0] > hi[0]) | (p[1] < lo[1]) | (p[1] > hi[1]) | (p[2] < lo[2]) |
           (p[2] > hi[2]);
  }
  // Whether box q lies more than `reach` from box p along some axis, with p's grown bounds given.
  static bool apart_along_an_axis(const EdgeBox& q, const double* lo, const double* hi) {
    return (q.hi[0] < lo[0]) | (q.lo[0] > hi[0]) | (q.hi[1] < lo[1]) | (q.lo[1] > hi[1]) |
           (q.hi[2] < lo[2]) | (q.lo[2] > hi[2]);
  }

  void edge_pair(const EdgeBox& p, const EdgeBox& q) {
    if ((p.v0 == q.v0) | (p.v0 == q.v1) | (p.v1 == q.v0) | (p.v1 == q.v1)) return;
    const EdgeBox& e1 = p.edge < q.edge ? p : q;
    const EdgeBox& e2 = p.edge < q.edge ? q : p;
    if (w[e1.v0] + w[e1.v1] <= 0.0 && w[e2.v0] + w[e2.v1] <= 0.0) return;
    // Two segments are at least as far apart as their boxes. Most pairs whose boxes come within
    // the reach along each axis are still farther than it (the boxes of two edges of a leaf pair
    // meet diagonally); those whose boxes are more than far_sq apart are left out before the
    // closest points, which would leave them out too (far_sq's margin is above their rounding).
    double box_sq = 0.0;
    for (int k = 0; k < 3; ++k) {
      const double gap = std::max({e2.lo[k] - e1.hi[k], e1.lo[k] - e2.hi[k], 0.0});
      box_sq += gap * gap;
    }
    if (box_sq > far_sq) return;
    const Vec3 p1 = x.col(e1.v0), q1 = x.col(e1.v1), p2 = x.col(e2.v0), q2 = x.col(e2.v1);
    // And at least as far apart as their projections onto the line through their midpoints (a
    // separating axis that catches the pairs side by side across a wrinkle, which the boxes keep):
    // with c the midpoints' offset, those are room / |c| apart, room = |c|^2 - (|d1.c| + |d2.c|) /
    // 2 for the edge vectors d1, d2. Left out likewise only beyond far_sq; this halves the closest
    // point calls on the 12k skirt.
    const Vec3 c = 0.5 * ((p2 + q2) - (p1 + q1));
    const double cc = c.squaredNorm();
    const double room = cc - 0.5 * (std::abs((q1 - p1).dot(c)) + std::abs((q2 - p2).dot(c)));
    if (room > 0.0 && room * room > far_sq * cc) return;
    if (skip_rest && listed(sc.rest_ee_begin, sc.rest_ee, e1.edge, e2.edge)) return;
    const double d_sq = segment_distance_sq(p1, q1, p2, q2);
    if (d_sq >= reach_sq) return;
    ee.push_back({e1.edge, e2.edge});
    if (ee_gap) ee_gap->push_back(float_below(std::sqrt(d_sq) - thickness));
    if (ee_region) ee_region->push_back(static_cast<int>(watches->size()));
  }

  // Own edges of leaf `of` within reach of leaf `to`'s box, as their boxes.
  int near_edges(int of, int to, const EdgeBox** out) const {
    const Patch& p = patch(of);
    const PatchBounds& b = sc.patch_bounds[static_cast<std::size_t>(to)];
    const double near_lo[3] = {b.lo[0] - reach, b.lo[1] - reach, b.lo[2] - reach};
    const double near_hi[3] = {b.hi[0] + reach, b.hi[1] + reach, b.hi[2] + reach};
    int count = 0;
    for (int i = p.edge_begin; i < p.edge_end; ++i) {
      const EdgeBox& e = sc.edge_boxes[static_cast<std::size_t>(i)];
      out[count] = &e;  // kept only if near (no branch)
      count += !apart_along_an_axis(e, near_lo, near_hi);
    }
    return count;
  }
  // Own edges of leaf a against own edges of leaf b (a == b: each unordered pair once): each
  // side's edges within reach of the other's box first, then the pairs of those whose boxes come
  // within reach of each other.
  void edges_edges(int a, int b) {
    const EdgeBox* from_a[3 * kLeafTriangles];
    const EdgeBox* from_b[3 * kLeafTriangles];
    const int count_a = near_edges(a, b, from_a);
    if (count_a == 0) return;
    const int count_b = a == b ? count_a : near_edges(b, a, from_b);
    const EdgeBox* const* others = a == b ? from_a : from_b;
    for (int i = 0; i < count_a; ++i) {
      const EdgeBox& e = *from_a[i];
      const double lo[3] = {e.lo[0] - reach, e.lo[1] - reach, e.lo[2] - reach};
      const double hi[3] = {e.hi[0] + reach, e.hi[1] + reach, e.hi[2] + reach};
      // The edges within reach of this one's box are gathered first, without a branch.
      int close[3 * kLeafTriangles];
      int count = 0;
      for (int j = a == b ? i + 1 : 0; j < count_b; ++j) {
        close[count] = j;
        count += !apart_along_an_axis(*others[j], lo, hi);
      }
      for (int m = 0; m < count; ++m) edge_pair(e, *others[close[m]]);
    }
  }

  // Each way the search settles a region leaves a watch (PatchWatch): a flat patch or a flat
  // union, a leaf or a pair of leaves searched (the pairs left out were farther than the reach:
  // slack reach - thickness, the skin), and a pair of patches found apart (slack: their boxes'
  // separation less the thickness). Together they cover every vertex-triangle and edge-edge pair
  // once.
  void own(int id) {
    if (skip_flat && patch_is_flat(sc, mesh, x, sc.patch_bounds, kFlatAngle, id, flat)) {
      watch(id, id, reach - thickness);
      return;
    }
    const Patch& p = patch(id);
    if (p.left < 0) {
      triangles_vertices(id, id);
      edges_edges(id, id);
      watch(id, id, reach - thickness);
      return;
    }
    own(p.left);
    own(p.right);
    between(p.left, p.right);
  }

  void between(int a, int b) {
    if (apart(a, b)) {
      if (watches) watch(a, b, separation(a, b) - thickness, true);
      return;
    }
    if (skip_flat && union_is_flat(sc, mesh, x, sc.patch_bounds, kFlatAngle, a, b, flat)) {
      watch(a, b, reach - thickness);
      return;
    }
    const Patch& pa = patch(a);
    const Patch& pb = patch(b);
    if (pa.left < 0 && pb.left < 0) {
      triangles_vertices(a, b);
      triangles_vertices(b, a);
      edges_edges(a, b);
      watch(a, b, reach - thickness);
      return;
    }
    if (split_first(pa, pb)) {
      between(pa.left, b);
      between(pa.right, b);
    } else {
      between(a, pb.left);
      between(a, pb.right);
    }
  }
};

// What a search lists: the pairs, and at a build their gaps, and the watches and each pair's.
struct SearchOut {
  std::vector<std::array<int, 2>>& vt;
  std::vector<std::array<int, 2>>& ee;
  std::vector<float>* vt_gap = nullptr;
  std::vector<float>* ee_gap = nullptr;
  std::vector<PatchWatch>* watches = nullptr;
  std::vector<int>* vt_region = nullptr;
  std::vector<int>* ee_region = nullptr;
};

// Appends to `out` the vertex-triangle and edge-edge pairs nearer than `reach` at positions x (see
// find_self_collision_pairs) of the regions `roots` (a, b): a == b, the pairs within patch a,
// otherwise those between a and b. The patches' bounds must be refit to x over the roots'
// subtrees. Each region searched is settled into regions of its own, each leaving a watch.
void search_regions(const SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                    double reach, bool skip_rest_neighbours, bool skip_flat,
                    const std::vector<std::array<int, 2>>& roots, SearchOut out,
                    FlatTestScratch& flat) {
  // The exact tests' computed distances are within about 1e-15 times the largest coordinate of the
  // true ones (closest_on_segments: points on the segments to a few ulps): 1e-13 of it, and 1 nm,
  // leave a margin of two orders of magnitude.
  const double far = reach + 1e-9 + 1e-13 * x.cwiseAbs().maxCoeff();
  PairSearch search{sc,
                    model.mesh,
                    x,
                    model.inv_mass.data(),
                    reach,
                    reach * reach,
                    sc.thickness,
                    far * far,
                    skip_rest_neighbours,
                    skip_flat,
                    out.vt,
                    out.ee,
                    out.vt_gap,
                    out.ee_gap,
                    out.vt_region,
                    out.ee_region,
                    flat};
  search.watches = out.watches;
  for (const auto& [a, b] : roots) {
    if (a == b)
      search.own(a);
    else
      search.between(a, b);
  }
}

// Every vertex-triangle and edge-edge pair nearer than `reach` at positions x (see
// find_self_collision_pairs); at a build (out's gaps, watches and regions given) with their
// gaps, the watches and each pair's region.
void find_pairs(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x, double reach,
                bool skip_rest_neighbours, bool skip_flat, SearchOut out) {
  out.vt.clear();
  out.ee.clear();
  for (std::vector<float>* gaps : {out.vt_gap, out.ee_gap})
    if (gaps) gaps->clear();
  for (std::vector<int>* regions : {out.vt_region, out.ee_region})
    if (regions) regions->clear();
  if (out.watches) out.watches->clear();
  if (!x.allFinite() || model.mesh.edges.empty() || sc.patches.empty())
    return;  // the solver's sanity check reports it
  refit_patches(sc, model.mesh, x);
  search_regions(sc, model, x, reach, skip_rest_neighbours, skip_flat, {{0, 0}}, out,
                 sc.flat_tests);
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
// them), then insertion sort within each owner's few pairs. The Gauss-Seidel order of the
// contacts is then the pairs' own order, whatever order the grid found them in (the crossings
// left depend on that order: docs/notebook/self_collision.md, "Fourth round").
void sort_pairs(std::vector<std::array<int, 2>>& pairs, std::vector<float>& gaps,
                std::vector<int>& regions, int owners, SelfCollision::RebuildScratch& scratch) {
  std::vector<int>& begin = scratch.order;
  begin.assign(static_cast<std::size_t>(owners) + 1, 0);
  for (const auto& p : pairs) ++begin[static_cast<std::size_t>(p[0]) + 1];
  for (int o = 0; o < owners; ++o)
    begin[static_cast<std::size_t>(o) + 1] += begin[static_cast<std::size_t>(o)];
  std::vector<std::array<int, 2>>& pairs_out = scratch.pairs_out;
  std::vector<float>& gaps_out = scratch.gaps_out;
  std::vector<int>& regions_out = scratch.regions_out;
  pairs_out.resize(pairs.size());
  gaps_out.resize(gaps.size());
  regions_out.resize(regions.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const auto slot = static_cast<std::size_t>(begin[static_cast<std::size_t>(pairs[k][0])]++);
    pairs_out[slot] = pairs[k];
    gaps_out[slot] = gaps[k];
    regions_out[slot] = regions[k];
  }
  // begin[o] now holds the end of owner o's run, which is the start of o + 1's; sort each run.
  std::size_t start = 0;
  for (int o = 0; o < owners; ++o) {
    const auto end = static_cast<std::size_t>(begin[static_cast<std::size_t>(o)]);
    for (std::size_t a = start + 1; a < end; ++a)
      for (std::size_t b = a; b > start && pairs_out[b][1] < pairs_out[b - 1][1]; --b) {
        std::swap(pairs_out[b], pairs_out[b - 1]);
        std::swap(gaps_out[b], gaps_out[b - 1]);
        std::swap(regions_out[b], regions_out[b - 1]);
      }
    start = end;
  }
  pairs.swap(pairs_out);
  gaps.swap(gaps_out);
  regions.swap(regions_out);
}

// A full build: every region searched, the lists sorted.
void build_candidates(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x) {
  find_pairs(sc, model, x, sc.thickness + sc.skin, true, true,
             {sc.vertex_triangle, sc.edge_edge, &sc.vertex_triangle_gap, &sc.edge_edge_gap,
              &sc.watches, &sc.vertex_triangle_region, &sc.edge_edge_region});
  sort_pairs(sc.vertex_triangle, sc.vertex_triangle_gap, sc.vertex_triangle_region,
             static_cast<int>(model.mesh.triangles.size()), sc.rebuild);
  sort_pairs(sc.edge_edge, sc.edge_edge_gap, sc.edge_edge_region,
             static_cast<int>(model.mesh.edges.size()), sc.rebuild);
  sc.built_at = x;
  ++sc.builds;
  sc.regions_settled += static_cast<long>(sc.watches.size());
  sc.full_build_watches = sc.watches.size();
}

// A partial build's lists (rebuild_regions): drops the pairs of the regions searched again
// (renumber[region] < 0), renumbers the others' regions and lowers their gaps by spread[new
// region] (how far the pair's parts may have moved relative to each other since the last build);
// a gap that falls below `exact_below` is raised to the pair's distance at the new reference less
// the thickness, `gap_at(pair)` (rebuild_regions says why both are lower bounds). Then merges in
// the new pairs `found`. Both parts are sorted by (first, second) and no pair is in both (each lies
// in one region), so the list ends sorted as a full build sorts it: the contacts' Gauss-Seidel
// order does not depend on which regions were searched when. Returns how many gaps were computed.
template <class GapAt>
long merge_pairs(std::vector<std::array<int, 2>>& pairs, std::vector<float>& gaps,
                 std::vector<int>& regions, const std::vector<int>& renumber,
                 const std::vector<double>& spread, double exact_below, const GapAt& gap_at,
                 const std::vector<std::array<int, 2>>& found, const std::vector<float>& found_gaps,
                 const std::vector<int>& found_regions, std::vector<int>& order) {
  std::size_t kept = 0;
  long computed = 0;
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const int region = renumber[static_cast<std::size_t>(regions[k])];
    if (region < 0) continue;
    pairs[kept] = pairs[k];
    float gap = float_below(double(gaps[k]) - spread[static_cast<std::size_t>(region)]);
    if (double(gap) < exact_below) {
      gap = std::max(gap, float_below(gap_at(pairs[kept])));
      ++computed;
    }
    gaps[kept] = gap;
    regions[kept] = region;
    ++kept;
  }
  order.resize(found.size());
  for (std::size_t k = 0; k < found.size(); ++k) order[k] = static_cast<int>(k);
  std::sort(order.begin(), order.end(), [&found](int a, int b) {
    return found[static_cast<std::size_t>(a)] < found[static_cast<std::size_t>(b)];
  });
  // Merged from the back, in place.
  const std::size_t total = kept + found.size();
  pairs.resize(total);
  gaps.resize(total);
  regions.resize(total);
  std::size_t i = kept, j = found.size(), k = total;
  while (j > 0) {
    const auto f = static_cast<std::size_t>(order[j - 1]);
    --k;
    if (i > 0 && found[f] < pairs[i - 1]) {
      --i;
      pairs[k] = pairs[i];
      gaps[k] = gaps[i];
      regions[k] = regions[i];
    } else {
      --j;
      pairs[k] = found[f];
      gaps[k] = found_gaps[f];
      regions[k] = found_regions[f];
    }
  }
  return computed;
}

}  // namespace

double acos_above(double c) {
  constexpr double pi = 3.14159265358979323846;
  c = std::clamp(c, -1.0, 1.0);  // NaN stays NaN, and so does the result
  const double a = std::abs(c);
  // Abramowitz & Stegun 4.4.46: acos(a) = sqrt(1 - a) (a0 + a1 a + ... + a7 a^7) + e(a) on [0, 1],
  // |e| <= 2e-8; acos(-a) = pi - acos(a).
  double p = -0.0012624911;
  for (double k : {0.0066700901, -0.0170881256, 0.0308918810, -0.0501743046, 0.0889789874,
                   -0.2145988016, 1.5707963050})
    p = p * a + k;
  const double r = std::sqrt(1.0 - a) * p;
  return (c >= 0.0 ? r : pi - r) + kAcosAbove;
}

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
  sc.exact_gap_below = kExactGapShare * sc.skin;
  // Only pairs nearer than the thickness at rest: leaving out all pairs within thickness + skin at
  // rest (a list of a few hundred pairs instead of 160,000 on the 12k skirt) let pairs two rings
  // apart cross in tight folds: 20 crossings at worst and 615 of 687 frames with any on the 3k
  // skirt over 01_01, against 4 and 71 (docs/notebook/self_collision.md, "Cost, second round").
  sc.rest_gap = thickness;
  make_patches(sc, model.mesh);
  std::vector<char> in_leaf(static_cast<std::size_t>(model.vertex_count()), 0);
  for (int v : sc.leaf_vertices) in_leaf[static_cast<std::size_t>(v)] = 1;
  for (int v = 0; v < model.vertex_count(); ++v)
    if (!in_leaf[static_cast<std::size_t>(v)]) sc.loose_vertices.push_back(v);
  // The rest neighbours: every pair nearer than rest_gap in the rest shape (flat patches searched
  // too), found once.
  std::vector<std::array<int, 2>> vt, ee;
  find_pairs(sc, model, model.mesh.rest, sc.rest_gap, false, false, {vt, ee});
  to_rows(vt, static_cast<int>(model.mesh.triangles.size()), sc.rest_vt_begin, sc.rest_vt);
  to_rows(ee, static_cast<int>(model.mesh.edges.size()), sc.rest_ee_begin, sc.rest_ee);
  return sc;
}

namespace {

// The centre of the box of the displacements x - built: the common motion m the bounds are taken
// relative to (any common vector keeps |d_i - d_j| <= |d_i - m| + |d_j - m|). It runs once in
// every sub-step, so it reads two vertices (six coordinates) as three pairs, each pair's minimum
// and maximum kept apart and the coordinates' own put together at the end: x, y | z, x | y, z
// (docs/notebook/self_collision.md, "Sixteenth round (a)"). Each coordinate's minimum and maximum
// are the same values as a pass vertex by vertex gives (a running std::min or std::max from the
// infinities leaves out a NaN in either order, and the two halves hold no NaN); only the sign of
// a zero may differ, which the bounds' norms do not see.
Vec3 common_motion(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& built) {
  using Pair = Eigen::Array2d;
  const double* xd = x.data();
  const double* bd = built.data();
  const Eigen::Index n = x.cols(), pairs = n / 2;
  Pair lo[3], hi[3];
  for (int j = 0; j < 3; ++j) {
    lo[j] = Pair::Constant(INFINITY);
    hi[j] = Pair::Constant(-INFINITY);
  }
  for (Eigen::Index i = 0; i < pairs; ++i)
    for (int j = 0; j < 3; ++j) {
      const Pair d =
          Eigen::Map<const Pair>(xd + 6 * i + 2 * j) - Eigen::Map<const Pair>(bd + 6 * i + 2 * j);
      lo[j] = lo[j].min(d);
      hi[j] = hi[j].max(d);
    }
  Vec3 low(std::min(lo[0][0], lo[1][1]), std::min(lo[0][1], lo[2][0]),
           std::min(lo[1][0], lo[2][1]));
  Vec3 high(std::max(hi[0][0], hi[1][1]), std::max(hi[0][1], hi[2][0]),
            std::max(hi[1][0], hi[2][1]));
  if (n % 2 == 1) {
    const Vec3 d = x.col(n - 1) - built.col(n - 1);
    low = low.cwiseMin(d);
    high = high.cwiseMax(d);
  }
  return 0.5 * (low + high);
}

// moved[i] = max(moved[i], |x_i - built_i - m|) for m the common motion of x (common_motion).
void raise_moved(std::vector<double>& moved, const Eigen::Matrix3Xd& x,
                 const Eigen::Matrix3Xd& built, const Vec3& m) {
  for (Eigen::Index i = 0; i < x.cols(); ++i)
    moved[static_cast<std::size_t>(i)] =
        std::max(moved[static_cast<std::size_t>(i)], (x.col(i) - built.col(i) - m).norm());
}

// The contacts' motion bounds (SelfCollision::moved) brought up to x and x_start (the sub-step's
// start) while the lists are kept: a pair's distance changes by at most |d_i - d_j| <= |d_i - m| +
// |d_j - m| for the vertex displacements d since the build and any common m, here the centre of
// the displacements' box. The bounds cover the sub-step's start too (its side decides a contact),
// and the positions left by the constraints after the last pass. The box at x is the one
// find_failed_watches has just made (the root patch's, with the loose vertices'), so only x_start
// takes a pass over the vertices before the bounds' own (docs/notebook/self_collision.md,
// "Fifteenth round (b)"), and x - built is the matrix that test left (sc.displacement).
void raise_kept_moved(SelfCollision& sc, const Eigen::Matrix3Xd& x,
                      const Eigen::Matrix3Xd& x_start) {
  const Eigen::Matrix3Xd& built = sc.built_at;
  // x - built, as find_failed_watches has just made it.
  const Eigen::Matrix3Xd& d = sc.displacement;
  Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
  if (!sc.patches.empty()) {
    lo = sc.displacement_box[0][0];
    hi = sc.displacement_box[0][1];
  }
  for (int v : sc.loose_vertices) {
    lo = lo.cwiseMin(d.col(v));
    hi = hi.cwiseMax(d.col(v));
  }
  const Vec3 m = 0.5 * (lo + hi), m_start = common_motion(x_start, built);
  double* moved = sc.moved.data();
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    moved[i] = std::max(moved[i], (d.col(i) - m).norm());
    moved[i] = std::max(moved[i], (x_start.col(i) - built.col(i) - m_start).norm());
  }
}

// Per patch, the box of its vertices' columns of `points` (displacements or positions), bottom-up:
// a leaf's from its vertices, a parent's from its children's (children come after parents). Only
// the patches `needed` marks when it is given (a marked patch's subtree is marked too).
inline void boxes_bottom_up(const SelfCollision& sc, const Eigen::Matrix3Xd& points,
                            std::array<Vec3, 2>* boxes, const char* needed) {
  const Patch* patches = sc.patches.data();
  const int* leaf_begin = sc.leaf_vertex_begin.data();
  const int* leaf_vertices = sc.leaf_vertices.data();
  for (std::size_t id = sc.patches.size(); id-- > 0;) {
    if (needed && !needed[id]) continue;
    const Patch& p = patches[id];
    if (p.left < 0) {
      Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
      const int end = leaf_begin[id + 1];
      for (int k = leaf_begin[id]; k < end; ++k) {
        const int v = leaf_vertices[k];
        lo = lo.cwiseMin(points.col(v));
        hi = hi.cwiseMax(points.col(v));
      }
      boxes[id] = {lo, hi};
    } else {
      const std::array<Vec3, 2>& l = boxes[static_cast<std::size_t>(p.left)];
      const std::array<Vec3, 2>& r = boxes[static_cast<std::size_t>(p.right)];
      boxes[id] = {l[0].cwiseMin(r[0]), l[1].cwiseMax(r[1])};
    }
  }
}

// The watches that fail at x (docs/notebook/self_collision.md, "Ninth round", "Thirteenth round"
// and "Fourteenth round"), into sc.rebuild.failed in their order: those for which the box of the
// displacements since the last build over the vertices of its patches has a diagonal of more than
// the watch's slack. While a watch holds, any two of those vertices have moved by at most the
// slack relative to each other, and a vertex-triangle or edge-edge distance changes by at most the
// largest relative motion of its corners, so a pair of its region left out (farther than
// thickness + slack at the last build) is still farther than the thickness (the Verlet argument
// per region). A patch found flat keeps the bound on its bending (the skin) it had under the old
// test, every vertex within skin / 2 of the garment's common motion, which asked this of every two
// vertices at once: the swinging hem rebuilt the lists of the whole skirt, although only patches
// near each other need to keep together. A watch of two patches found apart also holds while
// their boxes at x are still apart by more than the reach along an axis, as a search at x would
// find them: every vertex-triangle and edge-edge pair between them has its corners in the two
// boxes, so is farther than thickness + skin at x (Verlet's bound is for pairs whose distance can
// only be bounded through their motion; these have a bound at x itself), and the region keeps
// the skin a search leaves for the motion until the next test. Against the thickness alone (no
// skin kept) the twisted skirt went through itself (188,902 summed crossings). On the 12k skirt
// over 01_01 the apart watches of large patches had been the largest failed region at 98 % of the
// full builds (docs/notebook/self_collision.md, "Fifteenth round: exact watches"). Leaves each
// watch's squared diagonal in sc.rebuild.drift (rebuild_regions reads it) and each patch's
// displacement box in sc.displacement_box (raise_kept_moved reads the root's), and x - built in
// sc.displacement (which it reads too).
void find_failed_watches(SelfCollision& sc, const Eigen::Matrix3Xd& x) {
  // This runs in every sub-step, so its loops read the vectors through local pointers: through
  // the vectors themselves, every store (a box, a drift, a failed index) may alias their data
  // pointers in the compiler's view, which then reloads them for each watch
  // (docs/notebook/self_collision.md, "Sixteenth round (a)"). The displacements since the last
  // build are made in one streaming pass: the leaves then gather one column a vertex instead of
  // two, and raise_kept_moved reads them too (the same differences, so the same bits).
  sc.displacement = x - sc.built_at;
  const Eigen::Matrix3Xd& displacement = sc.displacement;
  // Per patch, the box of its vertices' displacements.
  const std::size_t count = sc.patches.size();
  sc.displacement_box.resize(count);
  std::array<Vec3, 2>* dbox = sc.displacement_box.data();
  boxes_bottom_up(sc, displacement, dbox, nullptr);
  // The watches beyond their slack, in their order.
  std::vector<int>& failed = sc.rebuild.failed;
  failed.clear();
  const std::size_t watch_count = sc.watches.size();
  sc.rebuild.drift.resize(watch_count);
  double* drift = sc.rebuild.drift.data();
  const PatchWatch* watches = sc.watches.data();
  const bool apart_boxes = sc.apart_boxes;
  bool ask_boxes = false;
  for (std::size_t k = 0; k < watch_count; ++k) {
    const PatchWatch& wt = watches[k];
    const std::array<Vec3, 2>& a = dbox[static_cast<std::size_t>(wt.a)];
    const std::array<Vec3, 2>& b = dbox[static_cast<std::size_t>(wt.b)];
    const Vec3 span = a[1].cwiseMax(b[1]) - a[0].cwiseMin(b[0]);
    const double slack = wt.slack;
    const double drift_k = span.squaredNorm();
    drift[k] = drift_k;
    // A slack below zero holds nothing: a watch held by its boxes alone through a partial build
    // had more drift than slack to carry over. slack |slack| is slack^2 for a slack of at least
    // zero and below zero otherwise (-0 gives -0, which a drift of 0 passes as 0 >= -0 does), so
    // this is slack >= 0 && drift <= slack^2 without the sign's branch; NaN fails both ways.
    if (drift_k <= slack * std::abs(slack)) continue;
    failed.push_back(static_cast<int>(k));  // NaN positions fail too
    ask_boxes = ask_boxes || (wt.apart && apart_boxes);
  }
  if (!ask_boxes) return;
  // Of those, the watches of patches found apart hold while the boxes of their patches' vertices
  // at x are apart by more than the reach along an axis (PatchWatch). The boxes are made only
  // for the patches such a watch names and their subtrees (36 % of the leaf-vertex entries over
  // the 12k skirt's first 20 frames of 01_01; docs/notebook/self_collision.md, "Sixteenth round
  // (a)"), by the same operations in the same order as a pass over every patch, so the same
  // boxes to the bit. A subtree is a range of ids (subtree_end); one already marked is not
  // marked again.
  std::vector<char>& needed = sc.rebuild.position_needed;
  needed.assign(count, 0);
  for (int f : failed) {
    const PatchWatch& wt = watches[f];
    if (!wt.apart) continue;
    for (int id : {wt.a, wt.b})
      if (!needed[static_cast<std::size_t>(id)])
        std::fill(needed.begin() + id, needed.begin() + subtree_end(sc, id), 1);
  }
  sc.position_box.resize(count);
  std::array<Vec3, 2>* pbox = sc.position_box.data();
  boxes_bottom_up(sc, x, pbox, needed.data());
  const double reach = sc.thickness + sc.skin;
  std::size_t kept = 0;
  for (int f : failed) {
    const PatchWatch& wt = watches[f];
    if (wt.apart) {
      // Every pair between the two patches is at least that far. NaN positions fail (the
      // comparison is false).
      const std::array<Vec3, 2>& p = pbox[static_cast<std::size_t>(wt.a)];
      const std::array<Vec3, 2>& q = pbox[static_cast<std::size_t>(wt.b)];
      if (std::max((p[0] - q[1]).maxCoeff(), (q[0] - p[1]).maxCoeff()) > reach) continue;
    }
    failed[kept++] = f;
  }
  failed.resize(kept);
}

// A partial build at x (docs/notebook/self_collision.md, "Fourteenth round"): the regions of the
// failed watches (sc.rebuild.failed) are searched again, from their patches (a, b) (a == b: from
// a alone), after refitting those patches' subtrees; every other region keeps its pairs and its
// watch. x becomes the one reference of all of them (built_at), and what each kept part promised
// about the old reference is carried over to it by the triangle inequality:
// - A watch that held with slack s, its region's displacements since the old reference spanning a
//   box of diagonal d <= s, keeps slack s - d: a pair of the region left out by its search was
//   farther than thickness + s at the old reference (by induction: at its search, less what every
//   later partial build took off), and has moved by at most d relative to itself since, so is
//   farther than thickness + (s - d) at x; and from x on the region's vertices may move by s - d
//   relative to each other before a pair left out could come within the thickness. For a flat
//   patch or union the slack bounds its bending since it was found flat in the same way. A watch
//   of two patches found apart may have held by its boxes alone (d > s): its slack then falls
//   below zero and holds nothing, and the watch lives only while its boxes stay apart, a test of
//   the positions tested alone that needs nothing carried over.
// - A kept pair's gap g (a lower bound on its distance less the thickness at the old reference)
//   becomes g - d for d its region's drift: its corners are vertices of the region's patches
//   (leaf_vertices holds every corner of a leaf's triangles), so they moved by at most d relative
//   to each other, and a distance to a triangle or segment moves by at most its farthest corner's
//   relative motion. (The contacts' motion bounds would do too, g - moved_p - max moved_q, but
//   they are measured from the garment's common motion, which the swinging hem leaves by far
//   more than its regions drift.) `moved` then restarts from 0 at x, as after a full build.
// - Those drifts add up: a pair kept through n partial builds has lost the sum of n drifts (the
//   path of its region's spread, each the diagonal of a box over the whole region), not its own
//   net approach, and with partial builds in most sub-steps the loosened gaps let many more pairs
//   through the contacts' gap test (docs/notebook/self_collision.md, "Sixteenth round (b)"). So a
//   kept gap that falls below sc.exact_gap_below is raised to the pair's own distance at x less
//   the thickness, rounded down, as a search at x would give it: that is a lower bound on the
//   distance at the new reference by itself, g - d is another, and the larger of two lower bounds
//   is one. The gaps above the level are left as carried: computing every kept pair's distance
//   costs more than the contacts it saves.
// The lists end sorted by (first, second) as a full build sorts them (merge_pairs). Returns false
// (nothing changed) when the failed regions' patches hold more than sc.partial_share of the
// garment's triangles, or x is not finite: then the caller searches everything.
bool rebuild_regions(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x) {
  SelfCollision::RebuildScratch& r = sc.rebuild;
  auto triangles = [&sc](int id) {
    const Patch& p = sc.patches[static_cast<std::size_t>(id)];
    return p.tri_end - p.tri_begin;
  };
  // The regions searched again: the failed ones.
  r.roots.clear();
  long share = 0;
  for (int f : r.failed) {
    const PatchWatch& wt = sc.watches[static_cast<std::size_t>(f)];
    r.roots.push_back({wt.a, wt.b});
    share += triangles(wt.a) + (wt.a != wt.b ? triangles(wt.b) : 0);
  }
  if (!(double(share) <= sc.partial_share * double(model.mesh.triangles.size())) || !x.allFinite())
    return false;
  // The kept watches renumbered, with their slack and drift against x. The drifts' square roots
  // are taken in one vectorised pass first (a scalar sqrt a watch was a third of the loop).
  Eigen::Map<Eigen::ArrayXd> drift(r.drift.data(), static_cast<Eigen::Index>(r.drift.size()));
  drift = drift.sqrt();
  r.renumber.resize(sc.watches.size());
  for (int f : r.failed) r.renumber[static_cast<std::size_t>(f)] = -1;
  std::size_t kept = 0, next_failed = 0;
  for (std::size_t k = 0; k < sc.watches.size(); ++k) {
    if (next_failed < r.failed.size() && r.failed[next_failed] == static_cast<int>(k)) {
      ++next_failed;
      continue;
    }
    const PatchWatch wt = sc.watches[k];
    const double d = r.drift[k];
    sc.watches[kept] = {wt.a, wt.b, float_below(double(wt.slack) - d), wt.apart};
    r.drift[kept] = d;
    r.renumber[k] = static_cast<int>(kept++);
  }
  sc.watches.resize(kept);
  // Each root's subtree refit once: an ancestor (a lower id) first, which covers its descendants.
  r.patches.clear();
  for (const auto& [a, b] : r.roots) {
    r.patches.push_back(a);
    if (b != a) r.patches.push_back(b);
  }
  std::sort(r.patches.begin(), r.patches.end());
  r.refit.assign(sc.patches.size(), 0);
  for (int id : r.patches) {
    if (r.refit[static_cast<std::size_t>(id)]) continue;
    refit_patches(sc, model.mesh, x, id);
    std::fill(r.refit.begin() + id, r.refit.begin() + subtree_end(sc, id), 1);
  }
  r.vertex_triangle.clear();
  r.edge_edge.clear();
  r.vertex_triangle_gap.clear();
  r.edge_edge_gap.clear();
  r.vertex_triangle_region.clear();
  r.edge_edge_region.clear();
  const std::size_t before = sc.watches.size();
  search_regions(sc, model, x, sc.thickness + sc.skin, true, true, r.roots,
                 {r.vertex_triangle, r.edge_edge, &r.vertex_triangle_gap, &r.edge_edge_gap,
                  &sc.watches, &r.vertex_triangle_region, &r.edge_edge_region},
                 sc.flat_tests);
  // Kept pairs' gaps lowered by their regions' drift, the low ones computed at x (above), as the
  // search computes them (PairSearch::vertex_triangle, edge_pair).
  const ClothMesh& mesh = model.mesh;
  const double thickness = sc.thickness;
  auto vertex_triangle_gap = [&](const std::array<int, 2>& pair) {
    return std::sqrt(vertex_triangle_distance_sq(mesh, x, pair[0], pair[1])) - thickness;
  };
  auto edge_edge_gap = [&](const std::array<int, 2>& pair) {
    const auto& e1 = mesh.edges[static_cast<std::size_t>(pair[0])];
    const auto& e2 = mesh.edges[static_cast<std::size_t>(pair[1])];
    return std::sqrt(segment_distance_sq(x.col(e1[0]), x.col(e1[1]), x.col(e2[0]), x.col(e2[1]))) -
           thickness;
  };
  sc.gaps_computed +=
      merge_pairs(sc.vertex_triangle, sc.vertex_triangle_gap, sc.vertex_triangle_region, r.renumber,
                  r.drift, sc.exact_gap_below, vertex_triangle_gap, r.vertex_triangle,
                  r.vertex_triangle_gap, r.vertex_triangle_region, r.order);
  sc.gaps_computed += merge_pairs(sc.edge_edge, sc.edge_edge_gap, sc.edge_edge_region, r.renumber,
                                  r.drift, sc.exact_gap_below, edge_edge_gap, r.edge_edge,
                                  r.edge_edge_gap, r.edge_edge_region, r.order);
  sc.built_at = x;
  ++sc.partial_builds;
  sc.regions_settled += static_cast<long>(sc.watches.size() - before);
  return true;
}

}  // namespace

bool refresh_self_collision(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                            const Eigen::Matrix3Xd& x_start) {
  const bool built = sc.built_at.cols() == x.cols() && sc.moved.size() == std::size_t(x.cols());
  bool partial = false;
  if (built) {
    // The lists stay complete while the regions the searches settled keep together, each within
    // its slack (find_failed_watches); when some do not, only theirs are searched again, unless
    // that is most of the garment (rebuild_regions). The watches are tested before the motion
    // bounds are raised: a build sets the bounds afresh, so they are raised only when the lists
    // are kept.
    find_failed_watches(sc, x);
    if (sc.rebuild.failed.empty()) {
      raise_kept_moved(sc, x, x_start);
      return false;
    }
    // Searching the failed regions only ever splits regions further: once the watches have grown
    // past sc.regrowth times those of the last full build, everything is searched (kRegrowth).
    if (double(sc.watches.size()) <= sc.regrowth * double(sc.full_build_watches))
      partial = rebuild_regions(sc, model, x);
  }
  if (!partial) build_candidates(sc, model, x);  // NaN positions: empty lists (the solver reports)
  // The bounds at x, the build's positions, are 0; the sub-step's start's are raised.
  sc.moved.assign(static_cast<std::size_t>(x.cols()), 0.0);
  raise_moved(sc.moved, x_start, sc.built_at, common_motion(x_start, sc.built_at));
  return true;
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
    const Vec3 n = unit_normal(x, t);
    if (n.isZero()) continue;
    const Vec3 a = x.col(t[0]);
    const double dist = (x.col(v) - a).dot(n);
    // Barycentric coordinates of the projection (Ericson 2005 sec. 3.4); only a vertex over the
    // triangle's interior touches its face (the edges' own pairs take the rest). Tested before the
    // side, which needs the normal at the sub-step's start: of the pairs the gap test lets through
    // on the 12k skirt over 200 frames of 01_01, 0.9 % lie over their triangle (237,842 of 26.8 M;
    // docs/notebook/self_collision.md, "Sixteenth round (b)"). The same pairs are skipped, from the
    // same values, in either order.
    double b1 = 0.0, b2 = 0.0;
    if (!barycentric(x.col(t[1]) - a, x.col(t[2]) - a, x.col(v) - dist * n - a, b1, b2)) continue;
    const double b0 = 1.0 - b1 - b2;
    if (b0 < 0.0 || b1 < 0.0 || b2 < 0.0) continue;
    const Vec3 n0 = unit_normal(x_start, t);
    const double dist_start = (x_start.col(v) - x_start.col(t[0])).dot(n0);
    const double sigma =
        dist_start != 0.0 ? (dist_start > 0.0 ? 1.0 : -1.0) : (dist >= 0.0 ? 1.0 : -1.0);
    const double c = sigma * dist - h;
    if (c >= 0.0) continue;
    if (push_vertex_off_triangle(x, sc, w, moved, v, t, b0, b1, b2, n, sigma, c)) ++contacts;
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
    const int who[4] = {e1[0], e1[1], e2[0], e2[1]};
    const double coef[4] = {1 - s, s, -(1 - t), -t};
    if (push_apart(x, sc, w, moved, who, coef, 4, n, c)) ++contacts;
  }
  return contacts;
}

namespace {

int find_root(std::vector<int>& parent, int i) {
  while (parent[static_cast<std::size_t>(i)] != i) {
    int& p = parent[static_cast<std::size_t>(i)];
    p = parent[static_cast<std::size_t>(p)];  // path halving
    i = p;
  }
  return i;
}

}  // namespace

namespace {

// ---- The crossing search over the patch hierarchy (hierarchy_crossings) ----

// Half-angle of the normal cone under which the crossing search takes a disk whose projected
// contour is simple as flat. Any half-angle below pi/2 makes such a patch a height field over the
// plane normal to the cone's axis (every triangle projects with the same orientation, and a
// boundary projected without crossing bounds a region covered once), so no edge of it crosses a
// triangle of it (Volino & Magnenat-Thalmann 1994). Unlike the build's kFlatAngle it needs no room
// for bending later: the search decides for the positions it tests. 2 pi / 5 (a triangle's
// projection at least 0.31 of its area) against pi/5, pi/4 and pi/3: 22.2 M instructions a call
// on the 12k skirt's frames against 37.4, 32.1 and 25.8 M (docs/notebook/self_collision.md,
// "Fourteenth round (b)").
constexpr double kCrossingFlatAngle = 2.0 * 3.14159265358979323846 / 5.0;
// cos(2 pi / 5) = (sqrt 5 - 1) / 4, as a literal (std::cos is not constexpr here).
constexpr double kCrossingFlatCos = 0.30901699437494742410;

// The descent of hierarchy_crossings. Every (edge, triangle) pair is met once: an edge is owned by
// one leaf (Patch), a triangle lies in one, and the descent reaches each leaf alone (own) and each
// pair of leaves (between) once, unless a patch or union holding both is flat or two patches
// holding them are apart.
struct CrossingSearch {
  const SelfCollision& sc;
  const ClothMesh& mesh;
  const Eigen::Matrix3Xd& x;
  HierarchyCrossingScratch& work;
  FlatTestScratch& flat;

  const Patch& patch(int id) const { return sc.patches[static_cast<std::size_t>(id)]; }
  const PatchBounds& bounds(int id) const { return work.bounds[static_cast<std::size_t>(id)]; }

  // Whether no edge owned by a can meet a triangle of b, nor one owned by b a triangle of a, by
  // edge_triangle_crossings' own box test: an edge's box against a triangle's grown by
  // kCrossingBoxSlack. A patch's box holds the boxes of its edges and triangles, and rounding is
  // monotone (lo <= lo' gives lo - s <= lo' - s), so the test below fails whenever that one
  // would fail for some pair of theirs.
  bool apart(int a, int b) const {
    const PatchBounds& p = bounds(a);
    const PatchBounds& q = bounds(b);
    constexpr double s = kCrossingBoxSlack;
    const bool edges_of_a = (p.hi[0] < q.lo[0] - s) | (p.hi[1] < q.lo[1] - s) |
                            (p.hi[2] < q.lo[2] - s) | (p.lo[0] > q.hi[0] + s) |
                            (p.lo[1] > q.hi[1] + s) | (p.lo[2] > q.hi[2] + s);
    const bool edges_of_b = (q.hi[0] < p.lo[0] - s) | (q.hi[1] < p.lo[1] - s) |
                            (q.hi[2] < p.lo[2] - s) | (q.lo[0] > p.hi[0] + s) |
                            (q.lo[1] > p.hi[1] + s) | (q.lo[2] > p.hi[2] + s);
    return edges_of_a && edges_of_b;
  }

  // The edges owned by leaf `edges` against the triangles of leaf `tris`, each pair as
  // edge_triangle_crossings tests it (the same box test, shared vertices, then
  // segment_crosses_triangle, whose operations are the metric's). The edges whose boxes the box
  // test would keep away from every triangle of the leaf (its box holds theirs) are left out
  // first.
  void test(int edges, int tris) {
    const Patch& pe = patch(edges);
    const Patch& pt = patch(tris);
    const PatchBounds& bt = bounds(tris);
    const Vec3 near_lo = bt.lo - Vec3::Constant(kCrossingBoxSlack),
               near_hi = bt.hi + Vec3::Constant(kCrossingBoxSlack);
    struct Edge {
      Vec3 lo, hi;
      int edge, v0, v1;
    };
    Edge near[3 * kLeafTriangles];
    int count = 0;
    for (int j = pe.edge_begin; j < pe.edge_end; ++j) {
      Edge& n = near[count];
      n.edge = sc.edge_order[static_cast<std::size_t>(j)];
      n.v0 = mesh.edges[static_cast<std::size_t>(n.edge)][0];
      n.v1 = mesh.edges[static_cast<std::size_t>(n.edge)][1];
      const Vec3 p = x.col(n.v0), q = x.col(n.v1);
      n.lo = p.cwiseMin(q);
      n.hi = p.cwiseMax(q);
      count += !((n.hi.array() < near_lo.array()).any() | (n.lo.array() > near_hi.array()).any());
    }
    if (count == 0) return;
    for (int k = pt.tri_begin; k < pt.tri_end; ++k) {
      const int t = sc.tri_order[static_cast<std::size_t>(k)];
      const std::array<int, 3>& tri = mesh.triangles[static_cast<std::size_t>(t)];
      const Vec3 a = x.col(tri[0]), b = x.col(tri[1]), c = x.col(tri[2]);
      const Vec3 lo = a.cwiseMin(b).cwiseMin(c) - Vec3::Constant(kCrossingBoxSlack),
                 hi = a.cwiseMax(b).cwiseMax(c) + Vec3::Constant(kCrossingBoxSlack);
      for (int j = 0; j < count; ++j) {
        const Edge& n = near[j];
        if (n.hi[0] < lo[0] || n.hi[1] < lo[1] || n.hi[2] < lo[2] || n.lo[0] > hi[0] ||
            n.lo[1] > hi[1] || n.lo[2] > hi[2])
          continue;
        if (n.v0 == tri[0] || n.v0 == tri[1] || n.v0 == tri[2] || n.v1 == tri[0] ||
            n.v1 == tri[1] || n.v1 == tri[2])
          continue;
        if (segment_crosses_triangle(x.col(n.v0), x.col(n.v1), a, b, c))
          work.found.push_back({t, n.edge});
      }
    }
  }

  void own(int id) {
    if (patch_is_flat(sc, mesh, x, work.bounds, kCrossingFlatAngle, id, flat)) return;
    const Patch& p = patch(id);
    if (p.left < 0) {
      test(id, id);
      return;
    }
    own(p.left);
    own(p.right);
    between(p.left, p.right);
  }

  void between(int a, int b) {
    if (apart(a, b) || union_is_flat(sc, mesh, x, work.bounds, kCrossingFlatAngle, a, b, flat))
      return;
    const Patch& pa = patch(a);
    const Patch& pb = patch(b);
    if (pa.left < 0 && pb.left < 0) {
      test(a, b);
      test(b, a);
      return;
    }
    if (split_first(pa, pb)) {
      between(pa.left, b);
      between(pa.right, b);
    } else {
      between(a, pb.left);
      between(a, pb.right);
    }
  }
};

}  // namespace

std::vector<std::array<int, 2>> hierarchy_crossings(SelfCollision& sc, const ClothMesh& mesh,
                                                    const Eigen::Matrix3Xd& x) {
  // The grid where the hierarchy cannot answer for it: positions it rejects (wrong count,
  // non-finite: it throws or decides as it does), no hierarchy, or edges no triangle owns (a mesh
  // whose edges are not its triangles'; build_topology's meshes have none).
  if (x.cols() != mesh.vertex_count() || !x.allFinite() || sc.patches.empty() ||
      sc.edge_order.size() != mesh.edges.size())
    return edge_triangle_crossings(mesh, x, &sc.crossing_scratch);
  HierarchyCrossingScratch& work = sc.hierarchy_crossing;
  // Into the search's own array, against its own flat cone: the build's bounds belong to the
  // build's positions.
  work.bounds.resize(sc.patches.size());
  refit_bounds(sc, mesh, x, 0, static_cast<int>(sc.patches.size()), kCrossingFlatAngle,
               kCrossingFlatCos, work.bounds, nullptr);
  work.found.clear();
  CrossingSearch search{sc, mesh, x, work, sc.flat_tests};
  search.own(0);
  // By triangle, then by edge: the metric's order (the untangling's constraints follow it).
  std::sort(work.found.begin(), work.found.end());
  std::vector<std::array<int, 2>> out;
  out.reserve(work.found.size());
  for (const auto& f : work.found) out.push_back({f[1], f[0]});
  return out;
}

int plan_untangle(SelfCollision& sc, const ClothModel& model, const Eigen::Matrix3Xd& x,
                  const Eigen::Matrix3Xd& x_start) {
  const ClothMesh& mesh = model.mesh;
  const double* w = model.inv_mass.data();
  const std::size_t n = static_cast<std::size_t>(x.cols());
  const std::vector<std::array<int, 2>> crossings = hierarchy_crossings(sc, mesh, x);
  if (crossings.empty()) return 0;
  // The pieces the crossing edges cut the mesh into (BWK 2003 sec. 4: the intersection contour
  // bounds a region on each side; the one that went through is the smaller). Union-find over the
  // edges that cross nothing; a piece with a fixed vertex cannot have gone through.
  std::vector<char> cut(mesh.edges.size(), 0);
  for (const auto& c : crossings) cut[static_cast<std::size_t>(c[0])] = 1;
  std::vector<int> parent(n);
  for (std::size_t i = 0; i < n; ++i) parent[i] = static_cast<int>(i);
  for (std::size_t e = 0; e < mesh.edges.size(); ++e) {
    if (cut[e]) continue;
    const int ra = find_root(parent, mesh.edges[e][0]), rb = find_root(parent, mesh.edges[e][1]);
    if (ra != rb) parent[static_cast<std::size_t>(std::max(ra, rb))] = std::min(ra, rb);
  }
  std::vector<int> size(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    int& s = size[static_cast<std::size_t>(find_root(parent, static_cast<int>(i)))];
    if (s == INT_MAX) continue;
    s = w[i] > 0.0 ? s + 1 : INT_MAX;
  }
  for (const auto& c : crossings) {
    const std::array<int, 2>& e = mesh.edges[static_cast<std::size_t>(c[0])];
    const std::array<int, 3>& t = mesh.triangles[static_cast<std::size_t>(c[1])];
    const Vec3 nrm = unit_normal(x, t);
    if (nrm.isZero()) continue;
    const Vec3 o = x.col(t[0]);
    const double d0 = (x.col(e[0]) - o).dot(nrm), d1 = (x.col(e[1]) - o).dot(nrm);
    if (!(d0 * d1 < 0.0)) continue;
    UntangleConstraint u;
    u.triangle = c[1];
    // Both ends on one side of the plane at the step's start: the crossing formed in this step, and
    // the end that is now on the other side (exactly one is, the edge straddling the plane now)
    // goes back to the side both had, whether it moved or the triangle did. Otherwise the pieces
    // decide.
    const Vec3 n_start = unit_normal(x_start, t), o_start = x_start.col(t[0]);
    const double s0 = (x_start.col(e[0]) - o_start).dot(n_start);
    const double s1 = (x_start.col(e[1]) - o_start).dot(n_start);
    int end = 0;
    if (s0 * s1 > 0.0 && !n_start.isZero()) {
      end = s0 * d0 < 0.0 ? 0 : 1;
      u.side = s0 > 0.0 ? 1.0 : -1.0;
    } else {
      const int p0 = size[static_cast<std::size_t>(find_root(parent, e[0]))];
      const int p1 = size[static_cast<std::size_t>(find_root(parent, e[1]))];
      end = p0 != p1 ? (p0 < p1 ? 0 : 1) : (std::abs(d0) <= std::abs(d1) ? 0 : 1);
      u.side = (end == 0 ? d0 : d1) < 0.0 ? 1.0 : -1.0;  // the other end's side
    }
    u.vertex = e[static_cast<std::size_t>(end)];
    // Barycentric coordinates of the point where the edge meets the plane (Ericson 2005 sec.
    // 3.4), clamped into the triangle.
    const Vec3 at = x.col(e[0]) + (d0 / (d0 - d1)) * (x.col(e[1]) - x.col(e[0]));
    double b1 = 0.0, b2 = 0.0;
    if (!barycentric(x.col(t[1]) - o, x.col(t[2]) - o, at - o, b1, b2)) continue;
    b1 = std::max(0.0, b1);
    b2 = std::max(0.0, b2);
    const double b0 = std::max(0.0, 1.0 - b1 - b2), sum = b0 + b1 + b2;
    u.weight = {b0 / sum, b1 / sum, b2 / sum};
    u.reach = model.edge_rest_length[static_cast<std::size_t>(c[0])];
    bool known = false;
    for (UntangleConstraint& old : sc.untangle)
      if (old.vertex == u.vertex && old.triangle == u.triangle) old = u, known = true;
    if (!known) sc.untangle.push_back(u);
  }
  return static_cast<int>(crossings.size());
}

int project_untangle(SelfCollision& sc, const ClothModel& model, Eigen::Matrix3Xd& x) {
  const double* w = model.inv_mass.data();
  int projected = 0;
  for (const UntangleConstraint& u : sc.untangle) {
    const std::array<int, 3>& t = model.mesh.triangles[static_cast<std::size_t>(u.triangle)];
    const Vec3 nrm = unit_normal(x, t);
    if (nrm.isZero()) continue;
    const double b0 = u.weight[0], b1 = u.weight[1], b2 = u.weight[2];
    const Vec3 q = b0 * x.col(t[0]) + b1 * x.col(t[1]) + b2 * x.col(t[2]);
    if ((x.col(u.vertex) - q).squaredNorm() > u.reach * u.reach) continue;
    // As the vertex-triangle contact (project_self_collision), with the side from the plan.
    const double c = u.side * (x.col(u.vertex) - q).dot(nrm) - sc.thickness;
    if (c >= 0.0) continue;
    // The contacts' motion bounds (SelfCollision::moved) cover this move too.
    double* moved = sc.moved.size() == std::size_t(x.cols()) ? sc.moved.data() : nullptr;
    if (push_vertex_off_triangle(x, sc, w, moved, u.vertex, t, b0, b1, b2, nrm, u.side, c))
      ++projected;
  }
  return projected;
}

void find_self_collision_pairs(SelfCollision& sc, const ClothModel& model,
                               const Eigen::Matrix3Xd& x, double reach, bool skip_rest_neighbours,
                               bool skip_flat, std::vector<std::array<int, 2>>& vertex_triangle,
                               std::vector<std::array<int, 2>>& edge_edge) {
  find_pairs(sc, model, x, reach, skip_rest_neighbours, skip_flat, {vertex_triangle, edge_edge});
}

}  // namespace clothdb
