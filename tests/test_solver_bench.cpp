// The solver benchmark's own logic: mass-spring sub-steps derived from the stability limit, the
// cap on them, and one measured row against its reference.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "bench/solver_bench.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

using namespace clothdb;

TEST(SolverBench, MassSpringSubstepsComeFromTheStabilityLimit) {
  const ClothScene scene = make_hard_case("hanging-sheet", 6);
  SolverBenchOptions options;
  const double critical = mass_spring_critical_dt(scene.model);
  ASSERT_TRUE(std::isfinite(critical));
  for (BenchConfig c : bench_configs(SolverKind::MassSpring, false)) {
    std::string why;
    ASSERT_TRUE(resolve_config(c, scene, options, why)) << why;
    // Every sub-step within the limit, and not wastefully far below it.
    const double h = scene.frame_dt / c.settings.substeps;
    EXPECT_LE(h, critical);
    EXPECT_GT(h, 0.45 * critical / c.critical_multiple);
    EXPECT_NE(c.label.find("substeps=" + std::to_string(c.settings.substeps)), std::string::npos);
  }
  // The derived rows run stably; a quarter of those sub-steps does not (so the derivation is
  // what makes them stable).
  BenchConfig c = bench_configs(SolverKind::MassSpring, true).front();
  std::string why;
  ASSERT_TRUE(resolve_config(c, scene, options, why));
  const BenchConfig ref_config = reference_config();
  auto ref = make_solver(ref_config.kind, scene.model, ref_config.settings);
  const RunResult reference = run_scene(scene, *ref, 3, true);
  const BenchRow row = measure_config(scene, c, 3, reference);
  EXPECT_TRUE(row.stable) << row.message;
  EXPECT_TRUE(std::isfinite(row.rms_error_mm));
  EXPECT_EQ(row.frames, 3);
  BenchConfig coarse = c;
  coarse.settings.substeps = std::max(1, c.settings.substeps / 4);
  EXPECT_FALSE(measure_config(scene, coarse, 3, reference).stable);
}

TEST(SolverBench, MassSpringOverTheCapIsNotRun) {
  const ClothScene scene = make_hard_case("hanging-sheet", 6);
  SolverBenchOptions options;
  options.max_mass_spring_substeps = 10;
  BenchConfig c = bench_configs(SolverKind::MassSpring, true).front();
  std::string why;
  EXPECT_FALSE(resolve_config(c, scene, options, why));
  EXPECT_NE(why.find("sub-steps"), std::string::npos) << why;
}

TEST(SolverBench, NewtonRowsMeasureIterationsAndFactorisations) {
  const ClothScene scene = make_hard_case("hanging-sheet", 7);
  const BenchConfig ref_config = reference_config();
  auto ref = make_solver(ref_config.kind, scene.model, ref_config.settings);
  const RunResult reference = run_scene(scene, *ref, 3, true);
  const BenchConfig c = newton_study_configs().front();
  const BenchRow row = measure_config(scene, c, 3, reference);
  EXPECT_TRUE(row.stable) << row.message;
  EXPECT_GE(row.iterations_per_frame, 1.0);  // a sheet sagging from rest iterates every frame
  EXPECT_GE(row.factorizations_per_frame, row.iterations_per_frame);  // no chord in the plain loop
  EXPECT_GT(row.cpu_ms_per_frame, 0.0);
  // One sub-step against eight: backward Euler's time discretisation error, a fraction of the
  // sag over the three frames (centimetres).
  EXPECT_GT(row.rms_error_mm, 0.0);
  EXPECT_LT(row.rms_error_mm, 10.0);
}
