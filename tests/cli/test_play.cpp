// `clothdb play` (cli/cmd_play.cpp): the body's colliders written beside the cloth, frame for
// frame in the same character space, and previews framed on the garment from the chosen view.
// The database is tests/data/v3_small.clothdb (made from tests/data/mpi_small.json, a skirt on
// CMU 01_01), copied so that the runtime's files land in a temporary folder.
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

#include "exchange/point_cache.hpp"
#include "support/cli.hpp"

namespace {

namespace fs = std::filesystem;
const std::string kSource = CLOTHDB_SOURCE_DIR;

fs::path work_dir() {
  const fs::path dir = fs::path(testing::TempDir()) / ("clothdb_play_" + std::to_string(getpid()));
  fs::create_directories(dir);
  return dir;
}

std::string database() {
  const fs::path to = work_dir() / "small.clothdb";
  if (!fs::exists(to)) fs::copy_file(kSource + "/tests/data/v3_small.clothdb", to);
  return to.string();
}

clothdb::test::CliResult run(const std::vector<std::string>& args) {
  return clothdb::test::run_clothdb(args, (work_dir() / "log.txt").string());
}

}  // namespace

TEST(PlayCli, WritesTheBodyBesideTheCloth) {
  const std::string out = (work_dir() / "play").string();
  const auto r =
      run({"play", database(), "--scene", kSource + "/tests/data/mpi_small.json", "--seconds", "2",
           "--out", out, "--preview-every", "30", "--width", "64", "--height", "48"});
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("body.obj,body.pc2"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("from the front"), std::string::npos) << r.output;
  ASSERT_TRUE(fs::exists(out + "/body.obj"));
  const clothdb::PointCache cloth = clothdb::read_pc2(out + "/cloth.pc2");
  const clothdb::PointCache body = clothdb::read_pc2(out + "/body.pc2");
  EXPECT_GT(body.vertex_count, 0);
  ASSERT_EQ(body.frame_count, cloth.frame_count) << "one body frame per cloth frame";
  EXPECT_EQ(cloth.frame_count, 61);
  // Frame by frame, the skirt hangs around the body: its centre is inside the body's bounds
  // (both in character space), and the body is the size of a person.
  for (int f = 0; f < cloth.frame_count; f += 10) {
    Eigen::Vector3d lo(1e9, 1e9, 1e9), hi(-1e9, -1e9, -1e9), centre(0, 0, 0);
    for (int v = 0; v < body.vertex_count; ++v)
      for (int k = 0; k < 3; ++k) {
        const double x = body.positions[(size_t(f) * body.vertex_count + v) * 3 + k];
        lo[k] = std::min(lo[k], x);
        hi[k] = std::max(hi[k], x);
      }
    for (int v = 0; v < cloth.vertex_count; ++v)
      for (int k = 0; k < 3; ++k)
        centre[k] += cloth.positions[(size_t(f) * cloth.vertex_count + v) * 3 + k];
    centre /= cloth.vertex_count;
    EXPECT_TRUE((centre.array() > lo.array()).all() && (centre.array() < hi.array()).all())
        << "frame " << f << ": skirt centre " << centre.transpose() << " outside the body "
        << lo.transpose() << " .. " << hi.transpose();
    EXPECT_GT(hi.y() - lo.y(), 0.4) << "the body's colliders span the hips and legs";
  }
  EXPECT_TRUE(fs::exists(out + "/previews/frame_0000.png"));
  // From behind: the view is named in the output.
  const std::string back = (work_dir() / "play_back").string();
  const auto b =
      run({"play", database(), "--scene", kSource + "/tests/data/mpi_small.json", "--seconds",
           "0.5", "--out", back, "--view", "back", "--width", "64", "--height", "48"});
  ASSERT_EQ(b.code, 0) << b.output;
  EXPECT_NE(b.output.find("from the back"), std::string::npos) << b.output;
  fs::remove_all(work_dir());
}

// Without the scene the database was made from, the cloth is written alone and the reason said.
TEST(PlayCli, WithoutItsSceneWritesTheClothAndSaysWhy) {
  const std::string out = (work_dir() / "alone").string();
  const auto r = run({"play", database(), "--scene", (work_dir() / "missing.json").string(),
                      "--seconds", "0.5", "--out", out, "--preview-every", "0"});
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("without the body"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(out + "/cloth.pc2"));
  EXPECT_FALSE(fs::exists(out + "/body.pc2"));
  fs::remove_all(work_dir());
}
