// The solver benchmark's own logic: mass-spring sub-steps derived from the stability limit, the
// cap on them, and one measured row against its reference; and the accuracy benchmark of
// docs/GUIDE.md#the-solvers (chaos floor, short-horizon windows, self-convergence, static cases,
// cost at a fixed error).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "bench/solver_accuracy.hpp"
#include "bench/solver_bench.hpp"
#include "bench/strain_study.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"
#include "support/cli.hpp"

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

// ---- the accuracy benchmark (bench/solver_accuracy.hpp, docs/GUIDE.md#the-solvers) ----

namespace {

// A small equilateral grid laid flat and pinned at the two corners of one edge: it falls and
// swings, deterministically (a smaller seed004-fall).
ClothScene small_falling_grid() {
  ClothScene scene = make_seed004_fall(7);
  scene.name = "small-fall";
  scene.frames = 8;
  return scene;
}

AccuracyRow row_at(const std::string& settings, double cost, double error) {
  AccuracyRow r;
  r.solver = "xpbd";
  r.settings = settings;
  r.cpu_s_per_sim_s = cost;
  r.short_rms_mm = error;
  return r;
}

}  // namespace

TEST(SolverAccuracy, ChaosFloorOfANonChaoticFallIsTinyButTheRunsDiffer) {
  const ClothScene scene = small_falling_grid();
  const SolverCandidate ref = accuracy_reference(4, 1e-7);
  const Trajectory a = simulate_from(scene, ref, scene.initial, 0, scene.frames);
  const Trajectory b =
      simulate_from(scene, ref, perturbed_state(scene, scene.initial, 1e-6, 1), 0, scene.frames);
  ASSERT_TRUE(a.stable && b.stable) << a.message << b.message;
  const std::vector<ErrorMm> floor = frame_errors(a, b);
  ASSERT_EQ(floor.size(), static_cast<size_t>(scene.frames + 1));
  // The start differs by 1 um at every free vertex (RMS over all, pins included, just under).
  EXPECT_GT(floor.front().rms, 0.5e-3);
  EXPECT_LE(floor.front().max, 1.0e-3 + 1e-12);
  for (const ErrorMm& e : floor) {
    EXPECT_GT(e.rms, 0.0);   // the perturbed run is a different run
    EXPECT_LT(e.rms, 0.01);  // and stays within 10 um: no amplification to speak of
  }
}

TEST(SolverAccuracy, TheReferenceTakesUniformStepsAndMatchesItselfOnRestart) {
  ClothScene scene = make_hard_case("swung-sheet", 6);
  const SolverCandidate ref = accuracy_reference(4, 1e-7);
  const Trajectory reference = simulate_from(scene, ref, scene.initial, 0, 6);
  ASSERT_TRUE(reference.stable) << reference.message;
  EXPECT_EQ(reference.step_halvings, 0);
  // Restarted from its own states, the reference reproduces its frames (fresh solver, same steps).
  const Windows again = run_windows(scene, ref, reference, 2, 2);
  EXPECT_EQ(again.step_halvings, 0);
  ASSERT_EQ(again.starts, (std::vector<int>{0, 2, 4}));
  const ErrorMm self = windows_error(again, reference_windows(reference, 2, 2));
  EXPECT_LT(self.max, 1e-9);
  // Twice the sub-steps is a different answer (the reference's own time error, first order in
  // the step: backward Euler), and it shrinks as the sub-steps grow.
  const Windows at4 = reference_windows(reference, 2, 2);
  const Windows at8 = run_windows(scene, accuracy_reference(8, 1e-7), reference, 2, 2);
  const Windows at16 = run_windows(scene, accuracy_reference(16, 1e-7), reference, 2, 2);
  EXPECT_EQ(at8.step_halvings + at16.step_halvings, 0);
  const double error_4 = windows_error(at4, at16).rms, error_8 = windows_error(at8, at16).rms;
  EXPECT_GT(error_8, 0.0);
  EXPECT_LT(error_8, 0.7 * error_4);
}

TEST(SolverAccuracy, XpbdSelfConvergenceErrorFallsAsStepsAreRefined) {
  const ClothScene scene = make_hard_case("hanging-sheet", 7);
  const Trajectory reference =
      simulate_from(scene, accuracy_reference(4, 1e-7), scene.initial, 0, 6);
  ASSERT_TRUE(reference.stable);
  const SolverCandidate base = candidate(SolverKind::Xpbd, 2, 1);
  const Windows w1 = run_windows(scene, base, reference, 3, 2);
  const Windows w4 = run_windows(scene, refined_candidate(base, 4), reference, 3, 2);
  const Windows w16 = run_windows(scene, refined_candidate(base, 16), reference, 3, 2);
  const double error_1x = windows_error(w1, w16).rms;
  const double error_4x = windows_error(w4, w16).rms;
  EXPECT_GT(error_1x, 0.0);
  EXPECT_LT(error_4x, error_1x);
  EXPECT_NE(refined_candidate(base, 4).label.find("x4"), std::string::npos);
  EXPECT_EQ(refined_candidate(base, 4).settings.substeps, 8);
}

TEST(SolverAccuracy, ConvergedNewtonMatchesTheStaticFormulas) {
  const SolverCandidate newton = candidate(SolverKind::Newton, 1, 0, 1e-6);
  // Equilateral strip: the edge-spring membrane has Young's modulus E t; F L / (E t w) within a
  // few per cent (the clamped top row and the lattice's Poisson ratio 1/3).
  const StaticRow strip = measure_static(membrane_strip_case(false), newton, 40);
  ASSERT_TRUE(strip.stable) << strip.message;
  EXPECT_NEAR(strip.measured_mm / strip.analytic_mm, 1.0, 0.04) << strip.measured_mm;
  // Quad grid with diagonals: the same springs are 1.2 E t stiff in uniaxial stress.
  const StaticRow quad = measure_static(membrane_strip_case(true), newton, 40);
  ASSERT_TRUE(quad.stable) << quad.message;
  EXPECT_NEAR(quad.measured_mm / quad.analytic_mm, 1.0 / 1.2, 0.03) << quad.measured_mm;
  const StaticRow catenary = measure_static(catenary_strip_case(), newton, 60);
  ASSERT_TRUE(catenary.stable) << catenary.message;
  EXPECT_NEAR(catenary.relative_error, 0.0, 0.02) << catenary.measured_mm;
}

TEST(SolverAccuracy, CatenaryParameterSolvesTheLengthEquation) {
  for (double span : {0.3, 0.8, 0.99}) {
    const double a = catenary_parameter(1.0, span);
    EXPECT_NEAR(2 * a * std::sinh(span / (2 * a)), 1.0, 1e-9) << span;
  }
  EXPECT_THROW(catenary_parameter(1.0, 1.2), std::invalid_argument);
}

TEST(SolverAccuracy, CostAtErrorInterpolatesAlongTheFront) {
  const std::vector<AccuracyRow> rows{row_at("cheap", 1.0, 10.0), row_at("mid", 10.0, 0.1),
                                      row_at("dear", 100.0, 0.01), row_at("dominated", 50.0, 5.0)};
  // 1 mm lies halfway (in log error) between 10 mm and 0.1 mm: halfway in log cost, 10^0.5.
  const CostAtError at1 = cost_at_error(rows, "xpbd", 1.0);
  EXPECT_NEAR(at1.cpu_s_per_sim_s, std::sqrt(10.0), 1e-9);
  EXPECT_NE(at1.how.find("cheap"), std::string::npos);
  // Under the cheapest setting's error: at most its cost.
  EXPECT_DOUBLE_EQ(cost_at_error(rows, "xpbd", 20.0).cpu_s_per_sim_s, 1.0);
  // Below every setting: not reached.
  const CostAtError none = cost_at_error(rows, "xpbd", 0.001);
  EXPECT_TRUE(std::isnan(none.cpu_s_per_sim_s));
  EXPECT_NE(none.how.find("not reached"), std::string::npos);
  EXPECT_TRUE(std::isnan(cost_at_error(rows, "newton", 1.0).cpu_s_per_sim_s));
}

TEST(SolverAccuracy, EnsembleSpreadBoundsItsMembers) {
  const ClothScene scene = small_falling_grid();
  const SolverCandidate ref = accuracy_reference(2, 1e-7);
  std::vector<EnsembleStats> members;
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    const Trajectory t = simulate_from(
        scene, ref, perturbed_state(scene, scene.initial, 1e-6, seed), 0, scene.frames);
    ASSERT_TRUE(t.stable);
    members.push_back(ensemble_stats(scene, t));
  }
  const EnsembleSpread spread = ensemble_spread(members);
  EXPECT_EQ(spread.members, 3);
  EXPECT_GT(spread.mean.sag_mm, 10.0);  // a grid falling from flat sags by decimetres
  EXPECT_GE(spread.mean.strain_p99, 0.0);
  EXPECT_LE(spread.min.sag_mm, spread.max.sag_mm);
  for (const EnsembleStats& m : members) EXPECT_EQ(stats_within_spread(m, spread), 4);
  EnsembleStats far = spread.mean;
  far.sag_mm = spread.max.sag_mm + 1e3;
  EXPECT_EQ(stats_within_spread(far, spread), 3);
}

TEST(SolverAccuracy, CommandWritesItsTablesAndPlots) {
  const std::string out = std::string(CLOTHDB_BINARY_DIR) + "/test_bench_solvers_out";
  std::filesystem::remove_all(out);
  const test::CliResult run = test::run_clothdb(
      "bench solvers --quick --solvers xpbd --scenes hanging-sheet --resolution 5 --frames 4 "
      "--restart-every 2 --static-frames 3 --out " +
          out,
      out + ".log");
  ASSERT_EQ(run.code, 0) << run.output;
  for (const char* f :
       {"accuracy.json", "rows.csv", "statics.csv", "accuracy.md", "hanging-sheet.svg"})
    EXPECT_TRUE(std::filesystem::exists(out + "/" + f)) << f;
  std::ifstream in(out + "/accuracy.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  ASSERT_EQ(j["scenes"].size(), 1u);
  const auto& scene = j["scenes"][0];
  EXPECT_EQ(scene["chaos_floor_rms_mm"].size(), 5u) << scene["chaos_floor_message"];  // frames 0..4
  EXPECT_EQ(scene["reference_step_halvings"], 0);
  EXPECT_EQ(scene["rows"].size(), 2u);  // the two quick XPBD settings
  for (const auto& row : scene["rows"]) {
    EXPECT_TRUE(row["short_horizon_rms_mm"].is_number());
    EXPECT_TRUE(row["self_convergence_rms_mm"].is_number());
  }
  EXPECT_EQ(scene["cost_at_target"].size(), 2u);  // xpbd at 1 and 10 mm
  // Every static case, each XPBD setting with and without tethers.
  EXPECT_EQ(j["statics"].size(), static_case_names().size() * 4);
  std::filesystem::remove_all(out);
}

// The strain study (`bench solvers --strain-study`, docs/guide/resolution.md) on a small sheet:
// one row per --setting, p99 at most the largest strain, a distance to the 8x-sub-step run of the
// same setting, and per target exactly the cheapest setting within it marked (or none).
TEST(StrainStudy, MarksTheCheapestSettingWithinEachTarget) {
  const ClothScene scene = make_large_sheet(200);
  StrainStudyOptions options;
  options.frames = 3;
  options.targets = {0.01, 1.0};
  SolverSettings plain;
  plain.substeps = 4;
  plain.iterations = 1;
  SolverSettings limited = plain;
  limited.stretch_iterations = 4;
  limited.strain_limit = 0.01;
  limited.strain_limit_iterations = 1000;
  limited.strain_limit_relaxation = 1.8;
  limited.chebyshev_rho = 0.8;
  options.settings = {{SolverKind::Xpbd, plain, "plain"}, {SolverKind::Xpbd, limited, "limited"}};
  const StrainStudy study = run_strain_study(scene, options, nullptr);
  ASSERT_EQ(study.rows.size(), 2u);
  for (const StrainStudyRow& r : study.rows) {
    ASSERT_TRUE(r.stable) << r.message;
    EXPECT_EQ(r.frames, 3);
    EXPECT_LE(r.p99_strain, r.max_strain);
    EXPECT_LE(r.last_strain, r.max_strain);
    EXPECT_TRUE(std::isfinite(r.reference_rms_mm) && r.reference_rms_mm >= 0) << r.settings;
    EXPECT_LE(r.reference_rms_mm, r.reference_max_mm);
    EXPECT_GT(r.reference_cpu_ms_per_frame, r.cpu_ms_per_frame) << r.settings;
  }
  // The strain limit (converged: no pass cap reached) holds 1 %; both settings are within 100 %.
  EXPECT_TRUE(meets_strain_target(study.rows[1].max_strain, 0.01)) << study.rows[1].max_strain;
  for (double target : options.targets) {
    int marked = 0;
    const StrainStudyRow* cheapest = nullptr;
    for (const StrainStudyRow& r : study.rows) {
      if (std::count(r.cheapest_for.begin(), r.cheapest_for.end(), target) > 0) ++marked;
      if (meets_strain_target(r.max_strain, target) &&
          (!cheapest || r.cpu_ms_per_frame < cheapest->cpu_ms_per_frame))
        cheapest = &r;
    }
    ASSERT_NE(cheapest, nullptr) << target;
    EXPECT_EQ(marked, 1) << target;
    EXPECT_EQ(std::count(cheapest->cheapest_for.begin(), cheapest->cheapest_for.end(), target), 1);
  }
  EXPECT_NE(strain_study_markdown(study).find("| **1.00 %** |"), std::string::npos);
}

// The command: --setting blocks parsed as in a scene file (a bad field named), the tables written.
TEST(StrainStudy, CommandTakesSolverBlocksAndWritesItsTables) {
  const std::string out = std::string(CLOTHDB_BINARY_DIR) + "/test_bench_strain_out";
  std::filesystem::remove_all(out);
  const test::CliResult run = test::run_clothdb(
      {"bench", "solvers", "--strain-study", "--scenes", "large-sheet", "--vertices", "100",
       "--frames", "2", "--no-references", "--strain-targets", "5", "--setting",
       R"({"name": "xpbd", "substeps": 2, "iterations": 1, "tethers": false})", "--out", out},
      out + ".log");
  ASSERT_EQ(run.code, 0) << run.output;
  std::ifstream in(out + "/strain.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  ASSERT_EQ(j.size(), 1u);
  ASSERT_EQ(j[0]["rows"].size(), 1u);
  EXPECT_NE(j[0]["rows"][0]["settings"].get<std::string>().find("tethers=off"), std::string::npos);
  EXPECT_TRUE(j[0]["rows"][0]["reference_rms_mm"].is_null());
  EXPECT_TRUE(std::filesystem::exists(out + "/strain.md"));
  const test::CliResult bad =
      test::run_clothdb({"bench", "solvers", "--strain-study", "--setting",
                         R"({"name": "xpbd", "chebyshev_rho": 2})", "--out", out},
                        out + ".log");
  EXPECT_NE(bad.code, 0);
  EXPECT_NE(bad.output.find("--setting"), std::string::npos) << bad.output;
  EXPECT_NE(bad.output.find("chebyshev_rho"), std::string::npos) << bad.output;
  std::filesystem::remove_all(out);
}
