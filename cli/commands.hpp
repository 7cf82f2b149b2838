// Each command file registers its subcommands on the CLI11 app; main.cpp calls them all.
// A command reports failure by throwing (std::exception): main prints "clothdb: error: <what>"
// and exits 1. Messages name the file and field that is wrong.
#pragma once

#include <CLI/CLI.hpp>

namespace clothdb::cli {

void register_bench_solvers(CLI::App& bench);  // cmd_bench_solvers.cpp
void register_bench_newton(CLI::App& bench);   // cmd_bench_solvers.cpp: `clothdb bench newton`
void register_scene_commands(CLI::App& app);   // cmd_scene.cpp: `clothdb scene run|list`
// cmd_simulate.cpp: `clothdb simulate`
void register_simulate(CLI::App& app);
// cmd_precompute.cpp: `clothdb precompute`
void register_precompute(CLI::App& app);
void register_floor(CLI::App& app);            // cmd_floor.cpp: `clothdb floor`
void register_forecast(CLI::App& app);         // cmd_forecast.cpp: `clothdb forecast`
void register_motion_commands(CLI::App& app);  // cmd_motion.cpp: `clothdb motion info`
void register_graph_commands(CLI::App& app);   // cmd_graph.cpp: `clothdb graph build|show`

void register_db_commands(CLI::App& app);    // cmd_db.cpp: `clothdb db info|check`
void register_db_dump(CLI::App& app);        // cmd_db_dump.cpp: `clothdb db dump`
void register_bench_codec(CLI::App& bench);  // cmd_bench_codec.cpp: `clothdb bench codec`

void register_play_commands(CLI::App& app);  // cmd_play.cpp: `clothdb play`
// cmd_clips.cpp: `clothdb clips list`, `clip show`
void register_clip_quality_commands(CLI::App& app);
void register_bench_runtime(CLI::App& bench);  // cmd_play.cpp: `clothdb bench runtime`
// cmd_edit.cpp: `clothdb clip export|import|resim|flag|unflag|delete|log`, `clothdb undo`
void register_edit_commands(CLI::App& app);
// cmd_bench_character.cpp: `clothdb bench character`
void register_bench_character(CLI::App& bench);
void register_bench_played(CLI::App& bench);  // cmd_bench_played.cpp: `clothdb bench played`
// cmd_bench_nearest.cpp: `clothdb bench nearest`
void register_bench_nearest(CLI::App& bench);
void register_view_command(CLI::App& app);  // cmd_view.cpp: `clothdb view`

}  // namespace clothdb::cli
