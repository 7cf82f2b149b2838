// `clothdb floor SCENE`: the error floor of a garment on a motion (explore/error_floor.hpp),
// measured without making a database: what epsilon the exploration can reach at all.
#include <algorithm>
#include <cstdio>
#include <memory>

#include "cli_util.hpp"
#include "commands.hpp"
#include "explore/error_floor.hpp"
#include "explore/precompute.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

namespace {

double largest_of(const std::vector<double>& v) {
  double m = 0;
  for (double d : v) m = std::max(m, d);
  return m;
}

}  // namespace

void register_floor(CLI::App& app) {
  struct Args {
    std::string scene, graph, out;
    double percentile = -1;
    double seconds = -1;
    bool quiet = false;
    ErrorFloorOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "floor",
      "The error floor of the scene's garment on its motion graph: how far apart cloth states "
      "stay that reach the same node by different histories. Simulates --histories weighted "
      "random walks from the settled start state that take different ways at their first choice "
      "and meet at a common node, then the same continuation of at least --seconds for all, then "
      "its last pose held still for --seconds; prints the pairwise state distances (the "
      "precompute's epsilon metric, character space) after walking and after holding still. The "
      "floor is the median walked distance: an --epsilon below it cannot link clip ends, so "
      "`precompute` refuses it without --force");
  cmd->add_option("SCENE", args->scene, "Scene file (JSON), e.g. motions/skirt_walk.json")
      ->required();
  cmd->add_option("--graph", args->graph,
                  "Motion graph file (from `clothdb graph build --out`); default: built from the "
                  "scene's clips as `precompute` builds it");
  cmd->add_option("--percentile", args->percentile,
                  "Motion graph: transition threshold percentile (default: the scene's graph "
                  "block, else graph build's; refused beside a graph block)")
      ->check(number_in(0.0, 100.0, true));
  cmd->add_option("--histories", args->options.histories, "Different histories (K)")
      ->capture_default_str()
      ->check(CLI::Range(2, 64));
  cmd->add_option("--seconds", args->seconds,
                  "Seconds of the common continuation and of holding still (each; default 2)")
      ->check(number_in(0.0, 600.0));
  cmd->add_option("--history-seconds", args->options.history_seconds,
                  "Seconds each history walks at random after its first choice")
      ->capture_default_str()
      ->check(number_in(0.0, 600.0));
  cmd->add_option("--seed", args->options.seed, "Seed of the random walks")->capture_default_str();
  cmd->add_option("--threads", args->options.threads,
                  "OpenMP threads across histories (0: all cores); the result does not depend on "
                  "it")
      ->capture_default_str()
      ->check(CLI::Range(0, 1024));
  cmd->add_option("--out", args->out, "Write the measurement as JSON to this file");
  cmd->add_flag("--quiet", args->quiet, "No progress lines");
  cmd->callback([args] {
    ErrorFloorOptions options = args->options;
    if (args->seconds >= 0) options.continuation_seconds = options.hold_seconds = args->seconds;
    options.progress = !args->quiet;
    const SceneFile file = load_scene_file(args->scene);
    const CharacterScene scene = build_character_scene(file);
    const ChosenGraph chosen = choose_motion_graph(scene, args->graph, "", args->percentile);
    if (chosen.graph.edges.empty())
      throw std::runtime_error(chosen.where + ": the motion graph has no edges");
    const ExploreGraph graph = explore_graph(scene, chosen.graph, chosen.where);
    std::printf("scene        %s: %s of %d vertices, %s; motion graph %d nodes, %d edges\n",
                args->scene.c_str(), scene.garment.name.c_str(), scene.model.vertex_count(),
                solver_name(scene.file.solver), chosen.graph.node_count(),
                chosen.graph.edge_count());
    for (const std::string& line : placement_lines(scene.placement))
      std::printf("             %s\n", line.c_str());
    std::fflush(stdout);
    const ErrorFloor f = measure_error_floor(scene, graph, options);
    if (f.fallback) std::printf("note         %s\n", f.note.c_str());
    for (int k = 0; k < f.histories(); ++k) {
      std::string edges;
      for (int e : f.history_edges[static_cast<size_t>(k)])
        edges += (edges.empty() ? "" : " ") + graph.edges[static_cast<size_t>(e)].name;
      std::printf("history %-4d %s%s\n", k, edges.c_str(),
                  f.fallback ? (" from frame " + std::to_string(f.start_frames[k])).c_str() : "");
    }
    std::string continuation;
    for (int e : f.continuation_edges)
      continuation += (continuation.empty() ? "" : " ") + graph.edges[static_cast<size_t>(e)].name;
    std::printf("continued    from node %d: %s (%d frames), then held still %d frames\n",
                f.common_node, continuation.empty() ? "(no edge leaves it)" : continuation.c_str(),
                f.continuation_frames, f.hold_frames);
    auto row = [](const char* name, const std::vector<double>& v, double median, double max) {
      std::printf("%-12s median %.2f mm, largest %.2f mm:", name, 1e3 * median, 1e3 * max);
      for (double d : v) std::printf(" %.2f", 1e3 * d);
      std::printf("\n");
    };
    row("met", f.met, f.met_median, f.met_max);
    row("halfway", f.halfway, f.halfway_median, largest_of(f.halfway));
    row("walked", f.walked, f.floor, f.walked_max);
    row("held", f.held, f.held_median, f.held_max);
    std::printf(
        "nearest      median %.2f mm: walked distance of each history to its nearest other\n",
        1e3 * f.nearest_median);
    std::printf("error floor  %s\n", error_floor_summary(f).c_str());
    std::printf("epsilon      at least %.0f mm suggested (1.5 x the floor, rounded up)\n",
                1e3 * suggested_epsilon(f.floor));
    std::printf("cpu          %.1f s, %ld solver steps (%.3f CPU-s per step)\n", f.cpu_seconds,
                f.frames, f.frames > 0 ? f.cpu_seconds / static_cast<double>(f.frames) : 0.0);
    if (!args->out.empty()) {
      write_file_atomic(args->out, error_floor_json(f, graph, options, true) + "\n");
      std::printf("output       %s\n", args->out.c_str());
    }
  });
}

}  // namespace clothdb::cli
