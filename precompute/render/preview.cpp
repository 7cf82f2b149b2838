#include "render/preview.hpp"

#include <GL/gl.h>
#include <GL/glu.h>
#include <GL/osmesa.h>
#include <png.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>

#include "report/output.hpp"

namespace clothdb {

namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

void draw_capsule(GLUquadric* quad, const Vec3& a, const Vec3& b, double r) {
  const Vec3 d = b - a;
  const double len = d.norm();
  glPushMatrix();
  glTranslated(a.x(), a.y(), a.z());
  gluSphere(quad, r, 16, 10);
  if (len > 1e-9) {
    // gluCylinder runs along +z: rotate +z onto d.
    const Vec3 z(0, 0, 1);
    const Vec3 axis = z.cross(d / len);
    const double angle = std::atan2(axis.norm(), z.dot(d / len)) * kRadToDeg;
    if (axis.norm() > 1e-9) {
      glRotated(angle, axis.x(), axis.y(), axis.z());
    } else if (d.z() < 0) {
      glRotated(180.0, 1, 0, 0);
    }
    gluCylinder(quad, r, r, len, 16, 1);
    glTranslated(0, 0, len);
    gluSphere(quad, r, 16, 10);
  }
  glPopMatrix();
}

std::array<float, 3> heat_color(float t) {
  t = std::clamp(t, 0.0f, 1.0f);  // blue -> green -> red
  if (t < 0.5f) return {0.2f, 0.3f + 1.2f * t, 1.0f - 1.6f * t};
  return {2.0f * (t - 0.5f) + 0.2f, 0.9f - 1.6f * (t - 0.5f), 0.2f};
}

struct OsmesaContext {
  OSMesaContext ctx = nullptr;
  ~OsmesaContext() {
    if (ctx) OSMesaDestroyContext(ctx);
  }
};

}  // namespace

const char* preview_view_name(PreviewView view) {
  switch (view) {
    case PreviewView::Front:
      return "front";
    case PreviewView::Back:
      return "back";
    case PreviewView::Side:
      return "side";
  }
  return "?";
}

PreviewView parse_preview_view(const std::string& text) {
  if (text == "front") return PreviewView::Front;
  if (text == "back") return PreviewView::Back;
  if (text == "side") return PreviewView::Side;
  throw std::invalid_argument("unknown view '" + text + "' (expected front, back or side)");
}

PreviewCamera frame_points(const Eigen::Matrix3Xd& points, double margin, PreviewView view) {
  PreviewCamera cam;
  if (points.cols() == 0) return cam;
  const Vec3 lo = points.rowwise().minCoeff(), hi = points.rowwise().maxCoeff();
  const Vec3 center = 0.5 * (lo + hi);
  const double radius = std::max(0.5 * (hi - lo).norm(), 0.05) * margin;
  // The bounding sphere fits the vertical field of view (previews are wider than tall).
  const double distance = radius / std::sin(0.5 * cam.fov_degrees / kRadToDeg);
  const Vec3 direction = view == PreviewView::Front  ? Vec3(0.35, 0.3, 1.0)
                         : view == PreviewView::Back ? Vec3(-0.35, 0.3, -1.0)
                                                     : Vec3(1.0, 0.3, 0.35);
  cam.target = center;
  cam.eye = center + distance * direction.normalized();
  return cam;
}

Eigen::Vector3d project_to_preview(const PreviewCamera& camera, const Vec3& point, int width,
                                   int height) {
  // gluLookAt's frame and gluPerspective's projection, as render_preview sets them.
  const Vec3 forward = (camera.target - camera.eye).normalized();
  const Vec3 right = forward.cross(camera.up).normalized();
  const Vec3 up = right.cross(forward);
  const Vec3 d = point - camera.eye;
  const double depth = d.dot(forward);
  const double f = 1.0 / std::tan(0.5 * camera.fov_degrees / kRadToDeg);
  const double aspect = static_cast<double>(width) / height;
  const double ndc_x = f / aspect * d.dot(right) / depth, ndc_y = f * d.dot(up) / depth;
  return {0.5 * (ndc_x + 1.0) * width, 0.5 * (1.0 - ndc_y) * height, depth};
}

std::vector<std::uint8_t> render_preview(const PreviewScene& scene, const PreviewCamera& camera,
                                         int width, int height) {
  OsmesaContext context;
  context.ctx = OSMesaCreateContextExt(OSMESA_RGBA, 24, 0, 0, nullptr);
  if (!context.ctx) throw std::runtime_error("OSMesa: cannot create an offscreen GL context");
  std::vector<std::uint8_t> pixels(static_cast<size_t>(width) * height * 4);
  if (!OSMesaMakeCurrent(context.ctx, pixels.data(), GL_UNSIGNED_BYTE, width, height))
    throw std::runtime_error("OSMesa: cannot make the offscreen context current");

  glViewport(0, 0, width, height);
  glClearColor(0.96f, 0.96f, 0.97f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glMatrixMode(GL_PROJECTION);
  glLoadIdentity();
  gluPerspective(camera.fov_degrees, static_cast<double>(width) / height, 0.01, 100.0);
  glMatrixMode(GL_MODELVIEW);
  glLoadIdentity();
  gluLookAt(camera.eye.x(), camera.eye.y(), camera.eye.z(), camera.target.x(), camera.target.y(),
            camera.target.z(), camera.up.x(), camera.up.y(), camera.up.z());

  glEnable(GL_LIGHTING);
  glEnable(GL_LIGHT0);
  glEnable(GL_LIGHT1);
  glEnable(GL_NORMALIZE);
  glEnable(GL_COLOR_MATERIAL);
  glColorMaterial(GL_FRONT_AND_BACK, GL_AMBIENT_AND_DIFFUSE);
  glLightModeli(GL_LIGHT_MODEL_TWO_SIDE, GL_TRUE);  // cloth has two visible sides
  const GLfloat key[] = {0.4f, 1.0f, 0.8f, 0.0f}, fill[] = {-0.6f, 0.3f, -0.5f, 0.0f};
  const GLfloat key_color[] = {0.8f, 0.8f, 0.8f, 1}, fill_color[] = {0.35f, 0.35f, 0.4f, 1};
  const GLfloat ambient[] = {0.25f, 0.25f, 0.25f, 1};
  glLightfv(GL_LIGHT0, GL_POSITION, key);
  glLightfv(GL_LIGHT0, GL_DIFFUSE, key_color);
  glLightfv(GL_LIGHT1, GL_POSITION, fill);
  glLightfv(GL_LIGHT1, GL_DIFFUSE, fill_color);
  glLightModelfv(GL_LIGHT_MODEL_AMBIENT, ambient);

  if (scene.floor) {
    glDisable(GL_LIGHTING);
    glColor3f(0.8f, 0.8f, 0.82f);
    glBegin(GL_LINES);
    for (int i = -10; i <= 10; ++i) {
      const double s = 0.25 * i;
      glVertex3d(s, scene.floor_height, -2.5);
      glVertex3d(s, scene.floor_height, 2.5);
      glVertex3d(-2.5, scene.floor_height, s);
      glVertex3d(2.5, scene.floor_height, s);
    }
    glEnd();
    glEnable(GL_LIGHTING);
  }

  std::unique_ptr<GLUquadric, void (*)(GLUquadric*)> quad(gluNewQuadric(), gluDeleteQuadric);
  glColor3f(0.82f, 0.80f, 0.74f);  // skeleton: light warm grey
  for (const auto& c : scene.skeleton) draw_capsule(quad.get(), c.a, c.b, c.radius);
  glColor3f(0.30f, 0.48f, 0.78f);  // colliders: blue
  for (const auto& c : scene.capsules) draw_capsule(quad.get(), c.a, c.b, c.radius);
  for (const auto& s : scene.spheres) draw_capsule(quad.get(), s.center, s.center, s.radius);

  if (scene.cloth && scene.triangles) {
    const Eigen::Matrix3Xd& x = *scene.cloth;
    // Smooth vertex normals from the triangles.
    Eigen::Matrix3Xd normals = Eigen::Matrix3Xd::Zero(3, x.cols());
    for (const auto& t : *scene.triangles) {
      const Vec3 n = (x.col(t[1]) - x.col(t[0])).cross(x.col(t[2]) - x.col(t[0]));
      for (int k = 0; k < 3; ++k) normals.col(t[k]) += n;
    }
    const bool heat = scene.vertex_heat.size() == static_cast<size_t>(x.cols());
    glColor3f(scene.cloth_color[0], scene.cloth_color[1], scene.cloth_color[2]);
    glBegin(GL_TRIANGLES);
    for (const auto& t : *scene.triangles) {
      for (int k = 0; k < 3; ++k) {
        if (heat) {
          const auto c = heat_color(scene.vertex_heat[t[k]]);
          glColor3f(c[0], c[1], c[2]);
        }
        const Vec3 n = normals.col(t[k]);
        glNormal3d(n.x(), n.y(), n.z());
        glVertex3d(x(0, t[k]), x(1, t[k]), x(2, t[k]));
      }
    }
    glEnd();
  }
  glFinish();

  // GL's first row is the bottom one: flip to top-to-bottom.
  const size_t row = static_cast<size_t>(width) * 4;
  for (int y = 0; y < height / 2; ++y)
    std::swap_ranges(pixels.begin() + y * row, pixels.begin() + (y + 1) * row,
                     pixels.begin() + (height - 1 - y) * row);
  return pixels;
}

void write_png(const std::string& path, const std::vector<std::uint8_t>& rgba, int width,
               int height) {
  if (rgba.size() != static_cast<size_t>(width) * height * 4)
    throw std::runtime_error(path + ": image buffer does not match " + std::to_string(width) + "x" +
                             std::to_string(height));
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  image.width = static_cast<png_uint_32>(width);
  image.height = static_cast<png_uint_32>(height);
  image.format = PNG_FORMAT_RGBA;
  png_alloc_size_t size = 0;
  if (!png_image_write_to_memory(&image, nullptr, &size, 0, rgba.data(), 0, nullptr))
    throw std::runtime_error(path + ": PNG encoding failed: " + image.message);
  std::string bytes(size, '\0');
  if (!png_image_write_to_memory(&image, bytes.data(), &size, 0, rgba.data(), 0, nullptr))
    throw std::runtime_error(path + ": PNG encoding failed: " + image.message);
  bytes.resize(size);
  write_file_atomic(path, bytes);
}

void draw_border(std::vector<std::uint8_t>& rgba, int width, int height, int thickness,
                 std::array<std::uint8_t, 3> color) {
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      if (x >= thickness && x < width - thickness && y >= thickness && y < height - thickness)
        continue;
      std::uint8_t* p = &rgba[(static_cast<size_t>(y) * width + x) * 4];
      p[0] = color[0], p[1] = color[1], p[2] = color[2], p[3] = 255;
    }
}

void draw_number(std::vector<std::uint8_t>& rgba, int width, int height, int x0, int y0,
                 long number, int scale, std::array<std::uint8_t, 3> color) {
  // 3 x 5 bitmaps, one row per 3 bits (top row first), for 0..9.
  static const std::uint16_t kDigits[10] = {0x7B6F, 0x2C97, 0x73E7, 0x73CF, 0x5BC9,
                                            0x79CF, 0x79EF, 0x7249, 0x7BEF, 0x7BCF};
  const std::string text = std::to_string(std::max(0L, number));
  const int box_w = (static_cast<int>(text.size()) * 4 + 1) * scale, box_h = 7 * scale;
  auto put = [&](int x, int y, std::array<std::uint8_t, 3> c) {
    if (x < 0 || y < 0 || x >= width || y >= height) return;
    std::uint8_t* p = &rgba[(static_cast<size_t>(y) * width + x) * 4];
    p[0] = c[0], p[1] = c[1], p[2] = c[2], p[3] = 255;
  };
  for (int y = 0; y < box_h; ++y)
    for (int x = 0; x < box_w; ++x) put(x0 + x, y0 + y, {255, 255, 255});
  for (size_t d = 0; d < text.size(); ++d) {
    const std::uint16_t bits = kDigits[text[d] - '0'];
    for (int row = 0; row < 5; ++row)
      for (int col = 0; col < 3; ++col) {
        if (!((bits >> (14 - 3 * row - col)) & 1)) continue;
        for (int sy = 0; sy < scale; ++sy)
          for (int sx = 0; sx < scale; ++sx)
            put(x0 + (1 + 4 * static_cast<int>(d) + col) * scale + sx, y0 + (1 + row) * scale + sy,
                color);
      }
  }
}

std::vector<std::uint8_t> contact_sheet(const std::vector<std::vector<std::uint8_t>>& tiles,
                                        int width, int height, int columns) {
  const int rows = static_cast<int>((tiles.size() + columns - 1) / columns);
  const int sheet_w = width * columns;
  std::vector<std::uint8_t> sheet(static_cast<size_t>(sheet_w) * height * std::max(rows, 1) * 4,
                                  255);
  for (size_t i = 0; i < tiles.size(); ++i) {
    const int cx = static_cast<int>(i) % columns, cy = static_cast<int>(i) / columns;
    for (int y = 0; y < height; ++y)
      std::copy_n(
          tiles[i].begin() + static_cast<size_t>(y) * width * 4, width * 4,
          sheet.begin() + (static_cast<size_t>(cy * height + y) * sheet_w + cx * width) * 4);
  }
  return sheet;
}

}  // namespace clothdb
