// Synthetic clothdb databases for the runtime's tests, example and benchmark: a square sheet of
// cloth, a small primary motion graph and a secondary cloth graph laid out exactly as
// docs/SECONDARY_GRAPH.md says the precompute writes one, with smooth made-up motion instead of
// simulation. Not part of the clothrt library (it uses the writer).
#pragma once

#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "database/format/artist_mesh.hpp"
#include "database/store/writer.hpp"

namespace clothdb::synthetic {

struct Edge {
  int from = 0, to = 0;  // nodes
  int frames = 30;
};

struct Spec {
  uint32_t side = 12;  // the sheet has side * side vertices
  int nodes = 2;
  std::vector<Edge> edges;
  int states_per_node = 3;
  double rate = 30;
  // Clip from local state i along edge e ends at local state (i + e) % states_per_node of the
  // target node; when (i + e) % blend_modulus == 1 it ends blend_offset away from it (a cloth edge
  // with blend_error > 0), otherwise exactly on it. 0: never.
  int blend_modulus = 2;
  double blend_offset = 0.04;  // m, largest vertex offset at the sheet's free edge
  double wave = 0.08;          // m, amplitude of the motion inside a clip
  // (global state index, edge index) pairs left unexplored: no clip, so players fall back.
  std::vector<std::pair<int, int>> unexplored;
  db::CodecSettings codec;
  // Store an artist's mesh of the sheet (sheet_artist_mesh): quads, a UV seam, split vertices.
  bool artist_mesh = false;
};

struct Built {
  std::vector<int64_t> primary;  // per edge
  std::vector<int64_t> states;   // global state index = node * states_per_node + local
  std::map<std::pair<int, int>, int64_t> clip;  // (global state, edge) -> cloth clip id
  std::map<int64_t, double> blend_error;        // cloth clip id -> its edge's blend error
  uint32_t vertices = 0;
};

inline float sheet_rest(uint32_t side, uint32_t v, int axis) {
  const double spacing = 0.8 / double(side - 1);
  const uint32_t i = v % side, j = v / side;
  return axis == 0 ? float(-0.4 + spacing * i) : axis == 1 ? float(1.4 - spacing * j) : 0.0f;
}

// An artist's mesh of the sheet as a DCC exports one with a UV seam down the middle column: two
// blocks of quads (columns 0..side/2 and side/2..side-1), the seam column's vertices split (one
// copy per block, with different UVs, as glTF and FBX store them), per-vertex UVs and normals. Its
// map sends both copies of a seam vertex to the one simulation vertex.
inline db::ArtistMesh sheet_artist_mesh(uint32_t side) {
  db::ArtistMesh m;
  m.source = "synthetic sheet";
  const uint32_t seam = side / 2;
  const uint32_t blocks[2][2] = {{0, seam}, {seam, side - 1}};  // first and last column
  for (int b = 0; b < 2; ++b) {
    const uint32_t c0 = blocks[b][0], c1 = blocks[b][1], width = c1 - c0 + 1;
    const uint32_t base = m.vertex_count();
    for (uint32_t j = 0; j < side; ++j)
      for (uint32_t i = c0; i <= c1; ++i) {
        const uint32_t v = j * side + i;
        for (int k = 0; k < 3; ++k) m.positions.push_back(sheet_rest(side, v, k));
        const float u = (b == 0 ? 0.0f : 0.55f) + 0.45f * float(i - c0) / float(c1 - c0);
        m.uvs.insert(m.uvs.end(), {u, float(j) / float(side - 1)});
        m.normals.insert(m.normals.end(), {0.0f, 0.0f, 1.0f});
        m.map_vertices.insert(m.map_vertices.end(), {v, v, v});
        m.map_weights.insert(m.map_weights.end(), {1.0f, 0.0f, 0.0f});
      }
    std::vector<uint32_t> group_faces;
    for (uint32_t j = 0; j + 1 < side; ++j)
      for (uint32_t i = 0; i + 1 < width; ++i) {
        const uint32_t a = base + j * width + i, bb = a + 1, c = a + width, d = c + 1;
        group_faces.push_back(m.face_count());
        m.face_sizes.push_back(4);
        m.corners.insert(m.corners.end(), {a, c, d, bb});  // the sheet's winding
      }
    m.groups.push_back({b == 0 ? "left" : "right", "cloth", group_faces});
  }
  m.corner_uvs = m.corners;  // UVs and normals per vertex
  m.corner_normals = m.corners;
  db::derive_render_mesh(&m);
  return m;
}

// A cloth state: the sheet swung and rippled by an amount that depends on the state.
inline std::vector<float> state_pose(uint32_t side, int node, int local) {
  std::vector<float> x(size_t(side) * side * 3);
  const double swing = 0.06 * std::sin(1.3 * node + 2.1 * local + 0.4);
  const double ripple = 0.03 * std::cos(0.7 * node + 1.7 * local);
  for (uint32_t v = 0; v < side * side; ++v) {
    const double u = double(v % side) / (side - 1), w = double(v / side) / (side - 1);
    x[3 * v] = float(sheet_rest(side, v, 0) + swing * w);
    x[3 * v + 1] = float(sheet_rest(side, v, 1) + 0.02 * ripple * std::sin(3 * u));
    x[3 * v + 2] = float(ripple * w * std::sin(4 * u + node));
  }
  return x;
}

// Frames from pose a to pose b (+ offset at the end) with a wave in between. Smoothstep and
// sin^2 have zero slope at both ends, so clips start and end at rest velocity, like states.
inline std::vector<float> clip_frames(uint32_t side, const std::vector<float>& a,
                                      const std::vector<float>& b, double end_offset, double wave,
                                      int frames, int seed) {
  const size_t n = a.size();
  std::vector<float> x(n * size_t(frames));
  for (int f = 0; f < frames; ++f) {
    const double s = double(f) / (frames - 1);
    const double h = s * s * (3 - 2 * s);
    const double bump = std::sin(M_PI * s) * std::sin(M_PI * s);
    for (uint32_t v = 0; v < side * side; ++v) {
      const double u = double(v % side) / (side - 1), w = double(v / side) / (side - 1);
      const double wx = wave * w * std::sin(4 * M_PI * s + 5 * u + seed);
      const double wz = wave * w * std::cos(3 * M_PI * s + 4 * u + 0.5 * seed);
      const double off = end_offset * h * w;
      for (int k = 0; k < 3; ++k) {
        const size_t i = 3 * size_t(v) + size_t(k);
        double y = (1 - h) * a[i] + h * b[i];
        y += bump * (k == 0 ? wx : k == 2 ? wz : 0.2 * wx * wz);
        y += off * (k == 0 ? 0.8 : k == 2 ? -0.6 : 0.0);
        x[size_t(f) * n + i] = float(y);
      }
    }
  }
  return x;
}

// RMS over vertices of the position gap (velocities are at rest on both sides here).
inline double rms_distance(const float* a, const float* b, size_t n) {
  double sum = 0;
  for (size_t i = 0; i < n; ++i) sum += (double(a[i]) - b[i]) * (double(a[i]) - b[i]);
  return std::sqrt(sum / double(n / 3));
}

// Writes a new database at `path` (which must not exist). Throws ClothdbError on failure.
inline Built build(const std::string& path, const Spec& spec) {
  Built out;
  const uint32_t side = spec.side, vertices = side * side;
  out.vertices = vertices;
  db::Writer w = db::Writer::create(path, spec.codec);
  {
    db::Writer::Transaction tx(w);
    db::Garment g;
    for (uint32_t v = 0; v < vertices; ++v)
      for (int k = 0; k < 3; ++k) g.rest_positions.push_back(sheet_rest(side, v, k));
    for (uint32_t j = 0; j + 1 < side; ++j)
      for (uint32_t i = 0; i + 1 < side; ++i) {
        const uint32_t a = j * side + i, b = a + 1, c = a + side, d = c + 1;
        g.triangles.insert(g.triangles.end(), {a, c, b, b, c, d});
      }
    g.material = R"({"synthetic": true})";
    g.solver = R"({"synthetic": true})";
    w.put_garment(g);
    if (spec.artist_mesh) w.put_artist_mesh(sheet_artist_mesh(side));
    for (size_t e = 0; e < spec.edges.size(); ++e) {
      db::PrimaryClip p;
      p.name = "edge" + std::to_string(e) + "_n" + std::to_string(spec.edges[e].from) + "_n" +
               std::to_string(spec.edges[e].to);
      p.frame_count = spec.edges[e].frames;
      p.frame_rate = spec.rate;
      out.primary.push_back(w.add_primary_clip(p));
    }
    std::string graph = "{\"nodes\": " + std::to_string(spec.nodes) + ", \"edges\": [";
    for (size_t a = 0; a < spec.edges.size(); ++a) {
      graph += (a ? ", " : "") + std::string("[") + std::to_string(spec.edges[a].from) + ", " +
               std::to_string(spec.edges[a].to) + ", " + std::to_string(out.primary[a]) + "]";
      for (size_t b = 0; b < spec.edges.size(); ++b) {
        if (spec.edges[a].to != spec.edges[b].from) continue;
        db::PrimaryTransition t;
        t.from_clip = out.primary[a];
        t.from_frame = spec.edges[a].frames - 1;
        t.to_clip = out.primary[b];
        w.add_primary_transition(t);
      }
    }
    w.set_meta(db::meta::kMotionGraph, graph + "]}");
    w.set_meta(db::meta::kStartClip, std::to_string(out.primary[0]));
    w.set_meta(db::meta::kScene, "synthetic sheet");
    // States at each node, stored with the lowest-id edge leaving it.
    const std::vector<float> rest_velocity(size_t(vertices) * 3, 0.0f);
    for (int n = 0; n < spec.nodes; ++n) {
      int64_t first_edge = 0;
      for (size_t e = 0; e < spec.edges.size() && !first_edge; ++e)
        if (spec.edges[e].from == n) first_edge = out.primary[e];
      for (int i = 0; i < spec.states_per_node; ++i)
        out.states.push_back(first_edge
                                 ? w.add_cloth_state(first_edge, 0, state_pose(side, n, i).data(),
                                                     rest_velocity.data(), vertices)
                                 : 0);
    }
    tx.commit();
  }
  // Clips start from the states as decoded (docs/SECONDARY_GRAPH.md).
  std::vector<std::vector<float>> decoded(out.states.size());
  {
    db::Reader r;
    Error err;
    codec::DecodeScratch scratch;
    if (r.open(path, &err) != Status::Ok) throw ClothdbError(err.status, err.message);
    std::vector<float> v;
    for (size_t s = 0; s < out.states.size(); ++s)
      if (out.states[s] &&
          r.read_state(out.states[s], &decoded[s], &v, scratch, &err) != Status::Ok)
        throw ClothdbError(err.status, err.message);
  }
  db::Writer::Transaction tx(w);
  const int S = spec.states_per_node;
  for (int n = 0; n < spec.nodes; ++n)
    for (int i = 0; i < S; ++i)
      for (size_t e = 0; e < spec.edges.size(); ++e) {
        const Edge& edge = spec.edges[e];
        const int s = n * S + i;
        if (edge.from != n) continue;
        bool skip = false;
        for (const auto& u : spec.unexplored) skip |= u.first == s && u.second == int(e);
        if (skip) continue;
        const int target = edge.to * S + (i + int(e)) % S;
        const bool blend = spec.blend_modulus > 0 && (i + int(e)) % spec.blend_modulus == 1;
        const std::vector<float> frames =
            clip_frames(side, decoded[size_t(s)], decoded[size_t(target)],
                        blend ? spec.blend_offset : 0.0, spec.wave, edge.frames, s * 7 + int(e));
        db::NewClothClip c;
        c.start_state = out.states[size_t(s)];
        c.primary_clip = out.primary[e];
        const int64_t id = w.add_cloth_clip(c, frames.data(), uint32_t(edge.frames), vertices);
        const size_t n3 = size_t(vertices) * 3;
        const double error = blend ? rms_distance(frames.data() + size_t(edge.frames - 1) * n3,
                                                  decoded[size_t(target)].data(), n3)
                                   : 0.0;
        w.add_cloth_edge(id, out.states[size_t(target)], error);
        out.clip[{s, int(e)}] = id;
        out.blend_error[id] = error;
      }
  tx.commit();
  return out;
}

// The graph the tests, the example and `clothdb play` demos use: two nodes, four edges (one a
// loop at each node), three states per node, one unexplored (state, edge) pair.
inline Spec demo_spec(uint32_t side = 12) {
  Spec s;
  s.side = side;
  s.nodes = 2;
  s.edges = {{0, 1, 40}, {1, 0, 36}, {1, 1, 30}, {0, 0, 32}};
  s.states_per_node = 3;
  s.unexplored = {{4, 2}};  // node 1, local state 1, along the loop at node 1
  return s;
}

// The benchmark's graph: 4 nodes, each with two edges leaving it, 60-frame edges.
inline Spec bench_spec(uint32_t side, int states_per_node) {
  Spec s;
  s.side = side;
  s.nodes = 4;
  for (int n = 0; n < 4; ++n) {
    s.edges.push_back({n, (n + 1) % 4, 60});
    s.edges.push_back({n, (n + 2) % 4, 60});
  }
  s.states_per_node = states_per_node;
  s.blend_modulus = 3;
  s.blend_offset = 0.02;
  return s;
}

}  // namespace clothdb::synthetic
