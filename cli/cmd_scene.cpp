// `clothdb scene list|run`: the shared hard-case scenes, one at a time.
#include <algorithm>
#include <cstdio>
#include <memory>
#include <sstream>

#include "bench/solver_bench.hpp"
#include "cli_util.hpp"
#include "commands.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

void register_scene_commands(CLI::App& app) {
  CLI::App* scene =
      app.add_subcommand("scene", "The shared hard cloth scenes (tests and benchmarks use them)");
  scene->require_subcommand(1);

  CLI::App* list = scene->add_subcommand("list", "Lists the scenes with their vertex counts");
  list->callback([] {
    SolverBenchOptions defaults;
    std::vector<std::string> names = hard_case_names();
    names.push_back("seed004-529");
    names.push_back("large-sheet");
    for (const auto& n : names) {
      const ClothScene s = make_bench_scene(n, defaults);
      std::printf("%-20s %6d vertices  %s\n", n.c_str(), s.model.vertex_count(),
                  s.description.c_str());
    }
  });

  struct RunArgs {
    std::string name, out;
    int frames = 0, resolution = 0;
    SolverOptions solver;
  };
  auto args = std::make_shared<RunArgs>();
  CLI::App* run = scene->add_subcommand(
      "run", "Simulates one scene and prints per-frame metrics (strain, penetration, energy)");
  run->add_option("NAME", args->name, "Scene name (see `clothdb scene list`)")->required();
  run->add_option("--frames", args->frames, "Frames at 30 fps (0: scene default)")
      ->capture_default_str();
  run->add_option("--resolution", args->resolution, "Nodes per side (0: scene default)")
      ->capture_default_str();
  run->add_option("--out", args->out, "Also write the per-frame metrics to this CSV file");
  args->solver.add_to(*run);
  run->callback([args] {
    SolverBenchOptions opts;
    opts.resolution = args->resolution;
    const ClothScene scene = make_bench_scene(args->name, opts);
    auto solver = make_solver(args->solver.kind(), scene.model, args->solver.resolved());
    const RunResult r = run_scene(scene, *solver, args->frames, false);
    std::ostringstream csv;
    csv << "frame,max_strain,max_penetration_mm,mean_penetration_mm,kinetic_energy_J,total_energy_"
           "J,step_halvings\n";
    for (size_t f = 0; f < r.metrics.size(); ++f) {
      const auto& m = r.metrics[f];
      csv << f << ',' << m.max_strain << ',' << 1e3 * m.max_penetration << ','
          << 1e3 * m.mean_penetration << ',' << m.kinetic_energy << ',' << m.total_energy << ','
          << m.step_halvings << '\n';
    }
    if (!args->out.empty()) write_file_atomic(args->out, csv.str());
    const auto& last = r.metrics.back();
    double worst = 0.0;
    for (const auto& m : r.metrics) worst = std::max(worst, m.max_strain);
    std::printf(
        "%s with %s: %zu frames, %.2f ms/frame (CPU %.2f), final max strain %.3f%% (largest over "
        "the "
        "run %.3f%%), max penetration %.3f mm, kinetic energy %.3g J\n",
        scene.name.c_str(), solver->describe().c_str(), r.metrics.size() - 1,
        r.metrics.size() > 1 ? 1e3 * r.seconds / (r.metrics.size() - 1) : 0.0,
        r.metrics.size() > 1 ? 1e3 * r.cpu_seconds / (r.metrics.size() - 1) : 0.0,
        100 * last.max_strain, 100 * worst, 1e3 * last.max_penetration, last.kinetic_energy);
    if (!r.stable) throw std::runtime_error(scene.name + ": unstable: " + r.message);
  });
}

}  // namespace clothdb::cli
