// The body colliders as a triangle mesh (a low-poly tube with end rings per capsule), so a clip
// exported for Blender carries the body as a separate reference object with its own point cache.
#pragma once

#include <array>
#include <vector>

#include "cloth/collision.hpp"

namespace clothdb {

// Triangles of the tube mesh for `capsule_count` capsules (the topology does not change per frame).
std::vector<std::array<int, 3>> capsule_mesh_triangles(int capsule_count, int segments = 8);
// Vertex positions (float x, y, z) of the tube mesh at the capsules' end pose (a, b), appended to
// `out`: per capsule, a ring of `segments` vertices around each end, pushed out by the radius.
void append_capsule_mesh_positions(const std::vector<CapsuleCollider>& capsules,
                                   std::vector<float>& out, int segments = 8);

}  // namespace clothdb
