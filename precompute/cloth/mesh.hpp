// Cloth mesh: welded vertices, triangles, unique edges and hinges (pairs of triangles that share
// an edge). Plain data, built once; solvers build their own constraint arrays from it.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <stdexcept>
#include <string>
#include <vector>

namespace clothdb {

using Vec3 = Eigen::Vector3d;

// A hinge is the edge (v0, v1) shared by triangles (v0, v1, a) and (v1, v0, b): the four
// vertices of a discrete-shell bending element (seed 004; Grinspun 2003, Tamstorf & Grinspun 2013).
struct Hinge {
  int v0, v1;  // the shared edge
  int a, b;    // the vertex opposite the edge in each triangle
};

struct ClothMesh {
  Eigen::Matrix3Xd rest;                      // 3 x n rest positions, metres
  std::vector<std::array<int, 3>> triangles;  // counter-clockwise seen from +normal
  std::vector<std::array<int, 2>> edges;      // unique undirected edges, edges[k][0] < edges[k][1]
  std::vector<Hinge> hinges;                  // one per interior edge
  // Grid bookkeeping for generated sheets (used for Provot's flexion springs and by scenes to find
  // corners/edges); -1 when the mesh was not generated as a grid.
  int grid_columns = -1;
  int grid_rows = -1;

  int vertex_count() const { return static_cast<int>(rest.cols()); }
};

// Thrown for meshes the solvers cannot take: non-manifold edges, out-of-range indices, degenerate
// (repeated-vertex) triangles, empty meshes. The message names what is wrong and where.
struct MeshError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Fills edges and hinges from triangles. Throws MeshError when an edge is shared by more than two
// triangles, when two triangles sharing an edge disagree on orientation, or on bad indices.
void build_topology(ClothMesh& mesh);

// Merges vertices closer than `tolerance` (imported meshes duplicate vertices along seams: seed
// 001), drops triangles that become degenerate, and builds topology. `old_to_new` (optional)
// receives, for each input vertex, its index in the welded mesh.
ClothMesh weld_vertices(const Eigen::Matrix3Xd& positions,
                        const std::vector<std::array<int, 3>>& triangles, double tolerance,
                        std::vector<int>* old_to_new = nullptr);

// Rectangular sheet of equilateral triangles (seed 004): `columns` x `rows` nodes in the XY plane,
// rows offset by half an edge, row spacing edge*sqrt(3)/2. Origin at the first node, +y up.
ClothMesh make_equilateral_sheet(int columns, int rows, double edge_length);

// Rectangular sheet of `columns` x `rows` nodes spanning width x height in the XY plane, each quad
// split into two triangles along alternating diagonals (less directional bias than one diagonal).
ClothMesh make_quad_grid(int columns, int rows, double width, double height);

// Index of grid node (column, row) in a generated sheet.
inline int grid_index(const ClothMesh& mesh, int column, int row) {
  return row * mesh.grid_columns + column;
}

// Applies x -> R x + t to the rest positions (e.g. to lay a sheet horizontally).
void transform_mesh(ClothMesh& mesh, const Eigen::Matrix3d& rotation, const Vec3& translation);

// Area of triangle t at the given positions.
double triangle_area(const Eigen::Matrix3Xd& x, const std::array<int, 3>& t);

}  // namespace clothdb
