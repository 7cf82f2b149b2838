// `clothdb bench played DB`: the end-to-end accuracy of a database (precompute/bench/
// played_bench.hpp): played cloth against a simulation of the same random walks, next to the
// chaos floor. Writes DIR/summary.json, DIR/path_K.csv and DIR/path_K.svg.
#include <cstdio>
#include <memory>

#include "bench/played_bench.hpp"
#include "cli_util.hpp"
#include "commands.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

void register_bench_played(CLI::App& bench) {
  struct Args {
    std::string db, out, scene, motions;
    PlayedOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "played",
      "How far the cloth a player sees is from simulation: plays --paths seeded random walks of "
      "--seconds through the primary graph (the manifest's weights) with the runtime library, "
      "simulates the same walks continuously with the database's scene and solver settings from "
      "the same start state, and compares frame by frame (RMS and max vertex distance, blending, "
      "fallbacks, linked edges). The chaos floor is the same simulation from a start perturbed by "
      "1 um. Writes DIR/summary.json, DIR/path_K.csv and DIR/path_K.svg");
  cmd->add_option("DB", args->db, "Database file")->required();
  cmd->add_option("--paths", args->options.paths, "Random walks")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  cmd->add_option("--seconds", args->options.seconds, "Length of each walk, s")
      ->capture_default_str()
      ->check(CLI::Range(1e-3, 3600.0));
  cmd->add_option("--seed", args->options.seed, "Seed of the walks")->capture_default_str();
  cmd->add_option("--threads", args->options.threads, "Simulations run in parallel (0: all cores)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1024));
  cmd->add_option("--out", args->out, "Output directory (default: DB.played)");
  cmd->add_option("--scene", args->scene,
                  "The scene file (default: the one the database stores; needed only for files "
                  "made before scenes were stored)");
  cmd->add_option("--motions", args->motions,
                  "Folder holding the motion files, if not at their recorded paths (found by "
                  "content hash)");
  cmd->add_flag(
      "--quiet", [args](int64_t) { args->options.progress = false; }, "No progress bar");
  cmd->callback([args] {
    db::Reader reader = open_reader(args->db);
    const DatabaseScene ds = load_database_scene(reader, args->scene, args->motions);
    // The solver setting the database was made with (it may be --auto's, not the scene's).
    SolverKind kind = ds.scene.file.solver;
    SolverSettings settings = ds.scene.file.settings;
    db::Garment garment;
    db::Error err;
    if (reader.garment(&garment, &err) == db::Status::Ok && !garment.solver.empty())
      parse_solver_settings_json(garment.solver, args->db + ": garment solver", &kind, &settings);
    reader.close();
    const PlayedReport r =
        bench_played(args->db, ds.scene, ds.graph, kind, settings, args->options);
    const std::string out = args->out.empty() ? args->db + ".played" : args->out;
    make_directories(out);
    for (size_t p = 0; p < r.paths.size(); ++p) {
      const std::string stem = out + "/path_" + std::to_string(p);
      write_file_atomic(stem + ".csv", played_path_csv(r.paths[p]));
      write_file_atomic(stem + ".svg",
                        played_path_svg(r.paths[p], args->db + ": path " + std::to_string(p)));
    }
    write_file_atomic(out + "/summary.json", played_json(r, args->options, args->db));
    std::printf(
        "played       %ld frames over %d paths of %g s (%s, %s)\n"
        "played RMS   p50 %.3f mm, p95 %.3f mm; largest vertex distance %.2f mm\n"
        "chaos floor  p50 %.4f mm, p95 %.4f mm (the same simulation from a start moved 1 um)\n"
        "pops         largest jump of a vertex beyond the simulation's %.3f mm; jitter %.3f mm "
        "(largest second difference of a vertex's error over frames)\n"
        "frames       %.1f %% blending, %.1f %% after a fallback, %.1f %% on a linked edge\n"
        "output       %s/summary.json, path_K.csv, path_K.svg\n",
        r.frames, args->options.paths, args->options.seconds, solver_name(kind), args->db.c_str(),
        r.played_rms_mm_p50, r.played_rms_mm_p95, r.played_max_mm, r.chaos_floor_rms_mm_p50,
        r.chaos_floor_rms_mm_p95, r.max_pop_mm, r.jitter_mm, 100 * r.blending_fraction,
        100 * r.fallback_fraction, 100 * r.linked_fraction, out.c_str());
  });
}

}  // namespace clothdb::cli
