// clothdb_bench_bender: our XPBD against Bender's PositionBasedDynamics XPBD kernels on the same
// hanging sheet at equal sub-steps (docs/notebook/BENCHMARKS.md, "Against Bender's
// PositionBasedDynamics at equal sub-steps"), one thread, CPU time. Prints a Markdown table.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <string>
#include <vector>

#include "bender_sheet.hpp"
#include "database/store/run_settings.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/solver.hpp"

using namespace clothdb;

namespace {

void print_row(const char* solver, int substeps, double cpu_seconds, int frames, double max_strain,
               double last_strain, bool finite, double ours_cpu) {
  const double ms = 1e3 * cpu_seconds / std::max(frames, 1);
  std::printf("| %s | %d | %.1f | %.2fx | %.2f %% | %.2f %% |%s\n", solver, substeps, ms,
              ours_cpu > 0 ? cpu_seconds / ours_cpu : 0.0, 100 * max_strain, 100 * last_strain,
              finite ? "" : " (blew up)");
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Our XPBD against Jan Bender's PositionBasedDynamics (its XPBD distance and isometric "
      "bending kernels and its integrator, in a loop like its TimeStepController) on the same "
      "hanging sheet, mesh, masses and pins, at equal sub-steps of one sweep, on one thread. "
      "CPU time of the sub-step loops; strain = max (l - l0) / l0 over edges."};
  int vertices = 10000, frames = 30;
  std::vector<int> substep_list{100, 200};
  app.add_option("--vertices", vertices, "Approximate vertex count of the hanging sheet")
      ->capture_default_str()
      ->check(CLI::Range(16, 1000000));
  app.add_option("--frames", frames, "Frames at 30 fps")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--substeps", substep_list, "Comma-separated sub-step counts")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(1, 1000000));
  std::vector<std::string> setting_texts;
  app.add_option("--setting", setting_texts,
                 "Also our XPBD with this solver block (as in a scene file, e.g. '{\"name\": "
                 "\"xpbd\", \"stretch_iterations\": 4, \"strain_limit\": 0.01, "
                 "\"strain_limit_iterations\": 64, \"strain_limit_relaxation\": 1.8, "
                 "\"chebyshev_rho\": 0.8}'; iterations default 1) at each --substeps count; "
                 "repeat for several. Bender's CPU is then also given as a ratio to each")
      ->take_all();
  CLI11_PARSE(app, argc, argv);
  std::vector<SolverSettings> settings_list;
  for (const std::string& text : setting_texts) {
    SolverKind kind = SolverKind::Xpbd;
    SolverSettings s;
    s.iterations = 1;
    try {
      parse_solver_settings_json(text, "--setting", &kind, &s);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "clothdb_bench_bender: %s\n", e.what());
      return 2;
    }
    if (kind != SolverKind::Xpbd) {
      std::fprintf(stderr, "clothdb_bench_bender: --setting: name must be xpbd\n");
      return 2;
    }
    s.threads = 1;
    settings_list.push_back(s);
  }
  const ClothScene scene = make_large_sheet(vertices);
  std::printf("scene: %s, %d frames at 30 fps, one thread\n\n", scene.description.c_str(), frames);
  std::printf(
      "| solver | sub-steps | CPU ms/frame | CPU vs ours (tethers off) | max strain over the run | "
      "at the last frame |\n|---|---:|---:|---:|---:|---:|\n");
  std::string ratios;  // printed after the table
  for (int substeps : substep_list) {
    double ours_cpu = 0;
    for (bool tethers : {false, true}) {
      SolverSettings settings;
      settings.substeps = substeps;
      settings.iterations = 1;
      settings.threads = 1;
      settings.tethers = tethers;
      auto solver = make_solver(SolverKind::Xpbd, scene.model, settings);
      const RunResult run = run_scene(scene, *solver, frames, false);
      double max_strain = 0;
      for (std::size_t f = 1; f < run.metrics.size(); ++f)
        max_strain = std::max(max_strain, run.metrics[f].max_strain);
      if (!tethers) ours_cpu = run.cpu_seconds;
      print_row(tethers ? "clothdb XPBD, tethers on" : "clothdb XPBD, tethers off", substeps,
                run.cpu_seconds, frames, max_strain, run.metrics.back().max_strain, run.stable,
                ours_cpu);
    }
    std::vector<std::pair<std::string, double>> ours;  // each --setting's label and CPU seconds
    for (SolverSettings settings : settings_list) {
      settings.substeps = substeps;
      auto solver = make_solver(SolverKind::Xpbd, scene.model, settings);
      const RunResult run = run_scene(scene, *solver, frames, false);
      double max_strain = 0;
      for (std::size_t f = 1; f < run.metrics.size(); ++f)
        max_strain = std::max(max_strain, run.metrics[f].max_strain);
      const std::string label = "clothdb " + solver->describe();
      print_row(label.c_str(), substeps, run.cpu_seconds, frames, max_strain,
                run.metrics.back().max_strain, run.stable, ours_cpu);
      ours.push_back({label, run.cpu_seconds});
    }
    const BenderSheetRun single = bender_sheet_float(scene, frames, substeps);
    print_row("Bender PBD, float (as shipped)", substeps, single.cpu_seconds, single.frames,
              single.max_strain, single.last_strain, single.finite, ours_cpu);
    const BenderSheetRun twice = bender_sheet_double(scene, frames, substeps);
    print_row("Bender PBD, double (USE_DOUBLE)", substeps, twice.cpu_seconds, twice.frames,
              twice.max_strain, twice.last_strain, twice.finite, ours_cpu);
    for (const auto& [label, cpu] : ours) {
      if (!(cpu > 0)) continue;
      char line[512];
      std::snprintf(line, sizeof line,
                    "- %d sub-steps: Bender's CPU / %s: %.2fx (float), %.2fx (double)\n", substeps,
                    label.c_str(), single.cpu_seconds / cpu, twice.cpu_seconds / cpu);
      ratios += line;
    }
  }
  if (!ratios.empty()) std::printf("\n%s", ratios.c_str());
  return 0;
}
