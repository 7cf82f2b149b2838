// `clothdb bench solvers`: speed against error for the four solvers (core issue).
#include <chrono>
#include <cstdio>
#include <memory>

#include "bench/solver_bench.hpp"
#include "cli_util.hpp"
#include "commands.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

void register_bench_solvers(CLI::App& bench) {
  struct Args {
    std::string scenes, solvers, threads = "1", out = "out/bench-solvers";
    SolverBenchOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "solvers",
      "Runs every solver over a range of settings on the hard-case scenes and a large sheet, "
      "measures each against a reference (Newton, 8 sub-steps, tolerance 1e-9), and writes "
      "solvers.csv, solvers.json, solvers.md and one SVG plot per scene (error against time, "
      "Pareto front dashed).");
  cmd->add_option("--scenes", args->scenes,
                  "Comma-separated scenes (default: all hard cases, seed004-529, large-sheet)");
  cmd->add_option("--solvers", args->solvers, "Comma-separated solvers (default: all four)");
  cmd->add_option("--frames", args->options.frames, "Frames per run at 30 fps")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--resolution", args->options.resolution,
                  "Nodes per side of the hard-case sheets (0: scene default)")
      ->capture_default_str();
  cmd->add_option("--large-vertices", args->options.large_vertices,
                  "Vertices of the large-sheet scene")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Comma-separated thread counts, e.g. 1,2")
      ->capture_default_str();
  cmd->add_flag("--quick", args->options.quick,
                "Two settings per solver instead of the full sweep");
  cmd->add_option("--out", args->out, "Output directory")->capture_default_str();
  cmd->callback([args] {
    SolverBenchOptions options = args->options;
    options.scenes = split_list(args->scenes);
    options.solvers = split_list(args->solvers);
    options.threads.clear();
    for (const auto& t : split_list(args->threads)) options.threads.push_back(std::stoi(t));
    for (const auto& s : options.solvers) parse_solver_kind(s);  // fail before any work
    make_directories(args->out);
    const auto start = std::chrono::steady_clock::now();
    // The tables are rewritten after every run, so a sweep stopped part-way (the full one takes
    // over half an hour) keeps every row it finished.
    auto write_tables = [&](const std::vector<BenchRow>& rows) {
      write_file_atomic(args->out + "/solvers.csv", bench_rows_csv(rows));
      write_file_atomic(args->out + "/solvers.json", bench_rows_json(rows));
      write_file_atomic(args->out + "/solvers.md", bench_rows_markdown(rows));
    };
    const auto rows = run_solver_bench(
        options,
        [&](const std::string& line) {
          const double s =
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
          std::fprintf(stderr, "[%6.1fs] %s\n", s, line.c_str());
        },
        write_tables);
    write_tables(rows);
    std::vector<std::string> scenes;
    for (const auto& r : rows)
      if (std::find(scenes.begin(), scenes.end(), r.scene) == scenes.end())
        scenes.push_back(r.scene);
    for (const auto& s : scenes)
      write_file_atomic(args->out + "/" + s + ".svg", render_svg(bench_plot(rows, s)));
    std::printf("%s", bench_rows_markdown(rows).c_str());
    std::printf("\nwrote %s/solvers.{csv,json,md} and %zu SVG plots\n", args->out.c_str(),
                scenes.size());
  });
}

void register_bench_newton(CLI::App& bench) {
  struct Args {
    std::string scenes = "seed004-fall,seed004-529", out = "out/bench-newton", only;
    int frames = 30, repeat = 1;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "newton",
      "The Newton solver's speed study on seed 004's 529-node grid: the original loop against "
      "the predicted start, chord iterations (factorisation reuse), looser tolerances, CHOLMOD "
      "and warm-started PCG (Jacobi and incomplete Cholesky), one thread, each measured against "
      "the reference (Newton, 8 sub-steps, tolerance 1e-9). Writes newton.csv, newton.json and "
      "newton.md.");
  cmd->add_option("--scenes", args->scenes, "Comma-separated scenes")->capture_default_str();
  cmd->add_option("--frames", args->frames, "Frames per run at 30 fps")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option(
         "--repeat", args->repeat,
         "Runs per variant; the fastest (CPU time) is kept, against a shared machine's noise")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--only", args->only,
                  "Comma-separated substrings: run only the variants whose label contains one, "
                  "e.g. 'ldlt tol=1e-06'");
  cmd->add_option("--out", args->out, "Output directory")->capture_default_str();
  cmd->callback([args] {
    const std::vector<std::string> scenes = split_list(args->scenes);
    SolverBenchOptions check;
    for (const auto& s : scenes) make_bench_scene(s, check);  // unknown names fail before any work
    make_directories(args->out);
    const auto start = std::chrono::steady_clock::now();
    const auto rows = run_newton_study(
        scenes, args->frames, args->repeat, split_list(args->only), [&](const std::string& line) {
          const double s =
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
          std::fprintf(stderr, "[%6.1fs] %s\n", s, line.c_str());
        });
    write_file_atomic(args->out + "/newton.csv", bench_rows_csv(rows));
    write_file_atomic(args->out + "/newton.json", bench_rows_json(rows));
    write_file_atomic(args->out + "/newton.md", newton_study_markdown(rows));
    std::printf("%s", newton_study_markdown(rows).c_str());
    std::printf("\nwrote %s/newton.{csv,json,md}\n", args->out.c_str());
  });
}

}  // namespace clothdb::cli
