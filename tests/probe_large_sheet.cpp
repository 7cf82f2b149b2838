// The 10,000-vertex sheet hanging from two corners (make_large_sheet, tethers on), 30 frames, one
// thread: CPU per frame and the largest edge strain of the run for the plain 200-sub-step setting
// and for the strain limit at 1 % with over-relaxed passes and Chebyshev-accelerated stretch sweeps
// (docs/guide/resolution.md). docs/notebook/resolution.md has the figures. An executable to run by
// hand (build/tests/probe_large_sheet), not a CTest test: it takes about a minute of CPU.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>

#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

namespace clothdb {
namespace {

struct Setting {
  int substeps, stretch_iterations;
  double strain_limit, relaxation, chebyshev_rho;
  int strain_limit_iterations;
};

TEST(Probe, LargeSheetWithinOnePercent) {
  const ClothScene scene = make_large_sheet(10000);
  const int frames = 30;
  for (const Setting& c :
       {Setting{200, 1, 0.0, 1.0, 0.0, 1}, Setting{40, 1, 0.01, 1.8, 0.0, 64},
        Setting{40, 4, 0.01, 1.8, 0.8, 64}, Setting{20, 4, 0.01, 1.8, 0.8, 64}}) {
    SolverSettings s;
    s.substeps = c.substeps;
    s.iterations = 1;
    s.threads = 1;
    s.tethers = true;
    s.stretch_iterations = c.stretch_iterations;
    s.strain_limit = c.strain_limit;
    s.strain_limit_relaxation = c.relaxation;
    s.chebyshev_rho = c.chebyshev_rho;
    s.strain_limit_iterations = c.strain_limit_iterations;
    auto solver = make_solver(SolverKind::Xpbd, scene.model, s);
    const RunResult run = run_scene(scene, *solver, frames, false);
    ASSERT_TRUE(run.stable) << run.message;
    double strain = 0.0;
    for (const FrameMetrics& m : run.metrics) strain = std::max(strain, m.max_strain);
    std::printf("%s: CPU %.1f ms/frame, max strain %.3f %%, last frame %.3f %%\n",
                solver->describe().c_str(), 1e3 * run.cpu_seconds / frames, 100 * strain,
                100 * run.metrics.back().max_strain);
    std::fflush(stdout);
  }
}

}  // namespace
}  // namespace clothdb
