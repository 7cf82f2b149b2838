// `clothdb precompute SCENE --db FILE`: the main job. Builds the scene's motion graph (Kovar et
// al. 2002), then explores the secondary cloth graph (Kim et al. 2013) into the database until
// no dead end is above epsilon or a budget runs out. Rerunning the same command resumes.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <memory>
#include <thread>

#include "commands.hpp"
#include "explore/explorer.hpp"
#include "graph/motion_graph.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

void register_precompute(CLI::App& app) {
  struct Args {
    std::string scene, db, graph, curve;
    double epsilon_mm = 5.0, cpu_hours = 0.0, percentile = -1.0;
    long frames = 0;
    int threads = 0, batch = 16;
    bool quiet = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "precompute",
      "Builds the scene's motion graph and explores the secondary cloth graph into the database "
      "(Kim et al. 2013) until every dead end is within --epsilon or a budget (--frames, "
      "--cpu-hours) runs out. Killed at any moment, the same command resumes from the database.");
  cmd->add_option("SCENE", args->scene, "Scene file (JSON), e.g. motions/skirt_walk.json")->required();
  cmd->add_option("--db", args->db, "Database file (created, or resumed if it exists)")->required();
  cmd->add_option("--epsilon", args->epsilon_mm,
                  "Error bound in mm: RMS over vertices of sqrt(|dx|^2 + (|dv|/rate)^2)")
      ->capture_default_str()->check(CLI::PositiveNumber);
  cmd->add_option("--frames", args->frames, "Budget: cloth frames to simulate in this run (0: none)")
      ->capture_default_str();
  cmd->add_option("--cpu-hours", args->cpu_hours, "Budget: CPU hours of simulation in this run (0: none)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "OpenMP threads (0: all cores)")->capture_default_str();
  cmd->add_option("--batch", args->batch,
                  "Dead ends simulated per batch; fixed so the result does not depend on --threads")
      ->capture_default_str()->check(CLI::PositiveNumber);
  cmd->add_option("--graph", args->graph, "Use this motion graph (from `clothdb graph build`) instead of building one");
  cmd->add_option("--percentile", args->percentile, "Motion graph: transition threshold percentile (default: graph build's)");
  cmd->add_option("--curve", args->curve,
                  "Write the error-against-CPU-time curve to PREFIX.csv and PREFIX.svg (default: beside the database)");
  cmd->add_flag("--quiet", args->quiet, "No progress bar");
  cmd->callback([args] {
    const SceneFile file = load_scene_file(args->scene);
    const CharacterScene scene = build_character_scene(file);
    MotionGraph graph;
    if (!args->graph.empty()) {
      graph = load_motion_graph(args->graph);
      // The graph's clip indices must mean the scene's clips.
      for (size_t c = 0; c < graph.clips.size(); ++c)
        if (c >= scene.clips.size() || graph.clips[c].name != scene.clips[c].name)
          throw std::runtime_error(args->graph + ": clips[" + std::to_string(c) + "] is '" + graph.clips[c].name +
                                   "' but the scene's clip " + std::to_string(c) + " is '" +
                                   (c < scene.clips.size() ? scene.clips[c].name : std::string("(none)")) +
                                   "': build the graph from the scene's clips, in its order");
    } else {
      GraphSettings settings;
      if (args->percentile > 0) settings.threshold = args->percentile;
      graph = build_motion_graph(scene.clips, scene.skeleton, settings);
    }
    if (graph.edges.empty()) throw std::runtime_error(args->scene + ": the motion graph has no edges");
    ExploreGraph eg = explore_graph(scene, graph, args->graph.empty() ? args->scene : args->graph);
    const bool exists = std::filesystem::exists(args->db);
    db::Writer writer = exists ? db::Writer::open(args->db) : db::Writer::create(args->db);
    prepare_database(writer, scene, eg, motion_graph_to_json(graph).dump());
    ExploreOptions options;
    options.epsilon = 1e-3 * args->epsilon_mm;
    options.cpu_hours = args->cpu_hours;
    options.max_frames = args->frames;
    options.threads = args->threads > 0 ? args->threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    options.batch = args->batch;
    options.progress = !args->quiet;
    std::fprintf(stderr,
                 "%s: %s of %d vertices, %zu capsules, %s; motion graph %d nodes, %d edges (%d transitions); "
                 "epsilon %.1f mm, %d threads%s\n",
                 args->db.c_str(), scene.garment.name.c_str(), scene.model.vertex_count(), scene.body.capsules.size(),
                 solver_name(file.solver), graph.node_count(), graph.edge_count(), graph.transition_count(),
                 args->epsilon_mm, options.threads, exists ? " (resuming)" : "");
    const ExploreReport report = explore(scene, eg, writer, options);
    const std::string prefix = args->curve.empty() ? args->db + ".curve" : args->curve;
    write_file_atomic(prefix + ".csv", curve_csv(report.curve));
    write_file_atomic(prefix + ".svg", curve_svg(report.curve, options.epsilon));
    std::printf(
        "database     %s\n"
        "states       %d\nclips        %d\ndead ends    %d (%s)\nframes       %ld stored, %ld this run\n"
        "cpu          %.1f s this run (%.3f CPU-s per stored frame)\n"
        "worst error  %.2f mm unresolved, %.2f mm largest blend on an edge (epsilon %.1f mm)\n"
        "curve        %s.csv, %s.svg\n",
        args->db.c_str(), report.states, report.clips, report.dead_ends,
        report.converged ? "converged" : "budget reached", report.frames, report.frames_this_run,
        report.cpu_seconds, report.frames_this_run > 0 ? report.cpu_seconds / report.frames_this_run : 0.0,
        1e3 * report.worst_error, 1e3 * report.worst_blend_error, args->epsilon_mm, prefix.c_str(), prefix.c_str());
  });
}

}  // namespace clothdb::cli
