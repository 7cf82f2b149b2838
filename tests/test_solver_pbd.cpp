// The PBD solver (Mueller et al. 2007, seed 000 Algorithm 1): stretch and bending constraints,
// stiffness, the velocity update, collisions and pins.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "cloth/collision.hpp"
#include "cloth/mesh.hpp"
#include "cloth/model.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

using namespace clothdb;

namespace {

SolverSettings pbd_settings(int substeps, int iterations, double stretch, double bend) {
  SolverSettings s;
  s.substeps = substeps;
  s.iterations = iterations;
  s.pbd_stretch_stiffness = stretch;
  s.pbd_bend_stiffness = bend;
  return s;
}

double final_strain(const ClothScene& scene, const SolverSettings& s, int frames) {
  auto solver = make_pbd_solver(scene.model, s);
  const RunResult run = run_scene(scene, *solver, frames, false);
  EXPECT_TRUE(run.stable) << run.message;
  return run.metrics.back().max_strain;
}

// A horizontal sheet (XZ plane) at height y0, no pins.
ClothModel horizontal_sheet(int n, double size, double y0) {
  ClothMesh mesh = make_quad_grid(n, n, size, size);
  Eigen::Matrix3d lay;
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(-0.5 * size, y0, 0.5 * size));
  return make_model(std::move(mesh), Material{}, {});
}

}  // namespace

TEST(Pbd, HangingSheetStaysFiniteWithSmallStrain) {
  // Gauss-Seidel PBD only approaches the constraints: with enough iterations the hanging sheet's
  // edges stay within 2 % of their rest length every frame, and more iterations mean less strain.
  const ClothScene scene = make_hard_case("hanging-sheet", 11);
  auto run_with = [&](int iterations) {
    auto solver = make_pbd_solver(scene.model, pbd_settings(10, iterations, 1.0, -1.0));
    return run_scene(scene, *solver, 45, true);
  };
  const RunResult run = run_with(50), few = run_with(2);
  ASSERT_TRUE(run.stable) << run.message;
  ASSERT_TRUE(few.stable) << few.message;
  for (size_t f = 0; f < run.frames.size(); ++f) {
    EXPECT_TRUE(run.frames[f].allFinite()) << "frame " << f;
    EXPECT_TRUE(few.frames[f].allFinite()) << "frame " << f;
    EXPECT_LE(run.metrics[f].max_strain, 0.02) << "frame " << f;
  }
  EXPECT_GT(few.metrics.back().max_strain, run.metrics.back().max_strain);
}

TEST(Pbd, StretchStiffnessChangesStretch) {
  // Same scene and iterations; only the stretch stiffness differs. With k = 1 the edges hold
  // their length; with a soft k the sheet visibly stretches under its own weight, and with k = 0
  // nothing resists stretch at all.
  const ClothScene scene = make_hard_case("hanging-sheet", 11);
  const double stiff = final_strain(scene, pbd_settings(5, 20, 1.0, 0.0), 20);
  const double soft = final_strain(scene, pbd_settings(5, 20, 0.02, 0.0), 20);
  const double none = final_strain(scene, pbd_settings(5, 20, 0.0, 0.0), 20);
  EXPECT_LT(stiff, 0.05);
  EXPECT_GT(soft, 3.0 * stiff);
  EXPECT_GT(none, soft);
  EXPECT_GT(none, 1.0);
}

TEST(Pbd, IterationCountIndependentStiffness) {
  // Mueller 2007 sec. 3.3: k' = 1 - (1 - k)^(1/n) makes a soft k give about the same stretch with
  // 5 or 40 iterations (a plain per-iteration k would be 8x stiffer with 40).
  const ClothScene scene = make_hard_case("hanging-sheet", 11);
  const double few = final_strain(scene, pbd_settings(5, 5, 0.05, 0.0), 20);
  const double many = final_strain(scene, pbd_settings(5, 40, 0.05, 0.0), 20);
  EXPECT_GT(few, 0.01);
  EXPECT_NEAR(many / few, 1.0, 0.35);
}

TEST(Pbd, FreeFallMatchesSymplecticEuler) {
  // No pins, no colliders, no drag: every vertex falls with the symplectic Euler discretisation
  // of Algorithm 1: v_k = -g k h, y_k = y_0 - g h^2 k (k + 1) / 2 after k sub-steps.
  const ClothModel model = horizontal_sheet(4, 0.3, 1.0);
  Environment env;
  StepInputs in;
  in.env = &env;
  const double g = -env.gravity.y();
  for (int substeps : {1, 3}) {
    auto solver = make_pbd_solver(model, pbd_settings(substeps, 10, 1.0, 1.0));
    ClothState s = rest_state(model);
    const double dt = 1.0 / 30.0, h = dt / substeps;
    for (int step = 1; step <= 10; ++step) {
      const Eigen::Matrix3Xd x_before = s.x;
      const StepReport r = solver->step(s, dt, in);
      ASSERT_TRUE(r.stable) << r.message;
      const double k = step * substeps;
      for (int i = 0; i < model.vertex_count(); ++i) {
        EXPECT_NEAR(s.x(1, i), 1.0 - g * h * h * k * (k + 1) / 2.0, 1e-12) << "vertex " << i;
        EXPECT_NEAR(s.v(1, i), -g * h * k, 1e-12);
        EXPECT_NEAR(s.x(0, i), model.mesh.rest(0, i), 1e-12);
        EXPECT_NEAR(s.x(2, i), model.mesh.rest(2, i), 1e-12);
        // Algorithm 1 line 19: v = (p - x) / h; with one sub-step that is the step's displacement.
        if (substeps == 1) {
          EXPECT_NEAR(s.v(1, i), (s.x(1, i) - x_before(1, i)) / dt, 1e-12);
        }
      }
    }
  }
}

TEST(Pbd, RestsOnAPlaneWithoutPenetrating) {
  const ClothModel model = horizontal_sheet(9, 0.5, 0.1);
  Environment env;
  env.planes.push_back(PlaneCollider{Vec3(0, 1, 0), 0.0});
  env.collision_margin = model.material.thickness;
  StepInputs in;
  in.env = &env;
  auto solver = make_pbd_solver(model, pbd_settings(4, 10, 1.0, -1.0));
  ClothState s = rest_state(model);
  for (int f = 0; f < 30; ++f) {
    const StepReport r = solver->step(s, 1.0 / 30.0, in);
    ASSERT_TRUE(r.stable) << r.message;
    EXPECT_LE(max_penetration(s.x, model.inv_mass, env), 0.0) << "frame " << f;
    EXPECT_GE(s.x.row(1).minCoeff(), env.collision_margin - 1e-12) << "frame " << f;
  }
  // After 1 s it has landed (a 0.1 m fall takes 0.14 s) and lies at the margin, at rest.
  EXPECT_NEAR(s.x.row(1).maxCoeff(), env.collision_margin, 1e-9);
  EXPECT_LT(s.v.cwiseAbs().maxCoeff(), 1e-6);
}

TEST(Pbd, SphereDrapeKeepsOutOfTheSphere) {
  const ClothScene scene = make_hard_case("sphere-drape", 11);
  auto solver = make_pbd_solver(scene.model, pbd_settings(4, 20, 1.0, -1.0));
  const RunResult run = run_scene(scene, *solver, 20, true);
  ASSERT_TRUE(run.stable) << run.message;
  for (size_t f = 0; f < run.metrics.size(); ++f)
    EXPECT_LE(run.metrics[f].max_penetration, scene.model.material.thickness) << "frame " << f;
  const SphereCollider& sphere = scene.env.spheres.at(0);
  double closest = 1e9;
  for (Eigen::Index i = 0; i < run.frames.back().cols(); ++i)
    closest = std::min(closest, (run.frames.back().col(i) - sphere.center).norm() - sphere.radius);
  EXPECT_LT(closest, 2.0 * scene.env.collision_margin);  // it did reach the sphere
}

TEST(Pbd, BendingStiffnessResistsSagging) {
  // A clamped horizontal strip: with bending constraints it sags less than without.
  const ClothScene scene = make_hard_case("cantilever", 11);
  auto tip_drop = [&](double bend) {
    auto solver = make_pbd_solver(scene.model, pbd_settings(5, 20, 1.0, bend));
    const RunResult run = run_scene(scene, *solver, 30, true);
    EXPECT_TRUE(run.stable) << run.message;
    return scene.initial.x.row(1).minCoeff() - run.frames.back().row(1).minCoeff();
  };
  const double limp = tip_drop(0.0), stiff = tip_drop(1.0), material = tip_drop(-1.0);
  EXPECT_GT(limp, 0.05);
  EXPECT_LT(stiff, 0.5 * limp);
  // The material-derived stiffness lies in between.
  EXPECT_LE(material, limp + 1e-9);
  EXPECT_GE(material, stiff - 1e-9);
}

TEST(Pbd, PinsFollowTheirTargets) {
  const ClothScene scene = make_hard_case("swung-sheet", 9);
  auto solver = make_pbd_solver(scene.model, pbd_settings(5, 10, 1.0, -1.0));
  const RunResult run = run_scene(scene, *solver, 15, true);
  ASSERT_TRUE(run.stable) << run.message;
  for (size_t f = 1; f < run.frames.size(); ++f) {
    const Eigen::Matrix3Xd target = scene.kinematic_path(f * scene.frame_dt);
    EXPECT_LT((kinematic_positions(scene.model, run.frames[f]) - target).cwiseAbs().maxCoeff(),
              1e-12);
    EXPECT_TRUE(run.frames[f].allFinite());
  }
}

TEST(Pbd, MaterialDerivedStiffnessIsStableOnHardCases) {
  for (const std::string name : {"stretched-start", "slivers", "stiff-large-step"}) {
    const ClothScene scene = make_hard_case(name, 9);
    auto solver = make_pbd_solver(scene.model, pbd_settings(1, 10, -1.0, -1.0));
    const RunResult run = run_scene(scene, *solver, 30, true);
    EXPECT_TRUE(run.stable) << name << ": " << run.message;
    for (const auto& x : run.frames) EXPECT_TRUE(x.allFinite()) << name;
  }
}

TEST(Pbd, DescribeNamesSettings) {
  const ClothScene scene = make_hard_case("hanging-sheet", 5);
  auto solver = make_pbd_solver(scene.model, pbd_settings(3, 7, 1.0, -1.0));
  const std::string d = solver->describe();
  EXPECT_EQ(d.rfind("pbd", 0), 0u) << d;
  EXPECT_NE(d.find("substeps=3"), std::string::npos) << d;
  EXPECT_NE(d.find("iterations=7"), std::string::npos) << d;
}
