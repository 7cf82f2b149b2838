#include "cloth/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>

namespace clothdb {

namespace {

std::string triangle_label(size_t t) {
  return "triangle " + std::to_string(t);
}

}  // namespace

void build_topology(ClothMesh& mesh) {
  const int n = mesh.vertex_count();
  if (n == 0 || mesh.triangles.empty()) throw MeshError("mesh has no vertices or no triangles");
  mesh.edges.clear();
  mesh.hinges.clear();

  // For each undirected edge, the triangles that use it and the directed sense in each; a manifold
  // mesh has at most two, and a consistently oriented one uses the edge in opposite senses.
  struct EdgeUse {
    int triangle;
    int from, to;  // directed as in the triangle
    int opposite;  // the triangle's third vertex
  };
  std::map<std::pair<int, int>, std::vector<EdgeUse>> uses;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    for (int k = 0; k < 3; ++k) {
      if (tri[k] < 0 || tri[k] >= n) {
        throw MeshError(triangle_label(t) + " has vertex index " + std::to_string(tri[k]) +
                        " outside [0, " + std::to_string(n) + ")");
      }
    }
    if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) {
      throw MeshError(triangle_label(t) + " repeats a vertex (" + std::to_string(tri[0]) + ", " +
                      std::to_string(tri[1]) + ", " + std::to_string(tri[2]) + ")");
    }
    for (int k = 0; k < 3; ++k) {
      const int a = tri[k], b = tri[(k + 1) % 3], c = tri[(k + 2) % 3];
      uses[{std::min(a, b), std::max(a, b)}].push_back({static_cast<int>(t), a, b, c});
    }
  }
  mesh.edges.reserve(uses.size());
  for (const auto& [key, list] : uses) {
    if (list.size() > 2) {
      throw MeshError("non-manifold edge (" + std::to_string(key.first) + ", " +
                      std::to_string(key.second) + ") is shared by " + std::to_string(list.size()) +
                      " triangles");
    }
    mesh.edges.push_back({key.first, key.second});
    if (list.size() == 2) {
      if (list[0].from == list[1].from) {
        throw MeshError("triangles " + std::to_string(list[0].triangle) + " and " +
                        std::to_string(list[1].triangle) +
                        " are oriented inconsistently across edge (" + std::to_string(key.first) +
                        ", " + std::to_string(key.second) + ")");
      }
      mesh.hinges.push_back({list[0].from, list[0].to, list[0].opposite, list[1].opposite});
    }
  }
}

ClothMesh weld_vertices(const Eigen::Matrix3Xd& positions,
                        const std::vector<std::array<int, 3>>& triangles, double tolerance,
                        std::vector<int>* old_to_new) {
  const int n = static_cast<int>(positions.cols());
  // Hash grid with cell = tolerance: a vertex's duplicates lie in its own or a neighbouring cell.
  const double cell = std::max(tolerance, 1e-12);
  auto key = [&](long i, long j, long k) {
    return (i * 73856093) ^ (j * 19349663) ^ (k * 83492791);
  };
  std::unordered_multimap<long, int> grid;
  std::vector<int> remap(n, -1);
  std::vector<int> kept;
  for (int v = 0; v < n; ++v) {
    const Vec3 p = positions.col(v);
    const long ci = std::lround(std::floor(p.x() / cell));
    const long cj = std::lround(std::floor(p.y() / cell));
    const long ck = std::lround(std::floor(p.z() / cell));
    int found = -1;
    for (long di = -1; di <= 1 && found < 0; ++di)
      for (long dj = -1; dj <= 1 && found < 0; ++dj)
        for (long dk = -1; dk <= 1 && found < 0; ++dk) {
          auto range = grid.equal_range(key(ci + di, cj + dj, ck + dk));
          for (auto it = range.first; it != range.second; ++it) {
            const int w = it->second;  // index into kept
            if ((positions.col(kept[w]) - p).norm() <= tolerance) {
              found = w;
              break;
            }
          }
        }
    if (found < 0) {
      found = static_cast<int>(kept.size());
      kept.push_back(v);
      grid.emplace(key(ci, cj, ck), found);
    }
    remap[v] = found;
  }
  ClothMesh mesh;
  mesh.rest.resize(3, static_cast<Eigen::Index>(kept.size()));
  for (size_t w = 0; w < kept.size(); ++w)
    mesh.rest.col(static_cast<Eigen::Index>(w)) = positions.col(kept[w]);
  for (const auto& t : triangles) {
    for (int k = 0; k < 3; ++k) {
      if (t[k] < 0 || t[k] >= n) {
        throw MeshError("triangle index " + std::to_string(t[k]) + " outside [0, " +
                        std::to_string(n) + ")");
      }
    }
    std::array<int, 3> w{remap[t[0]], remap[t[1]], remap[t[2]]};
    if (w[0] == w[1] || w[1] == w[2] || w[0] == w[2]) continue;  // collapsed by welding
    mesh.triangles.push_back(w);
  }
  build_topology(mesh);
  if (old_to_new) *old_to_new = std::move(remap);
  return mesh;
}

ClothMesh make_equilateral_sheet(int columns, int rows, double edge_length) {
  if (columns < 2 || rows < 2) throw MeshError("equilateral sheet needs at least 2x2 nodes");
  ClothMesh mesh;
  mesh.grid_columns = columns;
  mesh.grid_rows = rows;
  mesh.rest.resize(3, columns * rows);
  const double h = edge_length * std::sqrt(3.0) / 2.0;
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c)
      mesh.rest.col(r * columns + c) =
          Vec3(c * edge_length + (r % 2) * 0.5 * edge_length, r * h, 0);
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c + 1 < columns; ++c) {
      const int a = r * columns + c, b = a + 1, d = a + columns, e = d + 1;
      if (r % 2 == 0) {  // row above is shifted right: triangles (a,b,d) and (b,e,d)
        mesh.triangles.push_back({a, b, d});
        mesh.triangles.push_back({b, e, d});
      } else {  // row above is shifted left: triangles (a,e,d) and (a,b,e)
        mesh.triangles.push_back({a, e, d});
        mesh.triangles.push_back({a, b, e});
      }
    }
  build_topology(mesh);
  return mesh;
}

ClothMesh make_quad_grid(int columns, int rows, double width, double height) {
  if (columns < 2 || rows < 2) throw MeshError("quad grid needs at least 2x2 nodes");
  ClothMesh mesh;
  mesh.grid_columns = columns;
  mesh.grid_rows = rows;
  mesh.rest.resize(3, columns * rows);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c)
      mesh.rest.col(r * columns + c) =
          Vec3(width * c / (columns - 1), height * r / (rows - 1), 0.0);
  for (int r = 0; r + 1 < rows; ++r)
    for (int c = 0; c + 1 < columns; ++c) {
      const int a = r * columns + c, b = a + 1, d = a + columns, e = d + 1;
      if ((r + c) % 2 == 0) {
        mesh.triangles.push_back({a, b, e});
        mesh.triangles.push_back({a, e, d});
      } else {
        mesh.triangles.push_back({a, b, d});
        mesh.triangles.push_back({b, e, d});
      }
    }
  build_topology(mesh);
  return mesh;
}

void transform_mesh(ClothMesh& mesh, const Eigen::Matrix3d& rotation, const Vec3& translation) {
  mesh.rest = (rotation * mesh.rest).colwise() + translation;
}

double triangle_area(const Eigen::Matrix3Xd& x, const std::array<int, 3>& t) {
  const Vec3 e1 = x.col(t[1]) - x.col(t[0]);
  const Vec3 e2 = x.col(t[2]) - x.col(t[0]);
  return 0.5 * e1.cross(e2).norm();
}

}  // namespace clothdb
