// Headless previews: the renderer draws what it is given where the camera looks, and the PNG
// files read back with the same pixels.
#include <gtest/gtest.h>
#include <png.h>

#include <filesystem>

#include "cloth/mesh.hpp"
#include "render/preview.hpp"

using namespace clothdb;

namespace {

std::array<int, 3> pixel(const std::vector<std::uint8_t>& rgba, int w, int x, int y) {
  const size_t i = (static_cast<size_t>(y) * w + x) * 4;
  return {rgba[i], rgba[i + 1], rgba[i + 2]};
}

}  // namespace

TEST(Render, ClothAppearsWhereTheCameraLooks) {
  ClothMesh sheet = make_quad_grid(5, 5, 1.0, 1.0);
  sheet.rest.row(0).array() -= 0.5;  // centred on x = 0, spanning y in [0, 1]
  PreviewScene scene;
  scene.cloth = &sheet.rest;
  scene.triangles = &sheet.triangles;
  scene.floor = false;
  PreviewCamera cam;
  cam.eye = Vec3(0, 0.5, 3);
  cam.target = Vec3(0, 0.5, 0);
  const int w = 64, h = 48;
  const auto img = render_preview(scene, cam, w, h);
  ASSERT_EQ(img.size(), static_cast<size_t>(w * h * 4));
  const auto centre = pixel(img, w, w / 2, h / 2);
  EXPECT_GT(centre[0], centre[2] + 40) << "the red cloth should cover the centre";
  const auto corner = pixel(img, w, 1, 1);
  EXPECT_GT(corner[2], 200) << "the background should show at the corner";
  // Moving the cloth out of view leaves only background at the centre.
  Eigen::Matrix3Xd away = sheet.rest;
  away.row(0).array() += 50.0;
  scene.cloth = &away;
  const auto empty = render_preview(scene, cam, w, h);
  EXPECT_GT(pixel(empty, w, w / 2, h / 2)[2], 200);
}

TEST(Render, CapsuleIsDrawn) {
  PreviewScene scene;
  scene.floor = false;
  CapsuleCollider c;
  c.a = Vec3(0, 0, 0);
  c.b = Vec3(0, 1, 0);
  c.radius = 0.2;
  scene.capsules.push_back(c);
  PreviewCamera cam;
  cam.eye = Vec3(0, 0.5, 3);
  cam.target = Vec3(0, 0.5, 0);
  const int w = 64, h = 48;
  const auto img = render_preview(scene, cam, w, h);
  const auto centre = pixel(img, w, w / 2, h / 2), side = pixel(img, w, 2, h / 2);
  EXPECT_NE(centre, side);
}

TEST(Render, PngRoundTrip) {
  const int w = 7, h = 5;
  std::vector<std::uint8_t> rgba(w * h * 4);
  for (size_t i = 0; i < rgba.size(); ++i) rgba[i] = static_cast<std::uint8_t>(i * 37);
  const std::string path = testing::TempDir() + "/clothdb_roundtrip.png";
  write_png(path, rgba, w, h);
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  ASSERT_TRUE(png_image_begin_read_from_file(&image, path.c_str()));
  EXPECT_EQ(image.width, static_cast<unsigned>(w));
  EXPECT_EQ(image.height, static_cast<unsigned>(h));
  image.format = PNG_FORMAT_RGBA;
  std::vector<std::uint8_t> back(PNG_IMAGE_SIZE(image));
  ASSERT_TRUE(png_image_finish_read(&image, nullptr, back.data(), 0, nullptr));
  EXPECT_EQ(back, rgba);
  EXPECT_THROW(write_png("/nonexistent-dir/x.png", rgba, w, h), std::runtime_error);
  EXPECT_THROW(write_png(path, rgba, w + 1, h), std::runtime_error);
  std::filesystem::remove(path);
}

TEST(Render, ContactSheetPlacesTiles) {
  std::vector<std::vector<std::uint8_t>> tiles(3, std::vector<std::uint8_t>(2 * 2 * 4, 0));
  tiles[1].assign(16, 100);
  const auto sheet = contact_sheet(tiles, 2, 2, 2);  // 2 columns, 2 rows
  ASSERT_EQ(sheet.size(), static_cast<size_t>(4 * 4 * 4));
  EXPECT_EQ(pixel(sheet, 4, 0, 0)[0], 0);
  EXPECT_EQ(pixel(sheet, 4, 2, 0)[0], 100);
  EXPECT_EQ(pixel(sheet, 4, 3, 3)[0], 255);  // the unused cell stays white
}
