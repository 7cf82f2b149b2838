// The mass-spring solver (Provot 1995, seed 001): Provot's deformation-rate limit and its three
// cases, energy behaviour with and without damping, instability reporting, collisions, pins.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <string>

#include "cloth/collision.hpp"
#include "cloth/mesh.hpp"
#include "cloth/model.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

using namespace clothdb;

namespace {

// Sub-steps per frame within the solver's own stability bound (with 10 % margin), so the tests
// follow the material whatever its defaults; StiffLargeStepRecommendationIsStable checks the bound.
int stable_substeps(const ClothModel& model, double dt) {
  return static_cast<int>(std::ceil(dt / (0.9 * mass_spring_critical_dt(model))));
}

SolverSettings ms_settings(int substeps) {
  SolverSettings s;
  s.substeps = substeps;
  return s;
}

// One triangle: vertices 0 and 1 one metre apart, vertex 2 far away so that only the spring
// 0-1 can be over-stretched. A zero Young's modulus makes every spring forceless, so one step
// with zero gravity applies Provot's limit alone.
ClothModel provot_triangle(std::vector<int> pins) {
  ClothMesh mesh;
  mesh.rest.resize(3, 3);
  mesh.rest.col(0) = Vec3(0, 0, 0);
  mesh.rest.col(1) = Vec3(1, 0, 0);
  mesh.rest.col(2) = Vec3(0.5, 10, 0);
  mesh.triangles = {{0, 1, 2}};
  build_topology(mesh);
  Material m;
  m.youngs_modulus = 0.0;
  return make_model(std::move(mesh), m, std::move(pins));
}

// Spring 0-1 stretched to 150 %, symmetric about x = 0.5; the other two edges stay within 0.2 %.
ClothState stretched_triangle_state(const ClothModel& model) {
  ClothState s = rest_state(model);
  s.x.col(0) = Vec3(-0.25, 0, 0);
  s.x.col(1) = Vec3(1.25, 0, 0);
  return s;
}

StepReport one_provot_step(const ClothModel& model, ClothState& state) {
  Environment env;
  env.gravity = Vec3::Zero();
  StepInputs in;
  in.env = &env;
  auto solver = make_mass_spring_solver(model, ms_settings(1));
  return solver->step(state, 0.01, in);
}

}  // namespace

TEST(MassSpringProvot, BothFreeMoveSymmetricallyToTheMiddle) {
  const ClothModel model = provot_triangle({});
  ClothState s = stretched_triangle_state(model);
  const StepReport r = one_provot_step(model, s);
  ASSERT_TRUE(r.stable) << r.message;
  // Each end moves (1.5 - 1.1) / 2 = 0.2 towards the middle (x = 0.5), along the spring.
  EXPECT_NEAR(s.x(0, 0), -0.05, 1e-9);
  EXPECT_NEAR(s.x(0, 1), 1.05, 1e-9);
  EXPECT_NEAR(0.5 * (s.x(0, 0) + s.x(0, 1)), 0.5, 1e-12);
  EXPECT_NEAR((s.x.col(1) - s.x.col(0)).norm(), 1.1, 1e-9);
  EXPECT_NEAR(s.x(1, 0), 0.0, 1e-12);
  EXPECT_NEAR(s.x(1, 1), 0.0, 1e-12);
  // The violation existed before the step, so its correction is not released as velocity (that
  // would be the super-elastic energy the limit denies): the vertices end at rest.
  EXPECT_LT(s.v.cwiseAbs().maxCoeff(), 1e-12);
  // The far vertex had no violated spring and no force: it does not move.
  EXPECT_NEAR((s.x.col(2) - model.mesh.rest.col(2)).norm(), 0.0, 1e-12);
}

TEST(MassSpringProvot, OnePinnedOnlyTheFreeEndMoves) {
  const ClothModel model = provot_triangle({0});
  ClothState s = stretched_triangle_state(model);
  const StepReport r = one_provot_step(model, s);
  ASSERT_TRUE(r.stable) << r.message;
  EXPECT_EQ(s.x.col(0), Vec3(-0.25, 0, 0));  // pinned: exactly where it was
  EXPECT_EQ(s.v.col(0), Vec3::Zero());
  EXPECT_NEAR(s.x(0, 1), -0.25 + 1.1, 1e-9);  // free end brought to 110 % of the rest length
  EXPECT_NEAR((s.x.col(1) - s.x.col(0)).norm(), 1.1, 1e-9);
}

TEST(MassSpringProvot, BothPinnedUnchanged) {
  const ClothModel model = provot_triangle({0, 1});
  ClothState s = stretched_triangle_state(model);
  const ClothState before = s;
  const StepReport r = one_provot_step(model, s);
  ASSERT_TRUE(r.stable) << r.message;
  EXPECT_EQ(s.x.col(0), before.x.col(0));
  EXPECT_EQ(s.x.col(1), before.x.col(1));
  EXPECT_NEAR((s.x.col(1) - s.x.col(0)).norm(), 1.5, 1e-12);
}

TEST(MassSpring, ProvotLimitHoldsEveryFrameOnHangingSheet) {
  // The hanging-sheet scene with a fabric soft enough (E t = 5 N/m) that its own weight would
  // stretch the springs near the two pinned corners far beyond 10 %: Provot's limit must hold
  // them at 10 % after every frame. The same run with the limit effectively off (tau_c = 10)
  // shows that the limit, not the springs, is what keeps the strain down.
  ClothScene scene = make_hard_case("hanging-sheet", 9);
  Material soft = scene.model.material;
  soft.youngs_modulus = 1.0e4;
  scene.model = make_model(scene.model.mesh, soft, scene.model.kinematic);
  auto run_with = [&](double critical_rate) {
    SolverSettings s = ms_settings(stable_substeps(scene.model, scene.frame_dt));
    s.provot_critical_rate = critical_rate;
    auto solver = make_mass_spring_solver(scene.model, s);
    return run_scene(scene, *solver, 30, false);
  };
  const RunResult run = run_with(0.1);
  ASSERT_TRUE(run.stable) << run.message;
  ASSERT_EQ(run.metrics.size(), 31u);
  for (size_t f = 0; f < run.metrics.size(); ++f) {
    EXPECT_LE(run.metrics[f].max_strain, 0.1 + 1e-3) << "frame " << f;
    // Energy bounded: starting at rest, kinetic + gravity energy can only fall (damping, drag and
    // Provot's inelastic correction dissipate; springs store the rest). Slack: the symplectic
    // integrator's O(h) energy fluctuation, far below the ~0.5 J the sheet releases.
    EXPECT_LE(run.metrics[f].total_energy, 1e-4) << "frame " << f;
  }
  EXPECT_GT(run.metrics.back().max_strain, 0.09);  // the limit is active
  const RunResult unlimited = run_with(10.0);
  ASSERT_TRUE(unlimited.stable) << unlimited.message;
  EXPECT_GT(unlimited.metrics.back().max_strain, 0.2);
}

TEST(MassSpring, KineticEnergyDecaysWithDampingOnly) {
  // A free, soft sheet without gravity given a breathing velocity v = a (x - c): no rigid
  // motion, so only the springs' damping can remove the energy.
  auto run = [](double damping, double& peak_ratio, double& late_ratio) {
    ClothMesh mesh = make_quad_grid(11, 11, 0.5, 0.5);
    Material m;
    m.youngs_modulus = 2.0e5;  // E t = 100 N/m
    m.damping = damping;
    const ClothModel model = make_model(std::move(mesh), m, {});
    Environment env;
    env.gravity = Vec3::Zero();
    StepInputs in;
    in.env = &env;
    ClothState s = rest_state(model);
    const Vec3 c(0.25, 0.25, 0);
    for (int i = 0; i < model.vertex_count(); ++i) s.v.col(i) = 1.0 * (s.x.col(i) - c);
    const double ke0 = kinetic_energy(model, s.v);
    auto solver = make_mass_spring_solver(model, ms_settings(stable_substeps(model, 1.0 / 30.0)));
    peak_ratio = 0.0;
    double late_sum = 0.0;
    const int frames = 15;
    for (int f = 0; f < frames; ++f) {
      const StepReport r = solver->step(s, 1.0 / 30.0, in);
      ASSERT_TRUE(r.stable) << r.message;
      const double ke = kinetic_energy(model, s.v);
      peak_ratio = std::max(peak_ratio, ke / ke0);
      if (f >= frames - 5) late_sum += ke / ke0;
    }
    late_ratio = late_sum / 5.0;
  };
  double damped_peak = 0, damped_late = 0, free_peak = 0, free_late = 0;
  run(1e-2, damped_peak, damped_late);
  run(0.0, free_peak, free_late);
  // Energy bounded: no frame has more kinetic energy than the initial total (all kinetic).
  EXPECT_LE(damped_peak, 1.02);
  EXPECT_LE(free_peak, 1.02);
  // With damping the motion dies out; without it the energy keeps oscillating between kinetic and
  // elastic, so the decay is the damping force's doing, not numerical dissipation.
  EXPECT_LT(damped_late, 1e-3);
  EXPECT_GT(free_late, 0.1);
}

TEST(MassSpring, StiffLargeStepReportsUnstableWithoutNaN) {
  // One 1/30 s step per frame, no sub-steps: far beyond the explicit stability limit. The solver
  // must refuse (or, for a run-away it could not foresee, notice), leave the state as it was and
  // say why; and it must never hand back a NaN.
  const ClothScene scene = make_hard_case("stiff-large-step");
  ASSERT_GT(scene.frame_dt, mass_spring_critical_dt(scene.model));
  auto solver = make_mass_spring_solver(scene.model, ms_settings(1));
  ClothState s = scene.initial;
  Environment env = scene.env;
  StepInputs in;
  in.env = &env;
  StepReport r;
  int steps = 0;
  ClothState before;
  for (; steps < 10; ++steps) {
    before = s;
    r = solver->step(s, scene.frame_dt, in);
    ASSERT_TRUE(s.x.allFinite() && s.v.allFinite()) << "step " << steps;
    if (!r.stable) break;
  }
  ASSERT_FALSE(r.stable) << "no instability reported in 10 steps";
  EXPECT_NE(r.message.find("mass-spring"), std::string::npos) << r.message;
  EXPECT_NE(r.message.find("unstable"), std::string::npos) << r.message;
  EXPECT_NE(r.message.find("substeps"), std::string::npos) << r.message;
  // The failed step left the state exactly as it was before it.
  EXPECT_TRUE(s.x == before.x);
  EXPECT_TRUE(s.v == before.v);
  // Through run_scene: the run stops with the message, and no recorded frame holds a NaN.
  auto fresh = make_mass_spring_solver(scene.model, ms_settings(1));
  const RunResult run = run_scene(scene, *fresh, 10, true);
  EXPECT_FALSE(run.stable);
  EXPECT_NE(run.message.find("unstable"), std::string::npos) << run.message;
  for (const auto& x : run.frames) EXPECT_TRUE(x.allFinite());
  for (const auto& m : run.metrics) EXPECT_LE(m.max_strain, 1.0);
}

TEST(MassSpring, StiffLargeStepRecommendationIsStable) {
  // The message recommends dt / mass_spring_critical_dt sub-steps: a Gershgorin bound on the
  // stiffest mode including damping. As an upper bound on the frequency it must be enough.
  const ClothScene scene = make_hard_case("stiff-large-step", 5);
  auto coarse = make_mass_spring_solver(scene.model, ms_settings(1));
  const RunResult failed = run_scene(scene, *coarse, 10, false);
  ASSERT_FALSE(failed.stable);
  const size_t at = failed.message.find(">= ");
  ASSERT_NE(at, std::string::npos) << failed.message;
  const int needed = std::atoi(failed.message.c_str() + at + 3);
  EXPECT_EQ(needed,
            static_cast<int>(std::ceil(scene.frame_dt / mass_spring_critical_dt(scene.model))));
  auto solver = make_mass_spring_solver(scene.model, ms_settings(needed));
  const RunResult run = run_scene(scene, *solver, 6, false);
  EXPECT_TRUE(run.stable) << run.message;
  for (const auto& m : run.metrics) EXPECT_LE(m.max_strain, 0.1 + 1e-3);
}

TEST(MassSpring, SphereDrapeKeepsOutOfTheSphere) {
  const ClothScene scene = make_hard_case("sphere-drape", 9);
  auto solver = make_mass_spring_solver(scene.model,
                                        ms_settings(stable_substeps(scene.model, scene.frame_dt)));
  const RunResult run = run_scene(scene, *solver, 12, true);
  ASSERT_TRUE(run.stable) << run.message;
  const double thickness = scene.model.material.thickness;
  for (size_t f = 0; f < run.metrics.size(); ++f)
    EXPECT_LE(run.metrics[f].max_penetration, thickness) << "frame " << f;
  // Not vacuous: the sheet has reached the sphere and rests on it at the margin.
  const SphereCollider& sphere = scene.env.spheres.at(0);
  double closest = 1e9;
  for (Eigen::Index i = 0; i < run.frames.back().cols(); ++i)
    closest = std::min(closest, (run.frames.back().col(i) - sphere.center).norm() - sphere.radius);
  EXPECT_LT(closest, 2.0 * scene.env.collision_margin);
  EXPECT_GT(closest, -thickness);
}

TEST(MassSpring, PinsFollowTheirTargetsAndThreadsDoNotChangeResults) {
  const ClothScene scene = make_hard_case("swung-sheet", 7);
  auto run_with = [&](int threads) {
    SolverSettings s = ms_settings(stable_substeps(scene.model, scene.frame_dt));
    s.threads = threads;
    auto solver = make_mass_spring_solver(scene.model, s);
    return run_scene(scene, *solver, 4, true);
  };
  const RunResult one = run_with(1), four = run_with(4);
  ASSERT_TRUE(one.stable) << one.message;
  ASSERT_TRUE(four.stable) << four.message;
  for (size_t f = 1; f < one.frames.size(); ++f) {
    const Eigen::Matrix3Xd target = scene.kinematic_path(f * scene.frame_dt);
    EXPECT_LT((kinematic_positions(scene.model, one.frames[f]) - target).cwiseAbs().maxCoeff(),
              1e-12);
    EXPECT_EQ(one.frames[f], four.frames[f]) << "frame " << f;
  }
}

TEST(MassSpring, DescribeNamesSettings) {
  const ClothScene scene = make_hard_case("hanging-sheet", 5);
  auto solver = make_mass_spring_solver(scene.model, ms_settings(7));
  const std::string d = solver->describe();
  EXPECT_EQ(d.rfind("mass-spring", 0), 0u) << d;
  EXPECT_NE(d.find("substeps=7"), std::string::npos) << d;
}
