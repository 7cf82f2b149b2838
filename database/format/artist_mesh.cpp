#include "database/format/artist_mesh.hpp"

#include <cmath>
#include <map>
#include <tuple>

namespace clothdb::db {

namespace {

uint32_t at_or_none(const std::vector<uint32_t>& v, size_t i) {
  return i < v.size() ? v[i] : kNoAttribute;
}

}  // namespace

void derive_render_mesh(ArtistMesh* m) {
  const uint32_t n = m->vertex_count();
  m->render_vertices.assign(size_t(n) * 3, kNoAttribute);
  for (uint32_t v = 0; v < n; ++v) m->render_vertices[3 * v] = v;
  std::vector<char> seen(n, 0);
  std::map<std::tuple<uint32_t, uint32_t, uint32_t>, uint32_t> extra;
  std::vector<uint32_t> corner_render(m->corners.size());
  for (size_t c = 0; c < m->corners.size(); ++c) {
    const uint32_t v = m->corners[c], uv = at_or_none(m->corner_uvs, c),
                   nr = at_or_none(m->corner_normals, c);
    if (v >= n) {  // refused by check_artist_mesh; keep the derivation total
      corner_render[c] = 0;
      continue;
    }
    if (!seen[v]) {
      seen[v] = 1;
      m->render_vertices[3 * v + 1] = uv;
      m->render_vertices[3 * v + 2] = nr;
      corner_render[c] = v;
    } else if (m->render_vertices[3 * v + 1] == uv && m->render_vertices[3 * v + 2] == nr) {
      corner_render[c] = v;
    } else {
      const auto key = std::make_tuple(v, uv, nr);
      auto it = extra.find(key);
      if (it == extra.end()) {
        it = extra.emplace(key, uint32_t(m->render_vertices.size() / 3)).first;
        m->render_vertices.insert(m->render_vertices.end(), {v, uv, nr});
      }
      corner_render[c] = it->second;
    }
  }
  m->render_triangles.clear();
  size_t first = 0;
  for (uint32_t size : m->face_sizes) {
    for (uint32_t k = 1; k + 1 < size && first + k + 1 < corner_render.size(); ++k)
      m->render_triangles.insert(
          m->render_triangles.end(),
          {corner_render[first], corner_render[first + k], corner_render[first + k + 1]});
    first += size;
  }
}

std::vector<uint32_t> artist_triangles(const ArtistMesh& m) {
  std::vector<uint32_t> out(m.render_triangles.size());
  for (size_t i = 0; i < out.size(); ++i)
    out[i] = m.render_vertices[3 * size_t(m.render_triangles[i])];
  return out;
}

ArtistMesh identity_artist_mesh(const Garment& g) {
  ArtistMesh m;
  m.positions = g.rest_positions;
  m.face_sizes.assign(g.triangles.size() / 3, 3);
  m.corners = g.triangles;
  const uint32_t n = g.vertex_count();
  m.map_vertices.resize(size_t(n) * 3);
  m.map_weights.assign(size_t(n) * 3, 0.0f);
  for (uint32_t v = 0; v < n; ++v) {
    m.map_vertices[3 * v] = m.map_vertices[3 * v + 1] = m.map_vertices[3 * v + 2] = v;
    m.map_weights[3 * v] = 1.0f;
  }
  derive_render_mesh(&m);
  return m;
}

void to_artist_order(const ArtistMesh& m, const float* x, float* out) {
  const size_t n = m.vertex_count();
  for (size_t v = 0; v < n; ++v) {
    const uint32_t* i = &m.map_vertices[3 * v];
    const float* w = &m.map_weights[3 * v];
    for (size_t k = 0; k < 3; ++k)
      out[3 * v + k] = w[0] * x[3 * size_t(i[0]) + k] + w[1] * x[3 * size_t(i[1]) + k] +
                       w[2] * x[3 * size_t(i[2]) + k];
  }
}

bool to_simulation_order(const ArtistMesh& m, uint32_t sim, const float* a, float* out,
                         std::string* why) {
  std::vector<double> sum(size_t(sim) * 3, 0.0);
  std::vector<uint32_t> count(sim, 0);
  for (size_t v = 0; v < m.vertex_count(); ++v) {
    if (m.map_weights[3 * v] != 1.0f) continue;  // barycentric: not an index
    const uint32_t s = m.map_vertices[3 * v];
    ++count[s];
    for (size_t k = 0; k < 3; ++k) sum[3 * size_t(s) + k] += a[3 * v + k];
  }
  for (uint32_t s = 0; s < sim; ++s) {
    if (count[s] == 0) {
      *why = "simulation vertex " + std::to_string(s) +
             " is not an artist vertex (the simulation mesh was remeshed)";
      return false;
    }
    for (size_t k = 0; k < 3; ++k)
      out[3 * size_t(s) + k] = float(sum[3 * size_t(s) + k] / double(count[s]));
  }
  return true;
}

Status check_artist_mesh(const ArtistMesh& m, uint32_t sim, const std::string& path, Error* err) {
  const char* p = path.c_str();
  const size_t n = m.vertex_count();
  if (m.positions.size() != n * 3 || n == 0)
    return fail(err, Status::Corrupt, "%s: garment_mesh: %zu position floats, not 3 per vertex", p,
                m.positions.size());
  for (float x : m.positions)
    if (!std::isfinite(x))
      return fail(err, Status::Corrupt, "%s: garment_mesh: a non-finite position", p);
  size_t corners = 0;
  for (size_t f = 0; f < m.face_sizes.size(); ++f) {
    if (m.face_sizes[f] < 3)
      return fail(err, Status::Corrupt, "%s: garment_mesh: face %zu has %u corners", p, f,
                  m.face_sizes[f]);
    corners += m.face_sizes[f];
  }
  if (corners != m.corners.size())
    return fail(err, Status::Corrupt, "%s: garment_mesh: faces have %zu corners, %zu stored", p,
                corners, m.corners.size());
  for (size_t c = 0; c < m.corners.size(); ++c)
    if (m.corners[c] >= n)
      return fail(err, Status::Corrupt,
                  "%s: garment_mesh: corner %zu names vertex %u (%zu vertices)", p, c, m.corners[c],
                  n);
  const struct {
    const char* what;
    const std::vector<float>& values;
    const std::vector<uint32_t>& index;
    size_t width;
  } attributes[] = {{"uv", m.uvs, m.corner_uvs, 2}, {"normal", m.normals, m.corner_normals, 3}};
  for (const auto& a : attributes) {
    if (a.values.size() % a.width != 0)
      return fail(err, Status::Corrupt, "%s: garment_mesh: %zu %s floats, not %zu per %s", p,
                  a.values.size(), a.what, a.width, a.what);
    if (!a.index.empty() && a.index.size() != m.corners.size())
      return fail(err, Status::Corrupt, "%s: garment_mesh: %zu corner %ss for %zu corners", p,
                  a.index.size(), a.what, m.corners.size());
    for (size_t c = 0; c < a.index.size(); ++c)
      if (a.index[c] != kNoAttribute && a.index[c] >= a.values.size() / a.width)
        return fail(err, Status::Corrupt, "%s: garment_mesh: corner %zu names %s %u (%zu stored)",
                    p, c, a.what, a.index[c], a.values.size() / a.width);
    for (float x : a.values)
      if (!std::isfinite(x))
        return fail(err, Status::Corrupt, "%s: garment_mesh: a non-finite %s", p, a.what);
  }
  for (const ArtistGroup& g : m.groups)
    for (uint32_t f : g.faces)
      if (f >= m.face_sizes.size())
        return fail(err, Status::Corrupt, "%s: garment_group '%s' names face %u (%zu faces)", p,
                    g.name.c_str(), f, m.face_sizes.size());
  if (m.map_vertices.size() != n * 3 || m.map_weights.size() != n * 3)
    return fail(err, Status::Corrupt,
                "%s: garment_mesh: the map holds %zu indices and %zu weights, %zu vertices need "
                "%zu of each",
                p, m.map_vertices.size(), m.map_weights.size(), n, n * 3);
  for (size_t v = 0; v < n; ++v) {
    double sum = 0;
    for (size_t k = 0; k < 3; ++k) {
      if (m.map_vertices[3 * v + k] >= sim)
        return fail(err, Status::Corrupt,
                    "%s: garment_mesh: vertex %zu maps to simulation vertex %u (%u in the "
                    "garment)",
                    p, v, m.map_vertices[3 * v + k], sim);
      const float w = m.map_weights[3 * v + k];
      if (!std::isfinite(w) || w < -1e-3f || w > 1.001f)
        return fail(err, Status::Corrupt, "%s: garment_mesh: vertex %zu has map weight %g", p, v,
                    double(w));
      sum += w;
    }
    if (std::fabs(sum - 1.0) > 1e-3)
      return fail(err, Status::Corrupt, "%s: garment_mesh: vertex %zu's map weights sum to %g", p,
                  v, sum);
  }
  ArtistMesh derived = m;
  derive_render_mesh(&derived);
  if (derived.render_vertices != m.render_vertices ||
      derived.render_triangles != m.render_triangles)
    return fail(err, Status::Corrupt,
                "%s: garment_mesh: the stored render mesh (%u vertices, %u triangles) is not the "
                "one its faces make (%u, %u)",
                p, m.render_vertex_count(), m.render_triangle_count(),
                derived.render_vertex_count(), derived.render_triangle_count());
  return Status::Ok;
}

}  // namespace clothdb::db
