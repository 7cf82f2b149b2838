// Blender exchange formats: PC2 point caches and OBJ meshes round-trip, and bad files are refused
// with the file and the problem named.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <vector>

#include "exchange/point_cache.hpp"

using namespace clothdb;

namespace {
std::string temp(const std::string& name) {
  return testing::TempDir() + "/clothdb_" + name;
}
}  // namespace

TEST(PointCache, RoundTripIsExact) {
  PointCache c;
  c.vertex_count = 5;
  c.frame_count = 3;
  c.start_frame = 1;
  c.sample_rate = 1;
  for (int i = 0; i < 45; ++i) c.positions.push_back(0.001f * i - 0.02f);
  write_pc2(temp("a.pc2"), c);
  EXPECT_EQ(std::filesystem::file_size(temp("a.pc2")), 32u + 45u * 4u);
  const PointCache back = read_pc2(temp("a.pc2"));
  EXPECT_EQ(back.vertex_count, 5);
  EXPECT_EQ(back.frame_count, 3);
  EXPECT_EQ(back.start_frame, 1.0f);
  EXPECT_EQ(back.positions, c.positions);
}

TEST(PointCache, RefusesBadFiles) {
  PointCache c;
  c.vertex_count = 2;
  c.frame_count = 2;
  c.positions.assign(12, 0.5f);
  write_pc2(temp("b.pc2"), c);
  std::filesystem::resize_file(temp("b.pc2"), 40);
  try {
    read_pc2(temp("b.pc2"));
    FAIL();
  } catch (const ExchangeError& e) {
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("b.pc2"), std::string::npos) << e.what();
  }
  std::ofstream(temp("c.pc2")) << "this is not a point cache at all, no sir";
  EXPECT_THROW(read_pc2(temp("c.pc2")), ExchangeError);
  EXPECT_THROW(read_pc2(temp("missing.pc2")), ExchangeError);
  c.positions.pop_back();
  EXPECT_THROW(write_pc2(temp("d.pc2"), c), ExchangeError);
  EXPECT_FALSE(std::filesystem::exists(temp("d.pc2")));
}

TEST(Obj, RoundTripAndPolygons) {
  const float p[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
  write_obj(temp("q.obj"), "sheet", p, 4, {{0, 1, 2}, {0, 2, 3}});
  const ObjMesh m = read_obj(temp("q.obj"));
  ASSERT_EQ(m.positions.size(), 12u);
  EXPECT_EQ(m.triangles.size(), 2u);
  EXPECT_EQ(m.triangles[1], (std::array<int, 3>{0, 2, 3}));
  EXPECT_EQ(m.groups[0], "sheet");
  std::ofstream(temp("quad.obj")) << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                                     "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n"
                                     "g front\nusemtl cloth\nf 1/1/1 2/2/1 3/3/1 -1/4/-1\n";
  const ObjMesh quad = read_obj(temp("quad.obj"));
  EXPECT_EQ(quad.triangles.size(), 2u);
  // The face as given: one quad, its corners' vertices, UVs and normals.
  EXPECT_EQ(quad.face_sizes, (std::vector<uint32_t>{4}));
  EXPECT_EQ(quad.corners, (std::vector<uint32_t>{0, 1, 2, 3}));
  EXPECT_EQ(quad.corner_uvs, (std::vector<uint32_t>{0, 1, 2, 3}));
  EXPECT_EQ(quad.corner_normals, (std::vector<uint32_t>{0, 0, 0, 0}));
  EXPECT_EQ(quad.uvs.size(), 8u);
  ASSERT_EQ(quad.face_groups.size(), 1u);
  EXPECT_EQ(quad.face_groups[0].name, "front");
  EXPECT_EQ(quad.face_groups[0].material, "cloth");
  // A corner naming a UV the file does not have is refused with its line.
  std::ofstream(temp("no_uv.obj")) << "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1/1 2/2 3/3\n";
  try {
    read_obj(temp("no_uv.obj"));
    FAIL();
  } catch (const ExchangeError& e) {
    EXPECT_NE(std::string(e.what()).find("no_uv.obj:4: face texture coordinate index 1/1"),
              std::string::npos)
        << e.what();
  }
  std::ofstream(temp("bad.obj")) << "v 0 0 0\nv 1 0 0\nf 1 2 9\n";
  try {
    read_obj(temp("bad.obj"));
    FAIL();
  } catch (const ExchangeError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.obj:3"), std::string::npos) << e.what();
  }
}
