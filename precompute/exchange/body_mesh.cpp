#include "exchange/body_mesh.hpp"

#include <cmath>

namespace clothdb {

std::vector<std::array<int, 3>> capsule_mesh_triangles(int capsule_count, int segments) {
  std::vector<std::array<int, 3>> tris;
  const int per = 2 * segments + 2;  // two rings and two cap centres
  for (int c = 0; c < capsule_count; ++c) {
    const int base = c * per, top = base + 2 * segments, bottom = top + 1;
    for (int s = 0; s < segments; ++s) {
      const int s1 = (s + 1) % segments;
      const int a0 = base + s, a1 = base + s1, b0 = base + segments + s, b1 = base + segments + s1;
      tris.push_back({a0, a1, b1});
      tris.push_back({a0, b1, b0});
      tris.push_back({top, a1, a0});
      tris.push_back({bottom, b0, b1});
    }
  }
  return tris;
}

void append_capsule_mesh_positions(const std::vector<CapsuleCollider>& capsules,
                                   std::vector<float>& out, int segments) {
  for (const auto& c : capsules) {
    Vec3 axis = c.b - c.a;
    if (axis.norm() < 1e-9) axis = Vec3(0, 1, 0);
    axis.normalize();
    const Vec3 u = axis.unitOrthogonal(), w = axis.cross(u);
    auto push = [&](const Vec3& p) {
      out.push_back(static_cast<float>(p.x()));
      out.push_back(static_cast<float>(p.y()));
      out.push_back(static_cast<float>(p.z()));
    };
    for (const Vec3* end : {&c.a, &c.b})
      for (int s = 0; s < segments; ++s) {
        const double phi = 2.0 * 3.14159265358979323846 * s / segments;
        push(*end + c.radius * (std::cos(phi) * u + std::sin(phi) * w));
      }
    push(c.a - c.radius * axis);
    push(c.b + c.radius * axis);
  }
}

}  // namespace clothdb
