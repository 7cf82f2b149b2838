// `clothdb bench solvers`: the solvers' accuracy, separated into chaos, step size and model
// (docs/GUIDE.md#the-solvers); `clothdb bench newton`: the Newton loop's speed study.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <stdexcept>

#include "bench/solver_accuracy.hpp"
#include "bench/solver_bench.hpp"
#include "bench/strain_study.hpp"
#include "cli_util.hpp"
#include "commands.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

void register_bench_solvers(CLI::App& bench) {
  struct Args {
    std::string scenes, solvers, targets = "1,10", out = "out/bench-solvers";
    AccuracyOptions options;
    std::vector<std::string> settings;
    bool strain_study = false, no_references = false;
    std::string strain_targets = "1";
    int vertices = 10000;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "solvers",
      "Solver accuracy, separated: per scene a chaos floor (the reference against "
      "itself started 1 um away), the short-horizon error (every solver setting restarted from "
      "the reference's states every --restart-every frames and run --horizon frames, against "
      "Newton with uniform sub-steps), self-convergence (the same windows at --refine x the "
      "sub-steps: discretisation error against model mismatch), ensemble statistics against a "
      "perturbed reference ensemble on chaotic scenes, the CPU cost per simulated second at "
      "--target-mm, and static cases with analytic answers (membrane elongation, cantilever, "
      "catenary). Writes accuracy.json, rows.csv, statics.csv, accuracy.md and one Pareto SVG "
      "per scene into --out. See docs/GUIDE.md, \"The solvers\".");
  cmd->add_option("--scenes", args->scenes,
                  "Comma-separated scenes (default: hanging-sheet, swung-sheet, sphere-drape, "
                  "stretched-start, seed004-fall; also any hard case, seed004-529, large-sheet)");
  cmd->add_option("--solvers", args->solvers, "Comma-separated solvers (default: all four)");
  cmd->add_flag("--quick", args->options.quick,
                "Two settings per solver instead of the full sweep");
  cmd->add_option("--frames", args->options.frames, "Frames (1/30 s) of every continuous run")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--resolution", args->options.resolution,
                  "Nodes per side of the hard-case sheets (0: scene default)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000));
  cmd->add_option("--restart-every", args->options.restart_every,
                  "A short-horizon window starts every this many frames")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--horizon", args->options.horizon, "Frames run in each window")
      ->capture_default_str()
      ->check(CLI::Range(1, 3));
  cmd->add_option("--refine", args->options.refine,
                  "Self-convergence: sub-steps multiplied by this (4-8)")
      ->capture_default_str()
      ->check(CLI::Range(2, 64));
  cmd->add_option("--reference-substeps", args->options.reference_substeps,
                  "Uniform sub-steps per frame of the Newton reference")
      ->capture_default_str()
      ->check(CLI::Range(1, 1024));
  cmd->add_option("--reference-tolerance", args->options.reference_tolerance,
                  "Newton force tolerance of the reference (x max vertex weight; the solver "
                  "never asks for less than its rounding floor)")
      ->capture_default_str()
      ->check(number_in(0, 1e-2, true));
  cmd->add_option("--ensemble", args->options.ensemble,
                  "Members of the perturbed reference ensemble on chaotic scenes")
      ->capture_default_str()
      ->check(CLI::Range(2, 64));
  cmd->add_option("--chaotic-mm", args->options.chaotic_floor_mm,
                  "A scene whose chaos floor reaches this RMS (mm) is chaotic")
      ->capture_default_str()
      ->check(positive_number());
  cmd->add_option("--target-mm", args->targets,
                  "Comma-separated short-horizon RMS errors (mm) at which the cost is read")
      ->capture_default_str();
  cmd->add_option("--static-frames", args->options.static_frames,
                  "Frames each setting gets to settle a static case")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000));
  cmd->add_flag("!--no-statics", args->options.statics, "Skip the static analytic cases");
  cmd->add_option("--max-mass-spring-substeps", args->options.max_mass_spring_substeps,
                  "Mass-spring settings needing more sub-steps per frame are not run")
      ->capture_default_str()
      ->check(CLI::Range(1, 100000000));
  cmd->add_option("--seed", args->options.seed, "Seed of the perturbations")->capture_default_str();
  cmd->add_option("--setting", args->settings,
                  "A solver block as in a scene file, e.g. '{\"name\": \"xpbd\", \"substeps\": "
                  "40, \"stretch_iterations\": 4, \"strain_limit\": 0.01, "
                  "\"strain_limit_relaxation\": 1.8, \"chebyshev_rho\": 0.8}'; repeat it for "
                  "several. Fields left out keep their defaults (tethers on). Run after the sweep, "
                  "or alone with --strain-study (docs/guide/resolution.md)")
      ->take_all();
  cmd->add_flag("--strain-study", args->strain_study,
                "Instead of the accuracy benchmark: every --setting on every scene, one "
                "continuous run of --frames frames each: CPU ms per frame, p99 and largest edge "
                "strain, distance to the same setting at 8x the sub-steps, and per "
                "--strain-targets the cheapest setting within it. Writes strain.json and "
                "strain.md");
  cmd->add_option("--strain-targets", args->strain_targets,
                  "Comma-separated largest-strain targets in percent (--strain-study)")
      ->capture_default_str();
  cmd->add_flag("--no-references", args->no_references,
                "--strain-study without the 8x-sub-step reference runs (no distance column)");
  cmd->add_option(
         "--vertices", args->vertices,
         "Vertex count of large-sheet in --strain-study (the accuracy benchmark's is 10,000)")
      ->capture_default_str()
      ->check(CLI::Range(16, 1000000));
  cmd->add_option("--out", args->out, "Output directory")->capture_default_str();
  cmd->callback([args] {
    std::vector<SolverCandidate> settings;
    for (const std::string& text : args->settings) {
      SolverKind kind = SolverKind::Xpbd;
      SolverSettings s;
      parse_solver_settings_json(text, "--setting", &kind, &s);
      settings.push_back({kind, s, text});
    }
    if (args->strain_study) {
      if (settings.empty())
        throw std::invalid_argument("--strain-study: give at least one --setting");
      StrainStudyOptions study;
      study.settings = settings;
      study.frames = args->options.frames;
      study.references = !args->no_references;
      study.targets.clear();
      for (const auto& t : split_list(args->strain_targets)) {
        double v = NAN;
        try {
          v = std::stod(t);
        } catch (const std::exception&) {
        }
        if (!(v > 0 && v < 1000))
          throw std::invalid_argument("--strain-targets: " + t + " is not in (0, 1000) %");
        study.targets.push_back(v / 100);
      }
      SolverBenchOptions scene_options;
      scene_options.resolution = args->options.resolution;
      scene_options.large_vertices = args->vertices;
      std::vector<std::string> names = split_list(args->scenes);
      if (names.empty()) names = {"large-sheet"};
      std::vector<ClothScene> scenes;
      for (const auto& name : names) scenes.push_back(make_bench_scene(name, scene_options));
      make_directories(args->out);
      const auto start = std::chrono::steady_clock::now();
      std::vector<StrainStudy> studies;
      std::string md;
      for (const ClothScene& scene : scenes) {
        studies.push_back(run_strain_study(scene, study, [&](const std::string& line) {
          const double s =
              std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
          std::fprintf(stderr, "[%6.1fs] %s\n", s, line.c_str());
        }));
        md += strain_study_markdown(studies.back()) + "\n";
      }
      write_file_atomic(args->out + "/strain.json", strain_study_json(studies));
      write_file_atomic(args->out + "/strain.md", md);
      std::printf("%s\nwrote %s/strain.{json,md}\n", md.c_str(), args->out.c_str());
      return;
    }
    AccuracyOptions options = args->options;
    options.extra = settings;
    options.scenes = split_list(args->scenes);
    options.solvers = split_list(args->solvers);
    for (const auto& s : options.solvers) parse_solver_kind(s);  // fail before any work
    options.target_errors_mm.clear();
    for (const auto& t : split_list(args->targets)) {
      double v = NAN;
      try {
        v = std::stod(t);
      } catch (const std::exception&) {
      }
      if (!(v > 0 && v < 1e6))
        throw std::invalid_argument("--target-mm: " + t + " is not in (0, 1e6) mm");
      options.target_errors_mm.push_back(v);
    }
    SolverBenchOptions check;
    for (const auto& s : options.scenes) make_bench_scene(s, check);
    make_directories(args->out);
    const auto start = std::chrono::steady_clock::now();
    const AccuracyReport report = run_accuracy_bench(options, [&](const std::string& line, int done,
                                                                  int total) {
      const double s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      const double eta = done > 0 ? s / done * (total - done) : 0.0;
      std::fprintf(stderr, "[%6.1fs %3d/%d ETA %5.0fs] %s\n", s, done, total, eta, line.c_str());
    });
    write_file_atomic(args->out + "/accuracy.json", accuracy_json(report));
    write_file_atomic(args->out + "/rows.csv", accuracy_rows_csv(report));
    write_file_atomic(args->out + "/statics.csv", accuracy_statics_csv(report));
    write_file_atomic(args->out + "/accuracy.md", accuracy_markdown(report));
    for (const auto& s : report.scenes)
      write_file_atomic(args->out + "/" + s.name + ".svg", render_svg(accuracy_plot(s)));
    std::printf("%s", accuracy_markdown(report).c_str());
    std::printf("\nwrote %s/{accuracy.json,rows.csv,statics.csv,accuracy.md} and %zu SVG plots\n",
                args->out.c_str(), report.scenes.size());
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
