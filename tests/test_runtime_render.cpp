// The runtime's render-mesh output (clothrt.h, "THE RENDER MESH"): on a synthetic database whose
// garment has an artist's mesh with quads, a UV seam and split seam vertices
// (synthetic::sheet_artist_mesh), positions equal the simulation positions through the map,
// normals are unit and agree across seam copies, tangents are unit and orthogonal, strides are
// honoured, nothing is allocated per frame after warm-up; a file without an artist's mesh renders
// its simulation mesh.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <string>
#include <vector>

#include "clothrt.h"
#include "database/format/artist_mesh.hpp"
#include "runtime/tools/synthetic_db.hpp"
#include "support/allocation_counter.hpp"
#include "support/temp_dir.hpp"

namespace clothdb {
namespace {

constexpr uint32_t kSide = 12;

struct Opened {
  test::TempDir dir;
  clothrt_db* db = nullptr;
  clothrt_player* player = nullptr;
  synthetic::Built built;
  explicit Opened(bool artist) {
    synthetic::Spec spec = synthetic::demo_spec(kSide);
    spec.artist_mesh = artist;
    built = synthetic::build(dir.file("render.clothdb"), spec);
    clothrt_db_options o;
    clothrt_db_options_init(&o);
    o.prefetch_threads = 0;
    EXPECT_EQ(clothrt_db_open(dir.file("render.clothdb").c_str(), &o, &db), CLOTHRT_OK)
        << clothrt_last_open_errmsg();
    EXPECT_EQ(clothrt_player_create(db, &player), CLOTHRT_OK);
    EXPECT_EQ(clothrt_player_start(player, 0), CLOTHRT_OK);
  }
  ~Opened() {
    clothrt_player_destroy(player);
    clothrt_db_close(db);
  }
};

double length(const float* v) {
  return std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2]);
}

TEST(RuntimeRender, RenderMeshIsTheArtistsWithSeamsSplit) {
  Opened h(true);
  const db::ArtistMesh artist = synthetic::sheet_artist_mesh(kSide);
  const uint32_t rn = clothrt_db_render_vertex_count(h.db);
  EXPECT_EQ(rn, artist.render_vertex_count());
  EXPECT_EQ(rn, kSide * kSide + kSide);  // the seam column twice
  ASSERT_EQ(clothrt_db_render_triangle_count(h.db), artist.render_triangle_count());
  std::vector<uint32_t> tri(size_t(artist.render_triangle_count()) * 3);
  ASSERT_EQ(clothrt_db_render_triangles(h.db, tri.data(), tri.size()), CLOTHRT_OK);
  EXPECT_EQ(tri, artist.render_triangles);
  EXPECT_EQ(clothrt_db_render_triangles(h.db, tri.data(), tri.size() - 1), CLOTHRT_ERR_INVALID);
  ASSERT_TRUE(clothrt_db_render_has_uvs(h.db));
  std::vector<float> uv(size_t(rn) * 3, -7.0f);
  ASSERT_EQ(clothrt_db_render_uvs(h.db, uv.data(), 12), CLOTHRT_OK);
  for (uint32_t r = 0; r < rn; ++r) {
    EXPECT_EQ(uv[3 * r], artist.uvs[2 * r]);
    EXPECT_EQ(uv[3 * r + 2], -7.0f);  // the stride's gap untouched
  }
  std::vector<uint32_t> source(rn);
  ASSERT_EQ(clothrt_db_render_source_vertices(h.db, source.data(), source.size()), CLOTHRT_OK);
  for (uint32_t r = 0; r < rn; ++r) EXPECT_EQ(source[r], artist.render_vertices[3 * r]);
}

TEST(RuntimeRender, PositionsNormalsTangentsThroughTheMapAtStrides) {
  Opened h(true);
  const db::ArtistMesh artist = synthetic::sheet_artist_mesh(kSide);
  const uint32_t n = clothrt_db_vertex_count(h.db), rn = clothrt_db_render_vertex_count(h.db);
  // One interleaved vertex buffer: position, normal, tangent, then a guard float.
  constexpr size_t kFloats = 11;
  std::vector<float> vb(size_t(rn) * kFloats, 0.0f), sim(size_t(n) * 3);
  clothrt_render_output out{vb.data(),   kFloats * 4,   vb.data() + 3,
                            kFloats * 4, vb.data() + 6, kFloats * 4};
  for (int step = 0; step < 40; ++step) {
    for (uint32_t r = 0; r < rn; ++r) vb[r * kFloats + 10] = 1234.5f;
    ASSERT_EQ(clothrt_player_advance(h.player, 1.0 / 45), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_get_positions(h.player, sim.data(), 12, nullptr), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_get_render_mesh(h.player, &out, nullptr), CLOTHRT_OK)
        << clothrt_player_errmsg(h.player);
    for (uint32_t r = 0; r < rn; ++r) {
      const float* p = &vb[r * kFloats];
      const uint32_t s = artist.map_vertices[3 * size_t(artist.render_vertices[3 * r])];
      for (int k = 0; k < 3; ++k) ASSERT_EQ(p[k], sim[3 * s + k]) << "render vertex " << r;
      EXPECT_NEAR(length(p + 3), 1.0, 1e-5);
      EXPECT_NEAR(length(p + 6), 1.0, 1e-5);
      EXPECT_NEAR(double(p[3]) * p[6] + double(p[4]) * p[7] + double(p[5]) * p[8], 0.0, 1e-5);
      EXPECT_EQ(std::fabs(p[9]), 1.0f);
      EXPECT_EQ(p[10], 1234.5f);  // the guard between vertices is never written
    }
    // Seam copies (artist vertices mapped to one simulation vertex) share position and normal.
    const uint32_t seam = kSide / 2, left_width = seam + 1;
    for (uint32_t j = 0; j < kSide; ++j) {
      const float* a = &vb[size_t(j * left_width + seam) * kFloats];
      const float* b = &vb[size_t(kSide * left_width + j * (kSide - seam)) * kFloats];
      for (int k = 0; k < 6; ++k) ASSERT_EQ(a[k], b[k]) << "seam row " << j;
    }
  }
  // Normals face the side the artist's normals (+z at rest) face.
  double facing = 0;
  for (uint32_t r = 0; r < rn; ++r) facing += vb[r * kFloats + 5];
  EXPECT_GT(facing, 0.5 * rn);
}

TEST(RuntimeRender, WorldSpaceTurnsNormalsAndMovesPositions) {
  Opened h(true);
  const uint32_t rn = clothrt_db_render_vertex_count(h.db);
  std::vector<float> p0(size_t(rn) * 3), n0(size_t(rn) * 3), p1(size_t(rn) * 3), n1(size_t(rn) * 3);
  ASSERT_EQ(clothrt_player_advance(h.player, 0.3), CLOTHRT_OK);
  clothrt_render_output a{p0.data(), 12, n0.data(), 12, nullptr, 0};
  clothrt_render_output b{p1.data(), 12, n1.data(), 12, nullptr, 0};
  // A quarter turn about y and a move.
  const float m[16] = {0, 0, -1, 0, 0, 1, 0, 0, 1, 0, 0, 0, 5, 6, 7, 1};
  ASSERT_EQ(clothrt_player_get_render_mesh(h.player, &a, nullptr), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_get_render_mesh(h.player, &b, m), CLOTHRT_OK);
  for (uint32_t r = 0; r < rn; ++r) {
    EXPECT_NEAR(p1[3 * r], p0[3 * r + 2] + 5, 1e-5);
    EXPECT_NEAR(p1[3 * r + 2], -p0[3 * r] + 7, 1e-5);
    EXPECT_NEAR(n1[3 * r], n0[3 * r + 2], 1e-5);
    EXPECT_NEAR(n1[3 * r + 1], n0[3 * r + 1], 1e-5);
    EXPECT_NEAR(n1[3 * r + 2], -n0[3 * r], 1e-5);
  }
}

// The normals as the straightforward loop makes them: each triangle's edge cross product scattered
// onto its corners in triangle order, normalised in float (+y for a vertex of no triangle), then
// copied to the render vertices; with a root transform turned and renormalised. The runtime gathers
// the same sums through its adjacency rows in SIMD registers and must give these bits.
std::vector<float> reference_normals(const std::vector<float>& x, const std::vector<uint32_t>& tri,
                                     const std::vector<uint32_t>& sim_of_render, const float* m) {
  const size_t n = x.size() / 3;
  std::vector<float> sum(n * 3, 0.0f);
  for (size_t t = 0; t < tri.size() / 3; ++t) {
    const float* a = &x[3 * size_t(tri[3 * t])];
    const float* b = &x[3 * size_t(tri[3 * t + 1])];
    const float* c = &x[3 * size_t(tri[3 * t + 2])];
    const float e0 = b[0] - a[0], e1 = b[1] - a[1], e2 = b[2] - a[2];
    const float f0 = c[0] - a[0], f1 = c[1] - a[1], f2 = c[2] - a[2];
    const float nv[3] = {e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0};
    for (int k = 0; k < 3; ++k)
      for (int i = 0; i < 3; ++i) sum[3 * size_t(tri[3 * t + size_t(k)]) + size_t(i)] += nv[i];
  }
  auto unit = [](float* v, bool fallback) {
    const float l2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if (l2 > 0) {
      const float s = 1.0f / std::sqrt(l2);
      v[0] *= s, v[1] *= s, v[2] *= s;
    } else if (fallback) {
      v[0] = 0, v[1] = 1, v[2] = 0;
    }
  };
  for (size_t v = 0; v < n; ++v) unit(&sum[3 * v], true);
  std::vector<float> out(sim_of_render.size() * 3);
  for (size_t r = 0; r < sim_of_render.size(); ++r) {
    const float* a = &sum[3 * size_t(sim_of_render[r])];
    float* o = &out[3 * r];
    if (m) {
      o[0] = m[0] * a[0] + m[4] * a[1] + m[8] * a[2];
      o[1] = m[1] * a[0] + m[5] * a[1] + m[9] * a[2];
      o[2] = m[2] * a[0] + m[6] * a[1] + m[10] * a[2];
      unit(o, false);
    } else {
      o[0] = a[0], o[1] = a[1], o[2] = a[2];
    }
  }
  return out;
}

TEST(RuntimeRender, NormalsAreTheScatteredSumsBitForBit) {
  for (const uint32_t side : {kSide, 13u}) {  // 13: a vertex count that is not a multiple of 4
    test::TempDir dir;
    synthetic::Spec spec = synthetic::demo_spec(side);
    spec.artist_mesh = true;
    synthetic::build(dir.file("n.clothdb"), spec);
    clothrt_db* db = nullptr;
    ASSERT_EQ(clothrt_db_open(dir.file("n.clothdb").c_str(), nullptr, &db), CLOTHRT_OK);
    clothrt_player* player = nullptr;
    ASSERT_EQ(clothrt_player_create(db, &player), CLOTHRT_OK);
    ASSERT_EQ(clothrt_player_start(player, 0), CLOTHRT_OK);
    const uint32_t n = clothrt_db_vertex_count(db), rn = clothrt_db_render_vertex_count(db);
    std::vector<uint32_t> tri(size_t(clothrt_db_triangle_count(db)) * 3);
    ASSERT_EQ(clothrt_db_triangles(db, tri.data(), tri.size()), CLOTHRT_OK);
    const db::ArtistMesh artist = synthetic::sheet_artist_mesh(side);
    std::vector<uint32_t> sim_of_render(rn);
    for (uint32_t r = 0; r < rn; ++r)
      sim_of_render[r] = artist.map_vertices[3 * size_t(artist.render_vertices[3 * r])];
    const float c = std::cos(0.7f), s = std::sin(0.7f);
    const float m[16] = {c, 0, -s, 0, 0, 1, 0, 0, s, 0, c, 0, 1, 2, 3, 1};
    std::vector<float> x(size_t(n) * 3), nr(size_t(rn) * 4);
    for (int step = 0; step < 12; ++step) {
      ASSERT_EQ(clothrt_player_advance(player, 1.0 / 45), CLOTHRT_OK);
      ASSERT_EQ(clothrt_player_get_positions(player, x.data(), 12, nullptr), CLOTHRT_OK);
      for (const float* mm : {static_cast<const float*>(nullptr), m}) {
        const clothrt_render_output out{nullptr, 0, nr.data(), 16, nullptr, 0};
        ASSERT_EQ(clothrt_player_get_render_mesh(player, &out, mm), CLOTHRT_OK);
        const std::vector<float> want = reference_normals(x, tri, sim_of_render, mm);
        for (uint32_t r = 0; r < rn; ++r)
          for (int k = 0; k < 3; ++k)
            ASSERT_EQ(nr[4 * r + k], want[3 * r + k])
                << "render vertex " << r << ", side " << side << (mm ? ", world" : "");
      }
    }
    clothrt_player_destroy(player);
    clothrt_db_close(db);
  }
}

TEST(RuntimeRender, ProceduralGarmentRendersItsSimulationMesh) {
  Opened h(false);
  const uint32_t n = clothrt_db_vertex_count(h.db);
  ASSERT_EQ(clothrt_db_render_vertex_count(h.db), n);
  std::vector<uint32_t> sim_tri(size_t(clothrt_db_triangle_count(h.db)) * 3),
      tri(size_t(clothrt_db_render_triangle_count(h.db)) * 3);
  ASSERT_EQ(clothrt_db_triangles(h.db, sim_tri.data(), sim_tri.size()), CLOTHRT_OK);
  ASSERT_EQ(clothrt_db_render_triangles(h.db, tri.data(), tri.size()), CLOTHRT_OK);
  EXPECT_EQ(tri, sim_tri);
  EXPECT_FALSE(clothrt_db_render_has_uvs(h.db));
  std::vector<float> uv(size_t(n) * 2), x(size_t(n) * 3), y(size_t(n) * 3), nr(size_t(n) * 4);
  EXPECT_EQ(clothrt_db_render_uvs(h.db, uv.data(), 8), CLOTHRT_ERR_NOT_FOUND);
  ASSERT_EQ(clothrt_player_advance(h.player, 0.5), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_get_positions(h.player, x.data(), 12, nullptr), CLOTHRT_OK);
  clothrt_render_output out{y.data(), 12, nr.data(), 16, nullptr, 0};
  ASSERT_EQ(clothrt_player_get_render_mesh(h.player, &out, nullptr), CLOTHRT_OK);
  EXPECT_EQ(x, y);
  for (uint32_t v = 0; v < n; ++v) EXPECT_NEAR(length(&nr[4 * v]), 1.0, 1e-5);
  // Tangents need UVs; strides below a vector or not a multiple of 4 are refused.
  out.tangents = nr.data();
  out.tangent_stride = 16;
  EXPECT_EQ(clothrt_player_get_render_mesh(h.player, &out, nullptr), CLOTHRT_ERR_INVALID);
  EXPECT_NE(std::string(clothrt_player_errmsg(h.player)).find("UVs"), std::string::npos);
  out.tangents = nullptr;
  out.normal_stride = 8;
  EXPECT_EQ(clothrt_player_get_render_mesh(h.player, &out, nullptr), CLOTHRT_ERR_INVALID);
  out.normal_stride = 14;
  EXPECT_EQ(clothrt_player_get_render_mesh(h.player, &out, nullptr), CLOTHRT_ERR_INVALID);
  EXPECT_EQ(clothrt_player_get_render_mesh(h.player, nullptr, nullptr), CLOTHRT_ERR_INVALID);
}

TEST(RuntimeRender, DamagedMapIsRefusedAtOpen) {
  test::TempDir dir;
  const std::string path = dir.file("bad_map.clothdb");
  synthetic::Spec spec = synthetic::demo_spec(kSide);
  spec.artist_mesh = true;
  synthetic::build(path, spec);
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  // The last artist vertex maps to a simulation vertex the garment does not have.
  ASSERT_EQ(sqlite3_exec(db,
                         "UPDATE garment_mesh SET map_vertices = "
                         "substr(map_vertices, 1, length(map_vertices) - 12) || "
                         "x'FFFF0000FFFF0000FFFF0000'",
                         nullptr, nullptr, nullptr),
            SQLITE_OK);
  sqlite3_close(db);
  clothrt_db* rt = nullptr;
  EXPECT_EQ(clothrt_db_open(path.c_str(), nullptr, &rt), CLOTHRT_ERR_CORRUPT);
  EXPECT_EQ(rt, nullptr);
  EXPECT_NE(std::string(clothrt_last_open_errmsg()).find("maps to simulation vertex 65535"),
            std::string::npos)
      << clothrt_last_open_errmsg();
}

TEST(RuntimeRender, NoAllocationPerFrameAfterWarmUp) {
  Opened h(true);
  const uint32_t rn = clothrt_db_render_vertex_count(h.db);
  std::vector<float> vb(size_t(rn) * 10);
  clothrt_render_output out{vb.data(), 40, vb.data() + 3, 40, vb.data() + 6, 40};
  const float m[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 2, 3, 1};
  ASSERT_EQ(clothrt_player_set_random(h.player, 1, 3), CLOTHRT_OK);
  auto frames = [&](int count) {
    for (int f = 0; f < count; ++f) {
      EXPECT_EQ(clothrt_player_advance(h.player, 1.0 / 60), CLOTHRT_OK);
      EXPECT_EQ(clothrt_player_get_render_mesh(h.player, &out, f % 2 ? m : nullptr), CLOTHRT_OK);
    }
  };
  // Warm up until the random path has decoded every clip of the graph.
  clothrt_stats s;
  for (int minute = 0; minute < 30; ++minute) {
    frames(3600);
    clothrt_db_stats(h.db, &s);
    if (s.clip_loads == h.built.clip.size()) break;
  }
  ASSERT_EQ(s.clip_loads, h.built.clip.size());
  const uint64_t before = g_allocations.load();
  frames(1800);
  EXPECT_EQ(g_allocations.load() - before, 0u);
  clothrt_stats after;
  clothrt_db_stats(h.db, &after);
  EXPECT_EQ(after.clip_loads, s.clip_loads);
  EXPECT_GT(after.frames_sampled, s.frames_sampled);
}

}  // namespace
}  // namespace clothdb
