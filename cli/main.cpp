// clothdb: the command-line tool for precomputed secondary cloth.
#include <cstdio>
#include <exception>

#include "commands.hpp"
#ifdef CLOTHDB_MPI
#include "explore/explore_mpi.hpp"
#endif

int main(int argc, char** argv) {
#ifdef CLOTHDB_MPI
  // Initialises MPI only under mpirun / srun; `clothdb` on its own never touches it.
  clothdb::mpi::Session mpi_session(&argc, &argv);
#endif
  CLI::App app{
      "clothdb: precomputed secondary cloth. Simulates a garment offline over a character's "
      "motion graph, stores it in one SQLite database, and plays it back."};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");

  CLI::App* bench = app.add_subcommand("bench", "Benchmarks (speed against error)");
  bench->require_subcommand(1);

  clothdb::cli::register_bench_solvers(*bench);
  clothdb::cli::register_bench_newton(*bench);
  clothdb::cli::register_bench_codec(*bench);
  clothdb::cli::register_bench_runtime(*bench);
  clothdb::cli::register_bench_played(*bench);
  clothdb::cli::register_bench_nearest(*bench);
  clothdb::cli::register_bench_character(*bench);
  clothdb::cli::register_scene_commands(app);
  clothdb::cli::register_db_commands(app);
  clothdb::cli::register_db_dump(app);
  clothdb::cli::register_simulate(app);
  clothdb::cli::register_precompute(app);
  clothdb::cli::register_floor(app);
  clothdb::cli::register_forecast(app);
  clothdb::cli::register_edit_commands(app);
  clothdb::cli::register_motion_commands(app);
  clothdb::cli::register_graph_commands(app);
  clothdb::cli::register_play_commands(app);
  clothdb::cli::register_clip_quality_commands(app);
  clothdb::cli::register_view_command(app);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "clothdb: error: %s\n", e.what());
#ifdef CLOTHDB_MPI
    clothdb::mpi::abort_all(1);  // the other ranks would wait for this one forever
#endif
    return 1;
  }
  return 0;
}
