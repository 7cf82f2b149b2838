// The cloth model: meshes, welding, topology, masses, colliders, and the shared scenes.
#include <gtest/gtest.h>

#include <cmath>

#include "cloth/collision.hpp"
#include "cloth/mesh.hpp"
#include "cloth/model.hpp"
#include "hard_cases/hard_cases.hpp"

using namespace clothdb;

TEST(Mesh, QuadGridCounts) {
  const ClothMesh m = make_quad_grid(5, 4, 1.0, 0.75);
  EXPECT_EQ(m.vertex_count(), 20);
  EXPECT_EQ(m.triangles.size(), 2u * 4 * 3);
  // Euler: E = V + F - 1 for a disc; interior edges are hinges.
  EXPECT_EQ(m.edges.size(), 20u + 24u - 1u);
  const size_t boundary = 2 * (4 + 3);
  EXPECT_EQ(m.hinges.size(), m.edges.size() - boundary);
}

TEST(Mesh, EquilateralSheetIsEquilateral) {
  const double edge = 0.05;
  const ClothMesh m = make_equilateral_sheet(22, 22, edge);
  EXPECT_EQ(m.vertex_count(), 22 * 22);
  for (const auto& e : m.edges) {
    EXPECT_NEAR((m.rest.col(e[0]) - m.rest.col(e[1])).norm(), edge, 1e-12);
  }
  for (const auto& t : m.triangles) {
    EXPECT_NEAR(triangle_area(m.rest, t), std::sqrt(3.0) / 4 * edge * edge, 1e-12);
    // Counter-clockwise seen from +z.
    const Vec3 n = (m.rest.col(t[1]) - m.rest.col(t[0])).cross(m.rest.col(t[2]) - m.rest.col(t[0]));
    EXPECT_GT(n.z(), 0.0);
  }
}

TEST(Mesh, HingesShareTheirEdge) {
  const ClothMesh m = make_quad_grid(4, 4, 1, 1);
  for (const auto& h : m.hinges) {
    int found = 0;
    for (const auto& t : m.triangles) {
      auto has = [&](int v) { return t[0] == v || t[1] == v || t[2] == v; };
      if (has(h.v0) && has(h.v1) && (has(h.a) || has(h.b))) ++found;
    }
    EXPECT_EQ(found, 2);
    EXPECT_NE(h.a, h.b);
  }
}

TEST(Mesh, WeldMergesSeamDuplicates) {
  // Two quads exported as separate pieces: the shared seam's two vertices are duplicated.
  Eigen::Matrix3Xd p(3, 8);
  p << 0, 1, 1, 0, 1, 2, 2, 1,  //
      0, 0, 1, 1, 0, 0, 1, 1,   //
      0, 0, 0, 0, 0, 0, 0, 1e-7;
  std::vector<std::array<int, 3>> tris{{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {4, 6, 7}};
  std::vector<int> remap;
  const ClothMesh m = weld_vertices(p, tris, 1e-5, &remap);
  EXPECT_EQ(m.vertex_count(), 6);
  EXPECT_EQ(remap[1], remap[4]);
  EXPECT_EQ(remap[2], remap[7]);
  EXPECT_EQ(m.hinges.size(), 3u);  // two quad diagonals and the welded seam
}

TEST(Mesh, RejectsNonManifoldAndBadIndices) {
  ClothMesh m;
  m.rest = Eigen::Matrix3Xd::Random(3, 5);
  m.triangles = {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}};
  EXPECT_THROW(build_topology(m), MeshError);
  m.triangles = {{0, 1, 7}};
  try {
    build_topology(m);
    FAIL() << "expected MeshError";
  } catch (const MeshError& e) {
    EXPECT_NE(std::string(e.what()).find("triangle 0"), std::string::npos) << e.what();
  }
  m.triangles = {{0, 1, 2}, {0, 1, 3}};  // same directed edge twice: inconsistent orientation
  EXPECT_THROW(build_topology(m), MeshError);
}

TEST(Model, MassesFromAreaDensity) {
  Material mat;
  mat.density = 0.2;
  const ClothModel model = make_model(make_quad_grid(11, 6, 2.0, 1.0), mat, {0, 10});
  EXPECT_NEAR(model.mass.sum(), 0.2 * 2.0 * 1.0, 1e-12);
  EXPECT_EQ(model.inv_mass[0], 0.0);
  EXPECT_EQ(model.inv_mass[10], 0.0);
  EXPECT_NEAR(model.inv_mass[5], 1.0 / model.mass[5], 1e-9);
  EXPECT_THROW(make_model(make_quad_grid(3, 3, 1, 1), mat, {9}), MeshError);
  EXPECT_THROW(make_model(make_quad_grid(3, 3, 1, 1), mat, {1, 1}), MeshError);
}

TEST(Model, EdgeAreaIsTheRestAreaOfTheEdgesTriangles) {
  // A 2 m x 1 m grid of 10 x 5 cells, two triangles each: every triangle counts towards its
  // three edges, an interior edge has two triangles and a border edge one.
  const ClothModel model = make_model(make_quad_grid(11, 6, 2.0, 1.0), Material{}, {});
  ASSERT_EQ(model.edge_area.size(), model.mesh.edges.size());
  double sum = 0.0;
  const double triangle = 0.5 * 0.2 * 0.2;
  for (std::size_t e = 0; e < model.mesh.edges.size(); ++e) {
    const auto [i, j] = model.mesh.edges[e];
    const bool border_x = (i % 11 == j % 11) && (i % 11 == 0 || i % 11 == 10);
    const bool border_y = (i / 11 == j / 11) && (i / 11 == 0 || i / 11 == 5);
    EXPECT_NEAR(model.edge_area[e], (border_x || border_y ? 1.0 : 2.0) * triangle, 1e-12)
        << "edge " << i << "-" << j;
    sum += model.edge_area[e];
  }
  EXPECT_NEAR(sum, 3.0 * 2.0 * 1.0, 1e-9);
}

TEST(Collision, ProjectsOutOfSphereToMargin) {
  Environment env;
  env.collision_margin = 0.002;
  SphereCollider s;
  s.radius = 0.5;
  env.spheres.push_back(s);
  Eigen::Matrix3Xd x(3, 2), x0(3, 2);
  x0 << 0, 2, 0.6, 2, 0, 2;
  x << 0, 2, 0.3, 2, 0, 2;  // vertex 0 moved straight down into the sphere
  Eigen::VectorXd w = Eigen::VectorXd::Ones(2);
  EXPECT_GT(max_penetration(x, w, env), 0.19);
  EXPECT_EQ(resolve_collisions(x, x0, w, env, 1.0), 1);
  EXPECT_NEAR(x.col(0).norm(), 0.5 + 0.002, 1e-12);
  EXPECT_EQ(max_penetration(x, w, env), 0.0);
  EXPECT_EQ(x.col(1), Vec3(2, 2, 2));
}

TEST(Collision, FrictionSticksThenSlides) {
  Environment env;
  env.planes.push_back(PlaneCollider{});
  env.collision_margin = 0.0;
  env.friction_static = 0.5;
  env.friction_kinetic = 0.5;
  Eigen::VectorXd w = Eigen::VectorXd::Ones(1);
  Eigen::Matrix3Xd x0(3, 1), x(3, 1);
  // Small slide under a deep correction: static friction holds it in place.
  x0 << 0, 0.0, 0;
  x << 0.01, -0.1, 0;
  resolve_collisions(x, x0, w, env, 1.0);
  EXPECT_NEAR(x(0, 0), 0.0, 1e-12);
  EXPECT_NEAR(x(1, 0), 0.0, 1e-12);
  // Large slide under a shallow correction: kinetic friction removes mu * depth of it.
  x << 1.0, -0.1, 0;
  resolve_collisions(x, x0, w, env, 1.0);
  EXPECT_NEAR(x(0, 0), 1.0 - 0.5 * 0.1, 1e-12);
}

TEST(Collision, MovingCapsulePushesWithItsMotion) {
  Environment env;
  env.collision_margin = 0.0;
  env.friction_static = 10.0;  // stick
  CapsuleCollider c;
  c.a_start = Vec3(0, 0, 0);
  c.b_start = Vec3(0, 1, 0);
  c.a = Vec3(0.03, 0.02, 0);  // the limb moves 3 cm sideways and 2 cm along its axis
  c.b = Vec3(0.03, 1.02, 0);
  c.radius = 0.05;
  env.capsules.push_back(c);
  Eigen::VectorXd w = Eigen::VectorXd::Ones(1);
  Eigen::Matrix3Xd x0(3, 1), x(3, 1);
  x0 << 0.07, 0.5, 0;  // 2 cm outside the surface at the start
  x = x0;              // the vertex did not move; the capsule moved into it
  resolve_collisions(x, x0, w, env, 1.0, 0.0);
  // Pushed out along the normal (+x) onto the surface, and carried along the axis by friction.
  EXPECT_NEAR(x(0, 0), 0.08, 1e-12);
  EXPECT_NEAR(x(1, 0), 0.52, 1e-12);
  // With the surface taken as still (s_start = s), nothing carries it along the axis.
  x = x0;
  resolve_collisions(x, x0, w, env, 1.0);
  EXPECT_NEAR(x(1, 0), 0.5, 1e-12);
}

// The body's surface nearest a vertex, for the self-contacts' room (self_collision.hpp, kBodyGive):
// the nearer of two capsules at the pose asked, with its outward normal; the margin as the least
// distance (where a response leaves a vertex); nothing beyond the reach. Fails if the pose
// fraction is ignored, a farther capsule is taken, or the reach is not kept to.
TEST(Collision, NearestSurfaceIsTheNearestCapsuleAtThePoseWithinReach) {
  Environment env;
  env.collision_margin = 0.004;
  CapsuleCollider near_one;
  near_one.a_start = Vec3(0, 0, 0);
  near_one.b_start = Vec3(0, 1, 0);
  near_one.a = Vec3(0.1, 0, 0);  // moves 10 cm along +x over the step
  near_one.b = Vec3(0.1, 1, 0);
  near_one.radius = 0.05;
  CapsuleCollider far_one = near_one;
  far_one.a_start = far_one.a = Vec3(0, 0, 0.2);
  far_one.b_start = far_one.b = Vec3(0, 1, 0.2);
  env.capsules = {far_one, near_one};
  // 2 cm out of the near capsule's surface (+x) at the start pose, 3 cm inside at the half pose.
  const Vec3 p(0.07, 0.5, 0);
  const NearSurface half = nearest_surface(p, env, 0.5, 0.03);
  EXPECT_NEAR(half.distance, 0.004, 1e-12) << "inside: the margin, where a response leaves it";
  EXPECT_NEAR(half.normal.x(), 1.0, 1e-12);
  const NearSurface start = nearest_surface(p, env, 0.0, 0.03);
  EXPECT_NEAR(start.distance, 0.02, 1e-12);
  EXPECT_NEAR(start.normal.x(), 1.0, 1e-12);
  EXPECT_EQ(nearest_surface(p, env, 0.0, 0.015).distance, INFINITY) << "2 cm is beyond the reach";
  EXPECT_EQ(nearest_surface(Vec3(0.07, 0.5, 0.3), env, 0.0, 0.03).distance, INFINITY);
  const NearSurface other = nearest_surface(Vec3(0, 0.5, 0.27), env, 0.0, 0.03);
  EXPECT_NEAR(other.distance, 0.02, 1e-12);
  EXPECT_NEAR(other.normal.z(), 1.0, 1e-12);
}

TEST(Collision, FastCapsuleTunnelsUnlessSwept) {
  // A limb moving 3 radii in one step past a still vertex: projected at the end pose the vertex is
  // already behind it (no contact at all: tunnelled); with the limb 2.2 radii on, the vertex is
  // inside near the back and the nearest-surface projection puts it out the back. Swept, the
  // vertex is found where the limb's front met it and leaves on the front, carried ahead.
  Environment env;
  env.collision_margin = 0.002;
  env.friction_static = 0.0;
  env.friction_kinetic = 0.0;
  CapsuleCollider c;
  c.radius = 0.05;
  c.a_start = Vec3(-0.08, 0, 0);
  c.b_start = Vec3(-0.08, 1, 0);
  Eigen::VectorXd w = Eigen::VectorXd::Ones(1);
  Eigen::Matrix3Xd x0(3, 1);
  x0 << 0, 0.5, 0;
  for (double travel : {0.15, 0.11}) {  // 3 radii: clean past it; 2.2 radii: ends 3 cm past it
    SCOPED_TRACE(travel);
    c.a = Vec3(c.a_start.x() + travel, 0, 0);
    c.b = Vec3(c.b_start.x() + travel, 1, 0);
    env.capsules = {c};
    const double end_axis = c.a.x();
    for (ColliderMotion m : {ColliderMotion::EndPose, ColliderMotion::Interpolated}) {
      env.collider_motion = m;
      Eigen::Matrix3Xd x = x0;
      resolve_collisions(x, x0, w, env, 1.0, 0.0);
      EXPECT_LT(x(0, 0), end_axis)
          << collider_motion_name(m) << ": expected behind the limb (tunnelled)";
      EXPECT_GT(path_depth_fraction(x0.col(0), x.col(0), c), 0.5) << collider_motion_name(m);
    }
    env.collider_motion = ColliderMotion::Swept;
    Eigen::Matrix3Xd x = x0;
    EXPECT_EQ(resolve_collisions(x, x0, w, env, 1.0, 0.0), 1);
    EXPECT_NEAR(x(0, 0), end_axis + c.radius + env.collision_margin, 1e-6) << "on the limb's front";
    EXPECT_NEAR(x(1, 0), 0.5, 1e-9);
    EXPECT_LT(path_depth_fraction(x0.col(0), x.col(0), c), 0.05);
    EXPECT_EQ(max_penetration(x, w, env), 0.0);
  }
  // Split into 4 sub-steps (limb moving under a radius per sub-step), plain interpolation
  // is enough: the vertex is pushed ahead step by step.
  env.collider_motion = ColliderMotion::Interpolated;
  c.a = Vec3(c.a_start.x() + 0.15, 0, 0);
  c.b = Vec3(c.b_start.x() + 0.15, 1, 0);
  env.capsules = {c};
  Eigen::Matrix3Xd x = x0;
  for (int k = 0; k < 4; ++k) {
    const Eigen::Matrix3Xd start = x;
    resolve_collisions(x, start, w, env, (k + 1) / 4.0, k / 4.0);
  }
  EXPECT_NEAR(x(0, 0), c.a.x() + c.radius + env.collision_margin, 1e-9);
}

TEST(Scenes, EveryHardCaseBuilds) {
  for (const auto& name : hard_case_names()) {
    const ClothScene s = make_hard_case(name);
    EXPECT_EQ(s.name, name);
    EXPECT_GT(s.model.vertex_count(), 100) << name;
    EXPECT_TRUE(s.initial.x.allFinite()) << name;
    if (s.kinematic_path) {
      EXPECT_EQ(s.kinematic_path(0.1).cols(), static_cast<Eigen::Index>(s.model.kinematic.size()));
    }
  }
  EXPECT_THROW(make_hard_case("no-such-scene"), std::invalid_argument);
  EXPECT_GT(max_edge_strain(make_hard_case("stretched-start").model,
                            make_hard_case("stretched-start").initial.x),
            0.49);
  EXPECT_EQ(make_large_sheet(10000).model.vertex_count(), 10000);
  EXPECT_EQ(make_seed004_grid().model.vertex_count(), 529);
}

TEST(Scenes, SwungSheetPinsReachFiveMetresPerSecond) {
  const ClothScene s = make_hard_case("swung-sheet");
  const double dt = 1e-4;
  double peak = 0;
  for (double t = 0; t < 0.5; t += dt) {
    peak = std::max(peak, (s.kinematic_path(t + dt) - s.kinematic_path(t)).col(0).norm() / dt);
  }
  EXPECT_NEAR(peak, 5.0, 0.01);
}
