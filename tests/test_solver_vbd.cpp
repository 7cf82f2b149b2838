// EXPERIMENT (issue 28, docs/notebook/resolution.md "Eighth round"): Vertex Block Descent (Chen et
// al. 2024) against XPBD's Gauss-Seidel on the swung sheet at 21, 42 and 84 nodes a side.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "hard_cases/hard_cases.hpp"
#include "report/cpu_time.hpp"
#include "solvers/solver.hpp"
#include "solvers/vbd.hpp"

namespace clothdb {
namespace {

// Each vertex's block solve uses only positions its colour does not write: 1 and 2 threads give
// the same bits, with Chebyshev acceleration and the adaptive initialisation.
TEST(Vbd, OneAndTwoThreadsGiveBitIdenticalResults) {
  const ClothScene scene = make_hard_case("swung-sheet");
  VbdSettings s1;
  s1.iterations = 6;
  s1.chebyshev_rho = 0.9;
  VbdSettings s2 = s1;
  s2.threads = 2;
  auto one = make_vbd_solver(scene.model, s1);
  auto two = make_vbd_solver(scene.model, s2);
  const RunResult a = run_scene(scene, *one, 10);
  const RunResult b = run_scene(scene, *two, 10);
  ASSERT_TRUE(a.stable && b.stable) << a.message << b.message;
  for (std::size_t f = 0; f < a.frames.size(); ++f)
    ASSERT_TRUE((a.frames[f].array() == b.frames[f].array()).all()) << "frame " << f;
  EXPECT_GT((a.frames.back() - a.frames.front()).norm(), 1e-2);
}

// Enough sweeps reach the implicit-Euler step that Newton solves tightly: the residual falls by
// orders of magnitude and the positions meet Newton's (so the per-vertex force and Hessian are
// those of the objective's gradient, which the residual computes separately). Even at 9 nodes a
// side the sweeps are slow (measured: residual 5.4, 0.089, 0.011, 2.6e-4, 2.7e-7 N after 10,
// 100, 1,000, 3,000, 10,000 sweeps, from 142 N at y).
TEST(Vbd, ConvergesToTheImplicitEulerStep) {
  ClothScene scene = make_hard_case("swung-sheet", 9);
  scene.model.material.damping = 0.0;
  const double h = scene.frame_dt / 4;
  ClothState state = scene.initial;
  Environment env = scene.env;
  StepInputs in;
  in.env = &env;
  // A few steps in, so the sheet moves and is stretched.
  VbdSettings warm;
  warm.substeps = 1;
  warm.iterations = 20;
  auto warm_solver = make_vbd_solver(scene.model, warm);
  for (int s = 1; s <= 8; ++s) {
    in.kinematic_targets = scene.kinematic_path(s * h);
    ASSERT_TRUE(warm_solver->step(state, h, in).stable);
  }
  in.kinematic_targets = scene.kinematic_path(9 * h);
  VbdSettings tight = warm;
  tight.iterations = 10000;
  const ClothState start = state;
  ASSERT_TRUE(make_vbd_solver(scene.model, tight)->step(state, h, in).stable);
  const Eigen::Matrix3Xd y = implicit_euler_target(scene.model, env, start, h, state.x);
  double newton_residual = 0;
  const Eigen::Matrix3Xd x_star =
      implicit_euler_solve(scene.model, y, h, y, 1e-11, &newton_residual);
  const double r0 = implicit_euler_residual(scene.model, y, h, y);
  EXPECT_LT(newton_residual, 1e-10 * r0);
  const double r = implicit_euler_residual(scene.model, y, h, state.x);
  const double dist = (state.x - x_star).colwise().norm().maxCoeff();
  std::printf("residual %.3e of %.3e, newton %.3e, distance %.3e m, y %.3e m\n", r, r0,
              newton_residual, dist, (y - x_star).colwise().norm().maxCoeff());
  EXPECT_LT(r, 1e-8 * r0);
  EXPECT_LT(dist, 1e-7);
  EXPECT_GT((y - x_star).colwise().norm().maxCoeff(), 1e-4);
}

// One method's run of the probe: the swung sheet (limit 2 %, no bending damping, so that VBD and
// XPBD solve the same implicit-Euler step, whose gradient is the residual), 4 sub-steps a frame,
// each sub-step one solver call.
struct ProbeRow {
  double strain = 0;          // largest edge strain of the run
  double residual_geo = 0;    // geometric mean over sub-steps of |grad G(x)| / |grad G(y)|
  double residual_worst = 0;  // the largest such ratio
  double dist_rms_mm = 0, dist_max_mm = 0;  // to Newton's x* at every dist_every-th frame's end
  double cpu_ms_frame = 0;
  double passes = 0;  // strain-limit passes per sub-step
  long capped = 0;
};

ProbeRow probe(const ClothScene& scene, Solver& solver, int frames, int dist_every) {
  const int substeps = 4;
  const double h = scene.frame_dt / substeps;
  ClothState state = scene.initial;
  Environment env = scene.env;
  StepInputs in;
  in.env = &env;
  ProbeRow row;
  double log_sum = 0, cpu = 0, dist_sq = 0;
  long passes = 0, dist_count = 0;
  for (int f = 1; f <= frames; ++f) {
    for (int s = 1; s <= substeps; ++s) {
      in.kinematic_targets = scene.kinematic_path(((f - 1) * substeps + s) * h);
      const ClothState start = state;
      const double c0 = process_cpu_seconds();
      const StepReport rep = solver.step(state, h, in);
      cpu += process_cpu_seconds() - c0;
      EXPECT_TRUE(rep.stable) << rep.message;
      if (!rep.stable) return row;
      passes += rep.strain_limit_passes;
      row.capped += rep.strain_limit_capped;
      const Eigen::Matrix3Xd y = implicit_euler_target(scene.model, env, start, h, state.x);
      const double ratio = implicit_euler_residual(scene.model, y, h, state.x) /
                           implicit_euler_residual(scene.model, y, h, y);
      log_sum += std::log(ratio);
      row.residual_worst = std::max(row.residual_worst, ratio);
      row.strain = std::max(row.strain, max_edge_strain(scene.model, state.x));
      if (s == substeps && f % dist_every == 0) {
        double rr = 0;
        const Eigen::Matrix3Xd x_star = implicit_euler_solve(scene.model, y, h, y, 1e-10, &rr);
        const Eigen::VectorXd d = (state.x - x_star).colwise().norm();
        row.dist_max_mm = std::max(row.dist_max_mm, 1e3 * d.maxCoeff());
        dist_sq += d.squaredNorm();
        dist_count += d.size();
      }
    }
  }
  row.residual_geo = std::exp(log_sum / (frames * substeps));
  row.dist_rms_mm = 1e3 * std::sqrt(dist_sq / static_cast<double>(dist_count));
  row.cpu_ms_frame = 1e3 * cpu / frames;
  row.passes = static_cast<double>(passes) / (frames * substeps);
  return row;
}

// The same steps for every method: a converged implicit-Euler trajectory (Newton to 1e-10 of the
// residual at y), and from each of its sub-step starts one call of the method. Per call: the
// residual ratio |grad G(x)| / |grad G(y)|, the distance ratio |x - x*| / |y - x*| (all vertices'
// distances, 2-norm), the largest edge strain of x. Geometric means over the sub-steps.
struct Reference {
  std::vector<ClothState> start;
  std::vector<Eigen::Matrix3Xd> targets, x_star;
  double strain = 0;  // largest edge strain of the converged steps
};

Reference converged_trajectory(const ClothScene& scene, int frames) {
  const int substeps = 4;
  const double h = scene.frame_dt / substeps;
  Reference ref;
  ClothState state = scene.initial;
  const Environment env = scene.env;
  for (int j = 1; j <= frames * substeps; ++j) {
    ref.start.push_back(state);
    Eigen::Matrix3Xd pins = scene.kinematic_path(j * h);
    ref.targets.push_back(pins);
    Eigen::Matrix3Xd x_end = state.x;
    for (std::size_t k = 0; k < scene.model.kinematic.size(); ++k)
      x_end.col(scene.model.kinematic[k]) = pins.col(static_cast<Eigen::Index>(k));
    const Eigen::Matrix3Xd y = implicit_euler_target(scene.model, env, state, h, x_end);
    double rr = 0;
    const Eigen::Matrix3Xd x = implicit_euler_solve(scene.model, y, h, y, 1e-10, &rr);
    ref.x_star.push_back(x);
    ref.strain = std::max(ref.strain, max_edge_strain(scene.model, x));
    for (Eigen::Index i = 0; i < x.cols(); ++i)
      state.v.col(i) = (x.col(i) - state.x.col(i)) / h;  // pins too: their motion over the step
    state.x = x;
  }
  return ref;
}

struct StepRow {
  double residual = 0, distance = 0, strain = 0, cpu_ms_step = 0;
};

StepRow same_steps(const ClothScene& scene, const Reference& ref, Solver& solver) {
  const double h = scene.frame_dt / 4;
  Environment env = scene.env;
  StepInputs in;
  in.env = &env;
  StepRow row;
  double log_r = 0, log_d = 0, cpu = 0;
  const std::size_t count = ref.start.size();
  for (std::size_t j = 0; j < count; ++j) {
    ClothState state = ref.start[j];
    in.kinematic_targets = ref.targets[j];
    const double c0 = process_cpu_seconds();
    const StepReport rep = solver.step(state, h, in);
    cpu += process_cpu_seconds() - c0;
    EXPECT_TRUE(rep.stable) << rep.message;
    const Eigen::Matrix3Xd y = implicit_euler_target(scene.model, env, ref.start[j], h, state.x);
    log_r += std::log(implicit_euler_residual(scene.model, y, h, state.x) /
                      implicit_euler_residual(scene.model, y, h, y));
    log_d += std::log((state.x - ref.x_star[j]).norm() / (y - ref.x_star[j]).norm());
    row.strain = std::max(row.strain, max_edge_strain(scene.model, state.x));
  }
  row.residual = std::exp(log_r / static_cast<double>(count));
  row.distance = std::exp(log_d / static_cast<double>(count));
  row.cpu_ms_step = 1e3 * cpu / static_cast<double>(count);
  return row;
}

std::vector<int> env_list(const char* name, std::vector<int> fallback) {
  const char* v = std::getenv(name);
  if (!v) return fallback;
  std::vector<int> out;
  for (const char* p = v; *p;) {
    char* end = nullptr;
    out.push_back(static_cast<int>(std::strtol(p, &end, 10)));
    p = *end ? end + 1 : end;
  }
  return out;
}

// PROBE (disabled): CLOTHDB_PROBE_VBD_RES (e.g. "21,42"), CLOTHDB_PROBE_VBD_K (iterations),
// CLOTHDB_PROBE_VBD_WHAT (letters: x XPBD sweeps, c XPBD sweeps with Chebyshev 0.8, l XPBD 1 sweep
// + strain limit with cap K, v VBD, w VBD with Chebyshev rho CLOTHDB_PROBE_VBD_RHO (percent),
// i VBD with y as the initial guess, p VBD from x_t).
TEST(Vbd, DISABLED_ProbeSwungSheet) {
  const std::vector<int> resolutions = env_list("CLOTHDB_PROBE_VBD_RES", {21, 42, 84});
  const std::vector<int> ks = env_list("CLOTHDB_PROBE_VBD_K", {4, 8, 16, 32, 64});
  const char* what_env = std::getenv("CLOTHDB_PROBE_VBD_WHAT");
  const std::string what = what_env ? what_env : "xlv";
  const double rho = 0.01 * env_list("CLOTHDB_PROBE_VBD_RHO", {90})[0];
  const int frames = env_list("CLOTHDB_PROBE_VBD_FRAMES", {20})[0];
  // CLOTHDB_PROBE_VBD_SAME=1: every method from the converged trajectory's sub-step starts.
  const bool same = std::getenv("CLOTHDB_PROBE_VBD_SAME") != nullptr;
  // The distance to Newton's step every this many frames (last sub-step) of a run.
  const int dist_every = env_list("CLOTHDB_PROBE_VBD_DIST_EVERY", {5})[0];
  for (int res : resolutions) {
    ClothScene scene = make_hard_case("swung-sheet", res);
    scene.model.material.damping = 0.0;
    // CLOTHDB_PROBE_VBD_SOFTEN=F: Young's modulus divided by F (a softer cloth, whose converged
    // step stretches F times as much).
    scene.model.material.youngs_modulus /= env_list("CLOTHDB_PROBE_VBD_SOFTEN", {1})[0];
    Reference ref;
    if (same) {
      ref = converged_trajectory(scene, frames);
      std::printf("res %d: converged trajectory, largest strain %.4f %%\n", res, 100 * ref.strain);
      std::fflush(stdout);
    }
    for (char m : what) {
      for (int k : ks) {
        std::unique_ptr<Solver> solver;
        if (m == 'x' || m == 'c' || m == 'l') {
          SolverSettings s;
          s.substeps = 1;
          s.iterations = m == 'l' ? 1 : k;
          s.threads = 1;
          s.tethers = false;
          if (m == 'c') s.chebyshev_rho = 0.8;
          if (m == 'l') {
            s.strain_limit = 0.02;
            s.strain_limit_iterations = k;
            s.strain_limit_relaxation = 1.8;
          }
          solver = make_xpbd_solver(scene.model, s);
        } else {
          VbdSettings s;
          s.substeps = 1;
          s.iterations = k;
          if (m == 'w') s.chebyshev_rho = rho;
          if (m == 'i') s.init = VbdSettings::Init::Inertia;
          if (m == 'p') s.init = VbdSettings::Init::Previous;
          solver = make_vbd_solver(scene.model, s);
        }
        if (same) {
          const StepRow r = same_steps(scene, ref, *solver);
          std::printf(
              "res %d method %c k %d: same steps: residual %.3e distance %.3e strain %.3f "
              "%% cpu %.3f ms/step\n",
              res, m, k, r.residual, r.distance, 100 * r.strain, r.cpu_ms_step);
          std::fflush(stdout);
          continue;
        }
        const ProbeRow r = probe(scene, *solver, frames, dist_every);
        std::printf(
            "res %d method %c k %d: strain %.3f %% residual geo %.3e worst %.3e dist rms %.3f max "
            "%.3f mm cpu %.2f ms/frame passes %.1f capped %ld\n",
            res, m, k, 100 * r.strain, r.residual_geo, r.residual_worst, r.dist_rms_mm,
            r.dist_max_mm, r.cpu_ms_frame, r.passes, r.capped);
        std::fflush(stdout);
      }
    }
  }
}

}  // namespace
}  // namespace clothdb
