// The artist's garment mesh (db::ArtistMesh, rows.hpp): the one place its render mesh is derived
// and its consistency is checked, shared by the precompute that builds it, the writer that stores
// it, `db check`, and the runtime that draws it (docs/DATABASE.md, "The artist's mesh").
#pragma once

#include <string>
#include <vector>

#include "database/format/rows.hpp"
#include "database/format/status.hpp"

namespace clothdb::db {

// Fills render_vertices and render_triangles from the faces, corners, UVs and normals: render
// vertex i < vertex_count() is artist vertex i with its first corner's UV and normal, every other
// (vertex, UV, normal) combination is appended in order of first use; each face is fanned from its
// first corner.
void derive_render_mesh(ArtistMesh* mesh);

// The artist-vertex triangles of the render triangulation (3 per triangle, in the same order): what
// the simulation mesh is welded from.
std::vector<uint32_t> artist_triangles(const ArtistMesh& mesh);

// The mesh a procedural garment (or a file written before the artist's mesh was stored) stands
// for: the simulation mesh itself, its triangles as faces, no UVs or normals, the identity map.
ArtistMesh identity_artist_mesh(const Garment& garment);

// One frame from simulation order to artist order: out (3 floats per artist vertex) = the map's
// weighted sum of `simulation` (3 floats per simulation vertex).
void to_artist_order(const ArtistMesh& mesh, const float* simulation, float* out);

// One frame back from artist order to simulation order (an edited PC2 of the artist's mesh): each
// simulation vertex is the mean of the artist vertices mapped onto it by index (a weld or a seam
// gives several, at one place). False, naming the first such vertex in `why`, when a simulation
// vertex has no artist vertex mapped onto it by index (a remeshed simulation mesh: import the
// simulation-order cache instead).
bool to_simulation_order(const ArtistMesh& mesh, uint32_t simulation_vertices, const float* artist,
                         float* out, std::string* why);

// Checks sizes, index ranges (simulation vertices against `simulation_vertices`), finite
// positions and weights that sum to 1, and that the stored render mesh is the one derived from the
// faces. Corrupt, with the first problem named after `path`.
Status check_artist_mesh(const ArtistMesh& mesh, uint32_t simulation_vertices,
                         const std::string& path, Error* err);

}  // namespace clothdb::db
