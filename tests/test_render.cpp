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

// frame_points frames the garment from each view: every point projects inside the image, the
// garment fills a good part of it, and the back view looks at the side facing -z (a cape).
TEST(Render, FramedViewsKeepTheGarmentInTheImage) {
  // A cape-like sheet behind a character facing +z: 0.6 m wide, 0.8 m tall, at z = -0.15.
  ClothMesh sheet = make_quad_grid(7, 9, 0.6, 0.8);
  sheet.rest.row(0).array() -= 0.3;
  sheet.rest.row(1).array() += 0.6;
  sheet.rest.row(2).array() = -0.15;
  const int w = 96, h = 72;
  for (PreviewView view : {PreviewView::Front, PreviewView::Back, PreviewView::Side}) {
    SCOPED_TRACE(preview_view_name(view));
    EXPECT_EQ(parse_preview_view(preview_view_name(view)), view);
    const PreviewCamera cam = frame_points(sheet.rest, 1.3, view);
    Eigen::Vector2d lo(1e9, 1e9), hi(-1e9, -1e9);
    for (Eigen::Index v = 0; v < sheet.rest.cols(); ++v) {
      const Eigen::Vector3d p = project_to_preview(cam, sheet.rest.col(v), w, h);
      EXPECT_GT(p.z(), 0.0) << "in front of the eye";
      EXPECT_GE(p.x(), 0.0);
      EXPECT_LE(p.x(), w);
      EXPECT_GE(p.y(), 0.0);
      EXPECT_LE(p.y(), h);
      lo = lo.cwiseMin(p.head<2>());
      hi = hi.cwiseMax(p.head<2>());
    }
    EXPECT_GT(hi.y() - lo.y(), 0.4 * h) << "the garment fills the frame's height";
    // The eye is on the viewed side of the sheet: +z in front, -z behind, +x at the side.
    if (view == PreviewView::Front) {
      EXPECT_GT(cam.eye.z(), 0.0);
    }
    if (view == PreviewView::Back) {
      EXPECT_LT(cam.eye.z(), -0.15);
    }
    if (view == PreviewView::Side) {
      EXPECT_GT(cam.eye.x(), 0.3);
    }
    // The projection agrees with the renderer: the sheet's centre lands on cloth pixels.
    PreviewScene scene;
    scene.cloth = &sheet.rest;
    scene.triangles = &sheet.triangles;
    scene.floor = false;
    const auto img = render_preview(scene, cam, w, h);
    const Eigen::Vector3d c = project_to_preview(cam, sheet.rest.rowwise().mean(), w, h);
    const auto px = pixel(img, w, int(c.x()), int(c.y()));
    EXPECT_GT(px[0], px[2] + 40) << "cloth at the projected centre";
  }
  EXPECT_THROW(parse_preview_view("top"), std::invalid_argument);
}
