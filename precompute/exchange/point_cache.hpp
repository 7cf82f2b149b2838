// Cloth frames in formats Blender opens directly: the garment's topology as an OBJ and its motion
// as a PC2 point cache (Blender: import the OBJ, add a Mesh Cache modifier, pick the .pc2).
// PC2 keeps every frame in one small binary file that Blender reads and writes natively, which an
// OBJ sequence (one file per frame, hundreds of files) does not.
#pragma once

#include <array>
#include <stdexcept>
#include <string>
#include <vector>

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

struct ObjMesh {
  std::vector<float> positions;               // 3 per vertex
  std::vector<std::array<int, 3>> triangles;  // 0-based; polygons are fanned into triangles
  std::vector<std::string> groups;            // per vertex: the last `g`/`o` name it was used in
};
// Reads `v` and `f` lines (v, v/vt, v/vt/vn, v//vn, negative indices); throws ExchangeError with
// the file and line number on malformed input.
ObjMesh read_obj(const std::string& path);

}  // namespace clothdb
