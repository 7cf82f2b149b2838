#include "exchange/point_cache.hpp"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>

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

ObjMesh read_obj(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ExchangeError(path + ": cannot open");
  ObjMesh mesh;
  std::string line, group;
  int line_no = 0;
  auto fail = [&](const std::string& what) {
    throw ExchangeError(path + ":" + std::to_string(line_no) + ": " + what);
  };
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag) || tag[0] == '#') continue;
    if (tag == "v") {
      float x, y, z;
      if (!(ls >> x >> y >> z)) fail("vertex needs three numbers");
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) fail("vertex is not finite");
      mesh.positions.insert(mesh.positions.end(), {x, y, z});
      mesh.groups.push_back(group);
    } else if (tag == "g" || tag == "o") {
      ls >> group;
    } else if (tag == "f") {
      std::vector<int> poly;
      std::string item;
      const int n = static_cast<int>(mesh.positions.size() / 3);
      while (ls >> item) {
        int idx = 0;
        try {
          idx = std::stoi(item.substr(0, item.find('/')));
        } catch (const std::exception&) {
          fail("face index '" + item + "' is not a number");
        }
        idx = idx < 0 ? n + idx : idx - 1;
        if (idx < 0 || idx >= n)
          fail("face index " + item + " outside the " + std::to_string(n) + " vertices so far");
        poly.push_back(idx);
      }
      if (poly.size() < 3) fail("face has fewer than three vertices");
      for (size_t k = 1; k + 1 < poly.size(); ++k)
        mesh.triangles.push_back({poly[0], poly[k], poly[k + 1]});
    }
  }
  if (mesh.positions.empty()) throw ExchangeError(path + ": no vertices");
  return mesh;
}

}  // namespace clothdb
