// Cloth frames in formats Blender opens directly: the garment's topology as an OBJ and its motion
// as a PC2 point cache (Blender: import the OBJ, add a Mesh Cache modifier, pick the .pc2).
// PC2 keeps every frame in one small binary file that Blender reads and writes natively, which an
// OBJ sequence (one file per frame, hundreds of files) does not.
#pragma once

#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "database/format/rows.hpp"

namespace clothdb {

struct ExchangeError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Frames are stored frame-major as float x, y, z per vertex (the database codec's layout).
struct PointCache {
  int vertex_count = 0;
  int frame_count = 0;
  float start_frame = 0.0f;
  float sample_rate = 1.0f;      // frames between samples, as Blender writes it (1 = every frame)
  std::vector<float> positions;  // frame_count * vertex_count * 3
};

// PC2 layout: "POINTCACHE2\0", int32 version 1, int32 points, float start frame, float sample
// rate, int32 samples, then samples * points * 3 little-endian float32.
void write_pc2(const std::string& path, const PointCache& cache);
// Throws ExchangeError naming the file and what is wrong (signature, version, sizes, truncation).
PointCache read_pc2(const std::string& path);

// Writes vertices and triangles (1-based indices) as a Wavefront OBJ, with an `o` name.
void write_obj(const std::string& path, const std::string& object_name, const float* positions,
               int vertex_count, const std::vector<std::array<int, 3>>& triangles);

// An OBJ face group: the faces after a `g` or `o` line (its name) that use one material
// (`usemtl`, "" before any).
struct ObjGroup {
  std::string name, material;
  std::vector<uint32_t> faces;
};

// The artist's mesh (db::ArtistMesh) with `positions` (3 floats per artist vertex): `v` in its
// vertex order, `vt` and `vn` as stored, its faces as given with their UVs and normals, `g` and
// `usemtl` where the face group changes. What Blender imports as the artist's own mesh.
void write_artist_obj(const std::string& path, const std::string& object_name,
                      const float* positions, const db::ArtistMesh& mesh);
// A simulation-order cache in the artist's vertex order (db::to_artist_order, frame by frame).
PointCache artist_order(const db::ArtistMesh& mesh, const PointCache& simulation);
// An artist-order or simulation-order cache in simulation order: by its vertex count (the
// artist's mesh, else the simulation's; equal counts mean the identity map). Throws ExchangeError
// naming `what` and both counts otherwise, or when the map cannot be inverted.
PointCache simulation_order(const db::ArtistMesh& mesh, uint32_t simulation_vertices,
                            const PointCache& cache, const std::string& what);

struct ObjMesh {
  std::vector<float> positions;               // 3 per vertex
  std::vector<std::array<int, 3>> triangles;  // 0-based; polygons are fanned into triangles
  std::vector<std::string> groups;            // per vertex: the last `g`/`o` name it was used in
  // The faces as given: corners per face, and per corner its vertex, UV and normal (0-based;
  // kObjNone where the corner names none). corner_uvs / corner_normals are empty when no corner
  // names one.
  std::vector<float> uvs;      // 2 per `vt` (a third coordinate is dropped)
  std::vector<float> normals;  // 3 per `vn`
  std::vector<uint32_t> face_sizes, corners, corner_uvs, corner_normals;
  std::vector<ObjGroup> face_groups;  // in order of first use
};
constexpr uint32_t kObjNone = 0xFFFFFFFFu;
// Reads `v`, `vt`, `vn`, `f`, `g`, `o` and `usemtl` lines (faces v, v/vt, v/vt/vn, v//vn, negative
// indices); throws ExchangeError with the file and line number on malformed input. Non-finite
// vertex coordinates ("nan", "inf") are read as such: the caller reports them with the vertex.
ObjMesh read_obj(const std::string& path);

}  // namespace clothdb
