// `clothdb graph build MANIFEST --out graph.json --db FILE.db` finds transitions between the clips
// of a motion manifest (Kovar et al. 2002) and writes the pruned motion graph (JSON, and/or into a
// database for `clothdb precompute`); `clothdb graph show
// graph.json` prints it and draws it (built-in SVG, or Graphviz DOT).
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>

#include "cli_util.hpp"
#include "commands.hpp"
#include "database/store/writer.hpp"
#include "explore/primary_graph.hpp"
#include "graph/graph_svg.hpp"
#include "graph/motion_graph.hpp"
#include "report/output.hpp"

namespace clothdb::cli {

namespace {

struct BuildArgs {
  std::string manifest, out, db, clips;
  GraphSettings settings;
  std::optional<double> threshold, percentile;
  bool no_prune = false;
  double position_bound_mm = 0;  // 0: the codec's default
};

void print_summary(const MotionGraph& g) {
  std::printf("motion graph: %d nodes, %d edges (%d transitions, %d clip segments), %zu clips\n",
              g.node_count(), g.edge_count(), g.transition_count(), g.clip_edge_count(),
              g.clips.size());
  std::printf("  window %d frames, blend %d frames; threshold ", g.settings.window,
              g.settings.blend);
  if (g.settings.threshold_mode == ThresholdMode::percentile)
    std::printf("%g percentile of each clip pair's distances, at most %.4f m RMS:\n",
                g.settings.threshold, g.settings.max_distance);
  else
    std::printf("%.4f m RMS:\n", g.settings.threshold);
  for (const PairThreshold& t : g.thresholds)
    std::printf("    %s - %s: %.4f m\n", g.clips[t.clip_a].name.c_str(),
                g.clips[t.clip_b].name.c_str(), t.rms);
  std::printf("  before pruning: %d nodes, %d transitions\n", g.candidate_nodes,
              g.candidate_transitions);
  if (g.settings.min_segment_s > 0)
    std::printf(
        "  min_segment_s %g: transition points snapped onto nodes %d frames apart or more\n",
        g.settings.min_segment_s, g.settings.min_segment_frames(g.clips.front().rate));
  for (int c = 0; c < static_cast<int>(g.clips.size()); ++c) {
    int nodes = 0, out = 0, in = 0;
    for (const GraphNode& n : g.nodes) nodes += n.clip == c;
    for (const GraphEdge& e : g.edges)
      if (e.kind == EdgeKind::transition) out += e.clip == c, in += e.target_clip == c;
    std::printf("  clip %-20s %5d frames at %g Hz: %3d nodes, %3d transitions out, %3d in\n",
                g.clips[c].name.c_str(), g.clips[c].frame_count, g.clips[c].rate, nodes, out, in);
  }
  std::printf("%s", coverage_text(g).c_str());
}

MotionGraph build_graph(const BuildArgs& a, GraphInput& input) {
  GraphSettings s = a.settings;
  if (a.threshold) {
    s.threshold_mode = ThresholdMode::absolute;
    s.threshold = *a.threshold;
  } else if (a.percentile) {
    s.threshold_mode = ThresholdMode::percentile;
    s.threshold = *a.percentile;
  }
  s.prune = !a.no_prune;
  input = load_graph_input(a.manifest, split_list(a.clips));
  try {
    MotionGraph g = build_motion_graph(input.clips, input.skeleton, s, input.transitions);
    set_edge_weights(g, input.clip_weights, input.transitions);
    return g;
  } catch (const GraphError& e) {
    // Messages about a declared transition already name the manifest; the others get it here.
    const std::string what = e.what();
    if (what.rfind(a.manifest + ":", 0) == 0) throw;
    throw GraphError(a.manifest + ": " + what);
  }
}

void write_graph_json(const MotionGraph& g, const std::string& path) {
  write_file_atomic(path, motion_graph_to_json(g).dump(1) + "\n");
}

// The graph into a database (new, or one that holds no graph yet or this very graph): its edges as
// primary clips and transitions, the JSON in meta (docs/SECONDARY_GRAPH.md). One transaction.
void write_graph_db(const MotionGraph& g, const GraphInput& input, const std::string& path,
                    const std::string& manifest, double position_bound) {
  ExploreGraph eg = make_explore_graph(g, input.clips, manifest);
  const std::string json = motion_graph_to_json(g).dump();
  db::Writer writer = db::Writer::open_or_create(path, position_bound);
  db::Reader reader;
  db::Error err;
  if (reader.open(path, &err) != db::Status::Ok)
    throw std::runtime_error(path + ": " + std::string(err.message));
  if (attach_primary_graph(reader, eg, json)) {
    std::printf("%s already holds this motion graph\n", path.c_str());
    return;
  }
  std::vector<db::StoredState> states;
  db::throw_if_error(reader.cloth_states(&states, &err), err);
  if (!states.empty())
    throw std::runtime_error(path + ": holds cloth states but no motion graph; use a new database");
  write_primary_graph(writer, eg, json, input.files);
  std::printf("wrote the motion graph into %s (%d primary clips)\n", path.c_str(), g.edge_count());
}

void print_graph(const MotionGraph& g) {
  print_summary(g);
  std::printf("nodes:\n");
  for (int v = 0; v < g.node_count(); ++v)
    std::printf("  %4d  %s frame %d\n", v, g.clips[g.nodes[v].clip].name.c_str(), g.nodes[v].frame);
  std::printf("edges:\n");
  for (int k = 0; k < g.edge_count(); ++k) {
    const GraphEdge& e = g.edges[k];
    if (e.kind == EdgeKind::clip) {
      std::printf("  %4d  %4d -> %-4d clip        %s frames %d..%d\n", k, e.from, e.to,
                  g.clips[e.clip].name.c_str(), e.first_frame, e.last_frame);
    } else {
      std::printf(
          "  %4d  %4d -> %-4d transition  %s %d -> %s %d, blend %d, %.2f cm RMS, turn %.1f deg%s\n",
          k, e.from, e.to, g.clips[e.clip].name.c_str(), e.first_frame,
          g.clips[e.target_clip].name.c_str(), e.target_frame, e.blend, e.distance * 100.0,
          e.align.theta * 180.0 / 3.14159265358979323846, e.manual ? " (declared)" : "");
    }
  }
}

}  // namespace

namespace {

// A graph file, or the motion graph a clothdb database holds (meta `motion_graph`).
MotionGraph load_graph_or_database(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  char magic[16] = {};
  in.read(magic, sizeof magic);
  if (std::string(magic, 15) != "SQLite format 3") {
    // Neither kind: say so, rather than report a text or binary file as bad JSON at its first byte.
    const size_t start = std::string(magic, size_t(in.gcount())).find_first_not_of(" \t\r\n");
    if (in.gcount() > 0 && (start == std::string::npos || magic[start] == '{'))
      return load_motion_graph(path);
    std::error_code ec;
    if (std::filesystem::is_regular_file(path, ec))
      throw std::runtime_error(path +
                               ": neither a clothdb database nor a motion graph (the JSON "
                               "`clothdb graph build --out` writes)");
    return load_motion_graph(path);  // names what is missing
  }
  db::Reader reader;
  db::Error err;
  if (reader.open(path, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  std::string text;
  if (reader.meta(db::meta::kMotionGraph, &text, &err) != db::Status::Ok)
    throw std::runtime_error(path +
                             ": holds no motion graph (run `clothdb precompute` on it first)");
  return motion_graph_from_json(nlohmann::json::parse(text), path + ": meta motion_graph");
}

}  // namespace

void register_graph_commands(CLI::App& app) {
  CLI::App* graph = app.add_subcommand("graph", "Primary motion graph (Kovar et al. 2002)");
  graph->require_subcommand(1);

  auto build = std::make_shared<BuildArgs>();
  CLI::App* b = graph->add_subcommand(
      "build",
      "Finds transitions between the clips of a motion manifest (point-cloud distance between "
      "windows of poses, local minima under a threshold), adds the manifest's declared ones, "
      "prunes to the largest strongly connected component and writes the graph as JSON.");
  b->add_option("MANIFEST", build->manifest, "Motion manifest (.json)")->required();
  b->add_option("--out", build->out, "Graph file to write (.json)");
  b->add_option(
      "--db", build->db,
      "Database to write the graph into (created if missing; `clothdb precompute SCENE --db "
      "FILE` then explores on this graph)");
  b->add_option("--position-bound", build->position_bound_mm,
                "Codec bound per coordinate in mm for a new --db (default 0.5; fixed when the "
                "file is made)")
      ->check(number_in(1e-6, 1e3));
  b->add_option("--clips", build->clips, "Comma-separated clip names (default: every clip)");
  b->add_option("--window", build->settings.window, "Frames per window of the distance")
      ->capture_default_str()
      ->check(positive_number());
  b->add_option("--blend", build->settings.blend, "Frames of a transition's blend")
      ->capture_default_str()
      ->check(positive_number());
  auto* threshold = b->add_option("--threshold", build->threshold,
                                  "Absolute threshold: largest RMS distance in metres");
  auto* percentile =
      b->add_option("--percentile", build->percentile,
                    "Relative threshold: this percentile (0-100) of the window distances of "
                    "each pair of clips (default 0.03)")
          ->check(number_in(0.0, 100.0));
  threshold->excludes(percentile);
  b->add_option("--max-distance", build->settings.max_distance,
                "With a percentile: never above this RMS distance, metres")
      ->capture_default_str()
      ->check(non_negative_number());
  b->add_option("--spacing", build->settings.spacing,
                "Radius in frames of the neighbourhood a transition is the minimum of")
      ->capture_default_str()
      ->check(non_negative_number());
  b->add_option("--self-offset", build->settings.min_self_offset,
                "Within a clip, ignore frame pairs closer than this")
      ->capture_default_str()
      ->check(positive_number());
  b->add_option("--min-segment-s", build->settings.min_segment_s,
                "Snap transition points within this many seconds of each other in one clip onto "
                "one node, so that clip segments last at least this long except at clip ends (0: "
                "off); a transition whose distance at the snapped frames exceeds the threshold "
                "is dropped")
      ->capture_default_str()
      ->check(non_negative_number());
  b->add_flag("--no-prune", build->no_prune,
              "Keep every node (do not prune to the largest strongly connected component)");
  b->callback([build] {
    if (build->out.empty() && build->db.empty())
      throw std::runtime_error("graph build: give --out FILE.json, --db FILE.db, or both");
    const auto start = std::chrono::steady_clock::now();
    GraphInput input;
    const MotionGraph g = build_graph(*build, input);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    print_summary(g);
    std::printf("built in %.2f s (loading included)\n", seconds);
    if (!build->out.empty()) {
      write_graph_json(g, build->out);
      std::printf("wrote %s\n", build->out.c_str());
    }
    if (!build->db.empty())
      write_graph_db(g, input, build->db, build->manifest, 1e-3 * build->position_bound_mm);
  });

  struct ShowArgs {
    std::string file, svg, dot, dot_svg;
    bool quiet = false;
  };
  auto show = std::make_shared<ShowArgs>();
  CLI::App* s = graph->add_subcommand(
      "show", "Prints a motion graph (nodes, edges, clips, transitions) and draws it as SVG");
  s->add_option("FILE", show->file, "Graph file (.json, from graph build) or clothdb database")
      ->required();
  s->add_option("--svg", show->svg, "Write the built-in drawing (one lane per clip) to this SVG");
  s->add_option("--dot", show->dot, "Write the graph in Graphviz DOT to this file");
  s->add_option("--dot-svg", show->dot_svg,
                "Render the DOT with Graphviz (dot must be on PATH) to this SVG");
  s->add_flag("--summary", show->quiet, "Print the counts only, not every node and edge");
  s->callback([show] {
    const MotionGraph g = load_graph_or_database(show->file);
    if (show->quiet)
      print_summary(g);
    else
      print_graph(g);
    if (!show->svg.empty()) {
      write_file_atomic(show->svg, motion_graph_svg(g));
      std::printf("wrote %s\n", show->svg.c_str());
    }
    if (!show->dot.empty()) {
      write_file_atomic(show->dot, motion_graph_dot(g));
      std::printf("wrote %s\n", show->dot.c_str());
    }
    if (!show->dot_svg.empty()) {
      render_dot_svg(motion_graph_dot(g), show->dot_svg);
      std::printf("wrote %s (Graphviz)\n", show->dot_svg.c_str());
    }
  });
}

}  // namespace clothdb::cli
