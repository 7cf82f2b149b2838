#include "exchange/point_cache.hpp"

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

#include "database/format/artist_mesh.hpp"
#include "report/output.hpp"

namespace clothdb {

namespace {

constexpr char kSignature[12] = {'P', 'O', 'I', 'N', 'T', 'C', 'A', 'C', 'H', 'E', '2', '\0'};

template <typename T>
void put(std::string& out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));  // x86-64 and ARM are little-endian, as PC2 is
  out.append(bytes, sizeof(T));
}

template <typename T>
T get(const std::string& in, size_t offset) {
  T value;
  std::memcpy(&value, in.data() + offset, sizeof(T));
  return value;
}

}  // namespace

void write_pc2(const std::string& path, const PointCache& cache) {
  const size_t floats = static_cast<size_t>(cache.vertex_count) * cache.frame_count * 3;
  if (cache.positions.size() != floats)
    throw ExchangeError(path + ": point cache has " + std::to_string(cache.positions.size()) +
                        " floats, expected " + std::to_string(floats));
  std::string out;
  out.reserve(32 + floats * 4);
  out.append(kSignature, 12);
  put<std::int32_t>(out, 1);
  put<std::int32_t>(out, cache.vertex_count);
  put<float>(out, cache.start_frame);
  put<float>(out, cache.sample_rate);
  put<std::int32_t>(out, cache.frame_count);
  out.append(reinterpret_cast<const char*>(cache.positions.data()), floats * 4);
  write_file_atomic(path, out);
}

PointCache read_pc2(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ExchangeError(path + ": cannot open");
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.size() < 32)
    throw ExchangeError(path + ": too short for a PC2 header (" + std::to_string(bytes.size()) +
                        " bytes)");
  if (std::memcmp(bytes.data(), kSignature, 12) != 0)
    throw ExchangeError(path + ": not a PC2 point cache (signature is not POINTCACHE2)");
  const auto version = get<std::int32_t>(bytes, 12);
  if (version != 1)
    throw ExchangeError(path + ": PC2 version " + std::to_string(version) +
                        " is not supported (expected 1)");
  PointCache cache;
  cache.vertex_count = get<std::int32_t>(bytes, 16);
  cache.start_frame = get<float>(bytes, 20);
  cache.sample_rate = get<float>(bytes, 24);
  cache.frame_count = get<std::int32_t>(bytes, 28);
  if (cache.vertex_count <= 0 || cache.frame_count < 0)
    throw ExchangeError(path + ": header has " + std::to_string(cache.vertex_count) +
                        " points and " + std::to_string(cache.frame_count) + " samples");
  const size_t floats = static_cast<size_t>(cache.vertex_count) * cache.frame_count * 3;
  if (bytes.size() != 32 + floats * 4)
    throw ExchangeError(path + ": " + std::to_string(bytes.size()) + " bytes, but the header's " +
                        std::to_string(cache.frame_count) + " samples of " +
                        std::to_string(cache.vertex_count) + " points need " +
                        std::to_string(32 + floats * 4) + " (truncated or padded)");
  cache.positions.resize(floats);
  std::memcpy(cache.positions.data(), bytes.data() + 32, floats * 4);
  for (size_t i = 0; i < floats; ++i)
    if (!std::isfinite(cache.positions[i]))
      throw ExchangeError(path + ": sample " + std::to_string(i / (3 * cache.vertex_count)) +
                          " has a non-finite coordinate at point " +
                          std::to_string((i / 3) % cache.vertex_count));
  return cache;
}

void write_obj(const std::string& path, const std::string& object_name, const float* positions,
               int vertex_count, const std::vector<std::array<int, 3>>& triangles) {
  std::ostringstream o;
  o << "# clothdb garment: " << vertex_count << " vertices, " << triangles.size() << " triangles\n"
    << "o " << object_name << "\n";
  char buf[96];
  for (int i = 0; i < vertex_count; ++i) {
    std::snprintf(buf, sizeof buf, "v %.6f %.6f %.6f\n", positions[3 * i], positions[3 * i + 1],
                  positions[3 * i + 2]);
    o << buf;
  }
  for (const auto& t : triangles)
    o << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
  write_file_atomic(path, o.str());
}

void write_artist_obj(const std::string& path, const std::string& object_name,
                      const float* positions, const db::ArtistMesh& m) {
  std::ostringstream o;
  o << "# clothdb garment, the artist's mesh" << (m.source.empty() ? "" : " of " + m.source) << ": "
    << m.vertex_count() << " vertices, " << m.face_count() << " faces\n"
    << "o " << object_name << "\n";
  char buf[128];
  for (uint32_t i = 0; i < m.vertex_count(); ++i) {
    std::snprintf(buf, sizeof buf, "v %.6f %.6f %.6f\n", positions[3 * i], positions[3 * i + 1],
                  positions[3 * i + 2]);
    o << buf;
  }
  // UVs and normals with 9 significant digits: they read back as the same floats.
  for (size_t i = 0; i + 1 < m.uvs.size(); i += 2) {
    std::snprintf(buf, sizeof buf, "vt %.9g %.9g\n", m.uvs[i], m.uvs[i + 1]);
    o << buf;
  }
  for (size_t i = 0; i + 2 < m.normals.size(); i += 3) {
    std::snprintf(buf, sizeof buf, "vn %.9g %.9g %.9g\n", m.normals[i], m.normals[i + 1],
                  m.normals[i + 2]);
    o << buf;
  }
  std::vector<int> group_of(m.face_sizes.size(), -1);
  for (size_t g = 0; g < m.groups.size(); ++g)
    for (uint32_t f : m.groups[g].faces) group_of[f] = int(g);
  int current = -1;
  size_t c = 0;
  for (size_t f = 0; f < m.face_sizes.size(); ++f) {
    if (group_of[f] != current && group_of[f] >= 0) {
      const db::ArtistGroup& g = m.groups[size_t(group_of[f])];
      if (current < 0 || g.name != m.groups[size_t(current)].name)
        o << "g " << (g.name.empty() ? object_name : g.name) << "\n";
      if (!g.material.empty()) o << "usemtl " << g.material << "\n";
      current = group_of[f];
    }
    o << 'f';
    for (uint32_t k = 0; k < m.face_sizes[f]; ++k, ++c) {
      o << ' ' << m.corners[c] + 1;
      const uint32_t t = c < m.corner_uvs.size() ? m.corner_uvs[c] : db::kNoAttribute;
      const uint32_t n = c < m.corner_normals.size() ? m.corner_normals[c] : db::kNoAttribute;
      if (t != db::kNoAttribute || n != db::kNoAttribute) o << '/';
      if (t != db::kNoAttribute) o << t + 1;
      if (n != db::kNoAttribute) o << '/' << n + 1;
    }
    o << '\n';
  }
  write_file_atomic(path, o.str());
}

PointCache artist_order(const db::ArtistMesh& mesh, const PointCache& sim) {
  PointCache out = sim;
  out.vertex_count = int(mesh.vertex_count());
  out.positions.resize(size_t(sim.frame_count) * mesh.vertex_count() * 3);
  for (int f = 0; f < sim.frame_count; ++f)
    db::to_artist_order(mesh, sim.positions.data() + size_t(f) * size_t(sim.vertex_count) * 3,
                        out.positions.data() + size_t(f) * mesh.vertex_count() * 3);
  return out;
}

PointCache simulation_order(const db::ArtistMesh& mesh, uint32_t sim_vertices,
                            const PointCache& cache, const std::string& what) {
  if (cache.vertex_count == int(sim_vertices) && mesh.vertex_count() != sim_vertices) return cache;
  if (cache.vertex_count != int(mesh.vertex_count()))
    throw ExchangeError(what + ": points: " + std::to_string(cache.vertex_count) +
                        " vertices, the garment has " + std::to_string(mesh.vertex_count()) +
                        " (the artist's mesh) and " + std::to_string(sim_vertices) +
                        " (the simulation mesh): keep the vertex order and count");
  PointCache out = cache;
  out.vertex_count = int(sim_vertices);
  out.positions.resize(size_t(cache.frame_count) * sim_vertices * 3);
  std::string why;
  for (int f = 0; f < cache.frame_count; ++f)
    if (!db::to_simulation_order(mesh, sim_vertices,
                                 cache.positions.data() + size_t(f) * mesh.vertex_count() * 3,
                                 out.positions.data() + size_t(f) * sim_vertices * 3, &why))
      throw ExchangeError(what + ": cannot map the artist's vertex order back: " + why);
  return out;
}

ObjMesh read_obj(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ExchangeError(path + ": cannot open");
  ObjMesh mesh;
  std::string line, group, material;
  int line_no = 0;
  auto fail = [&](const std::string& what) {
    throw ExchangeError(path + ":" + std::to_string(line_no) + ": " + what);
  };
  bool any_uv = false, any_normal = false;
  int current_group = -1;  // index into face_groups, -1: not yet known for (group, material)
  // One index of a face corner ("3", "-1"), 0-based, or kObjNone for an empty field.
  auto index = [&](const std::string& item, const std::string& field, size_t count,
                   const char* what) -> uint32_t {
    if (field.empty()) return kObjNone;
    long idx = 0;
    try {
      size_t used = 0;
      idx = std::stol(field, &used);
      if (used != field.size()) throw std::invalid_argument(field);
    } catch (const std::exception&) {
      fail("face index '" + item + "' is not a number");
    }
    idx = idx < 0 ? long(count) + idx : idx - 1;
    if (idx < 0 || idx >= long(count)) {
      const std::string plural =
          std::string(what) == "vertex" ? "vertices" : what + std::string("s");
      fail("face " + std::string(what) + " index " + item + " outside the " +
           std::to_string(count) + " " + plural + " so far");
    }
    return uint32_t(idx);
  };
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag) || tag[0] == '#') continue;
    if (tag == "v") {
      // strtof, not >>: "nan" and "inf" are numbers here, kept for the caller to report with
      // the vertex (the garment's check names the coordinates).
      float xyz[3];
      for (float& c : xyz) {
        std::string token;
        char* end = nullptr;
        if (!(ls >> token) || (c = std::strtof(token.c_str(), &end), *end != '\0'))
          fail("vertex needs three numbers");
      }
      mesh.positions.insert(mesh.positions.end(), {xyz[0], xyz[1], xyz[2]});
      mesh.groups.push_back(group);
    } else if (tag == "vt") {
      float u, v = 0;
      if (!(ls >> u)) fail("texture coordinate needs a number");
      ls >> v;
      if (!std::isfinite(u) || !std::isfinite(v)) fail("texture coordinate is not finite");
      mesh.uvs.insert(mesh.uvs.end(), {u, v});
    } else if (tag == "vn") {
      float x, y, z;
      if (!(ls >> x >> y >> z)) fail("normal needs three numbers");
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) fail("normal is not finite");
      mesh.normals.insert(mesh.normals.end(), {x, y, z});
    } else if (tag == "g" || tag == "o") {
      group.clear();
      ls >> group;
      current_group = -1;
    } else if (tag == "usemtl") {
      material.clear();
      ls >> material;
      current_group = -1;
    } else if (tag == "f") {
      std::vector<int> poly;
      std::string item;
      const size_t n = mesh.positions.size() / 3;
      while (ls >> item) {
        const size_t s1 = item.find('/');
        const size_t s2 = s1 == std::string::npos ? s1 : item.find('/', s1 + 1);
        const uint32_t v = index(item, item.substr(0, s1), n, "vertex");
        if (v == kObjNone) fail("face corner '" + item + "' names no vertex");
        const uint32_t t =
            s1 == std::string::npos
                ? kObjNone
                : index(item, item.substr(s1 + 1, s2 == std::string::npos ? s2 : s2 - s1 - 1),
                        mesh.uvs.size() / 2, "texture coordinate");
        const uint32_t nr = s2 == std::string::npos ? kObjNone
                                                    : index(item, item.substr(s2 + 1),
                                                            mesh.normals.size() / 3, "normal");
        poly.push_back(int(v));
        mesh.corners.push_back(v);
        mesh.corner_uvs.push_back(t);
        mesh.corner_normals.push_back(nr);
        any_uv |= t != kObjNone;
        any_normal |= nr != kObjNone;
      }
      if (poly.size() < 3) fail("face has fewer than three vertices");
      if (current_group < 0) {
        current_group = int(mesh.face_groups.size());
        for (size_t g = 0; g < mesh.face_groups.size(); ++g)
          if (mesh.face_groups[g].name == group && mesh.face_groups[g].material == material)
            current_group = int(g);
        if (current_group == int(mesh.face_groups.size()))
          mesh.face_groups.push_back({group, material, {}});
      }
      mesh.face_groups[size_t(current_group)].faces.push_back(uint32_t(mesh.face_sizes.size()));
      mesh.face_sizes.push_back(uint32_t(poly.size()));
      for (int v : poly) mesh.groups[size_t(v)] = group;
      for (size_t k = 1; k + 1 < poly.size(); ++k)
        mesh.triangles.push_back({poly[0], poly[k], poly[k + 1]});
    }
  }
  if (mesh.positions.empty()) throw ExchangeError(path + ": no vertices");
  if (!any_uv) mesh.corner_uvs.clear();
  if (!any_normal) mesh.corner_normals.clear();
  return mesh;
}

}  // namespace clothdb
