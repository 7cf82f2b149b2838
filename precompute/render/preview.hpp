// Headless PNG previews of cloth and body colliders, rendered offscreen with Mesa's OSMesa
// (software OpenGL: no display, no GPU) and written with libpng.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "cloth/collision.hpp"

namespace clothdb {

struct PreviewCamera {
  Vec3 eye{0, 1.2, 3.0};
  Vec3 target{0, 0.8, 0};
  Vec3 up{0, 1, 0};
  double fov_degrees = 40.0;
};

struct PreviewScene {
  const Eigen::Matrix3Xd* cloth = nullptr;  // positions (3 x n)
  const std::vector<std::array<int, 3>>* triangles = nullptr;
  std::vector<CapsuleCollider> capsules;  // colliders, drawn at their end pose (a, b)
  // The whole skeleton as thinner capsules in a lighter shade than the colliders, so a preview
  // shows a person and which of their bones the cloth meets (docs/GUIDE.md#blender-and-previews).
  std::vector<CapsuleCollider> skeleton;
  std::vector<SphereCollider> spheres;
  bool floor = true;  // a grid floor at y = floor_height
  double floor_height = 0.0;
  // Per-vertex highlight (e.g. strain or penetration in [0, 1] -> colour ramp); empty: plain cloth.
  std::vector<float> vertex_heat;
  std::array<float, 3> cloth_color{0.85f, 0.35f, 0.3f};
};

// Where a preview looks from, in character space (the character faces +z): the front (+z), the
// back (-z: a cape) or the side (+x), each a little above and off-axis so depth reads.
enum class PreviewView { Front, Back, Side };
const char* preview_view_name(PreviewView view);  // "front", "back", "side"
// Parses "front"/"back"/"side"; throws std::invalid_argument naming the accepted values.
PreviewView parse_preview_view(const std::string& text);

// A camera that frames the given points (their bounding sphere times `margin`) from `view`.
PreviewCamera frame_points(const Eigen::Matrix3Xd& points, double margin = 1.3,
                           PreviewView view = PreviewView::Front);

// Pixel coordinates (x right, y down, from the top-left corner) of `point` in a width x height
// preview through `camera`; z of the result is the depth along the view (< 0: behind the eye).
Eigen::Vector3d project_to_preview(const PreviewCamera& camera, const Vec3& point, int width,
                                   int height);

// Renders to RGBA8, rows top to bottom. Throws std::runtime_error if OSMesa cannot create a
// context.
std::vector<std::uint8_t> render_preview(const PreviewScene& scene, const PreviewCamera& camera,
                                         int width, int height);

// Writes RGBA8 pixels (rows top to bottom) as a PNG, atomically; throws naming the path.
void write_png(const std::string& path, const std::vector<std::uint8_t>& rgba, int width,
               int height);

// Marks an RGBA image (rows top to bottom): a frame `thickness` pixels wide around its edge.
void draw_border(std::vector<std::uint8_t>& rgba, int width, int height, int thickness,
                 std::array<std::uint8_t, 3> color);
// Writes a non-negative integer at pixel (x, y) (top left of the text) in a 3 x 5 pixel digit
// font scaled by `scale`, on a white box so it reads on any background. Clipped to the image.
void draw_number(std::vector<std::uint8_t>& rgba, int width, int height, int x, int y, long number,
                 int scale, std::array<std::uint8_t, 3> color);

// Pastes `tiles` (all width x height RGBA) into a grid `columns` wide; unused cells are white.
std::vector<std::uint8_t> contact_sheet(const std::vector<std::vector<std::uint8_t>>& tiles,
                                        int width, int height, int columns);

}  // namespace clothdb
