#include "explore/error_floor.hpp"

#include <omp.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <limits>
#include <nlohmann/json.hpp>
#include <queue>
#include <random>
#include <stdexcept>

#include "character_scene/character_space.hpp"
#include "database/format/cloth_graph.hpp"
#include "report/cpu_time.hpp"

namespace clothdb {

namespace {

int frames_of(const ExploreGraph& graph, int edge) {
  return static_cast<int>(graph.edges[static_cast<size_t>(edge)].poses.size()) - 1;
}

std::vector<std::vector<int>> ways_out(const ExploreGraph& graph) {
  std::vector<std::vector<int>> out(static_cast<size_t>(graph.node_count));
  for (size_t e = 0; e < graph.edges.size(); ++e)
    out[static_cast<size_t>(graph.edges[e].from_node)].push_back(static_cast<int>(e));
  return out;
}

// One of `ways` with probability proportional to its weight: how the game chooses.
int choose_way(const ExploreGraph& graph, const std::vector<int>& ways, std::mt19937_64& rng) {
  double total = 0;
  for (int k : ways) total += graph.edges[static_cast<size_t>(k)].weight;
  double u = std::uniform_real_distribution<double>(0.0, total)(rng);
  for (int k : ways) {
    u -= graph.edges[static_cast<size_t>(k)].weight;
    if (u < 0) return k;
  }
  return ways.back();
}

// Appends edges chosen at random from `node` until at least `frames` frames are walked or no way
// leads on.
void walk_on(const ExploreGraph& graph, const std::vector<std::vector<int>>& out, int node,
             int frames, std::mt19937_64& rng, std::vector<int>& edges) {
  int walked = 0;
  while (walked < frames) {
    const std::vector<int>& ways = out[static_cast<size_t>(node)];
    if (ways.empty()) return;
    const int e = choose_way(graph, ways, rng);
    edges.push_back(e);
    walked += frames_of(graph, e);
    node = graph.edges[static_cast<size_t>(e)].to_node;
  }
}

int end_node(const ExploreGraph& graph, const std::vector<int>& edges, int start) {
  return edges.empty() ? start : graph.edges[static_cast<size_t>(edges.back())].to_node;
}

// Shortest ways (in frames) from `from` to every node: distance and the edge arriving there.
struct ShortestWays {
  std::vector<long> frames;  // -1: unreachable
  std::vector<int> via;      // the last edge of the shortest way (-1 at `from`)
};

ShortestWays shortest_ways(const ExploreGraph& graph, const std::vector<std::vector<int>>& out,
                           int from) {
  ShortestWays s;
  s.frames.assign(static_cast<size_t>(graph.node_count), -1);
  s.via.assign(static_cast<size_t>(graph.node_count), -1);
  using Item = std::pair<long, int>;  // (frames, node), ties by node: deterministic
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> queue;
  s.frames[static_cast<size_t>(from)] = 0;
  queue.push({0, from});
  while (!queue.empty()) {
    const auto [d, node] = queue.top();
    queue.pop();
    if (d != s.frames[static_cast<size_t>(node)]) continue;
    for (int e : out[static_cast<size_t>(node)]) {
      const int to = graph.edges[static_cast<size_t>(e)].to_node;
      const long nd = d + frames_of(graph, e);
      long& best = s.frames[static_cast<size_t>(to)];
      if (best < 0 || nd < best) {
        best = nd;
        s.via[static_cast<size_t>(to)] = e;
        queue.push({nd, to});
      }
    }
  }
  return s;
}

std::vector<int> way_to(const ExploreGraph& graph, const ShortestWays& s, int from, int to) {
  std::vector<int> edges;
  for (int node = to; node != from;) {
    const int e = s.via[static_cast<size_t>(node)];
    edges.push_back(e);
    node = graph.edges[static_cast<size_t>(e)].from_node;
  }
  std::reverse(edges.begin(), edges.end());
  return edges;
}

// The walk histories of the header's step 2, meeting at *common. Empty (with *why) when no two
// different walks can meet. History k makes its first D = ceil(log2 K) choices by the digits of
// k (in the base of each choice's number of ways: history 1 takes the second way at the first
// choice, ...), so any two differ at the first choice where their digits do (k < 2^D <= the
// product of the bases); then it chooses at random by weight, until it has walked
// history_seconds since its first choice.
std::vector<std::vector<int>> walk_histories(const ExploreGraph& graph,
                                             const ErrorFloorOptions& options, int* common,
                                             std::string* why) {
  const std::vector<std::vector<int>> out = ways_out(graph);
  const int history_frames = static_cast<int>(std::lround(options.history_seconds * graph.rate));
  int forced = 0;
  while ((1 << forced) < options.histories) ++forced;
  // Long enough to pass several choices, short enough to end (a graph of one-way nodes only).
  const long give_up = 100L * graph.node_count + 30L * history_frames + 1000;
  std::vector<std::vector<int>> walks;
  for (int k = 0; k < options.histories; ++k) {
    std::mt19937_64 rng(options.seed * 1000003ULL + 7919ULL * static_cast<uint64_t>(k));
    std::vector<int> walk;
    int node = graph.start_node, digits = k, choices = 0;
    int walked = -1;  // frames since the first choice
    for (long step = 0; step < give_up; ++step) {
      const std::vector<int>& ways = out[static_cast<size_t>(node)];
      if (ways.empty() || (walked >= history_frames && choices >= forced)) break;
      int e = ways.front();
      if (ways.size() > 1) {
        if (walked < 0) walked = 0;
        if (choices < forced) {
          e = ways[static_cast<size_t>(digits) % ways.size()];
          digits /= static_cast<int>(ways.size());
        } else {
          e = choose_way(graph, ways, rng);
        }
        ++choices;
      }
      walk.push_back(e);
      if (walked >= 0) walked += frames_of(graph, e);
      node = graph.edges[static_cast<size_t>(e)].to_node;
    }
    if (walked < 0) {
      *why = "the walk from the start node meets no node with more than one way out";
      return {};
    }
    if (std::find(walks.begin(), walks.end(), walk) == walks.end()) walks.push_back(walk);
  }
  // The common node: the one whose farthest walk end is nearest (then the smallest sum, then the
  // lowest index), so the histories add as few frames as possible.
  std::vector<ShortestWays> ways;
  for (const auto& w : walks)
    ways.push_back(shortest_ways(graph, out, end_node(graph, w, graph.start_node)));
  long best_max = -1, best_sum = -1;
  *common = -1;
  for (int n = 0; n < graph.node_count; ++n) {
    long worst = 0, sum = 0;
    bool all = true;
    for (const auto& s : ways) {
      const long d = s.frames[static_cast<size_t>(n)];
      if (d < 0) all = false;
      worst = std::max(worst, d);
      sum += d;
    }
    if (!all) continue;
    if (*common < 0 || worst < best_max || (worst == best_max && sum < best_sum))
      *common = n, best_max = worst, best_sum = sum;
  }
  if (*common < 0) {
    *why = "no node is reachable from the ends of all the walks";
    return {};
  }
  std::vector<std::vector<int>> histories;
  for (size_t k = 0; k < walks.size(); ++k) {
    std::vector<int> h = walks[k];
    const std::vector<int> rest =
        way_to(graph, ways[k], end_node(graph, walks[k], graph.start_node), *common);
    h.insert(h.end(), rest.begin(), rest.end());
    if (std::find(histories.begin(), histories.end(), h) == histories.end())
      histories.push_back(std::move(h));
  }
  if (histories.size() < 2) {
    *why = "the random walks found fewer than two different ways to a common node";
    return {};
  }
  return histories;
}

// Appends edge `e`'s frames after the first, carried rigidly so that its first pose's character
// frame is the walk's last (the character walks on; docs/SECONDARY_GRAPH.md): what the cloth sees
// in character space does not depend on where the walk has taken the character.
void append_edge(const CharacterScene& scene, const ExploreEdge& e,
                 std::vector<std::vector<JointPose>>& poses) {
  const Eigen::Isometry3d t =
      character_frame(scene, poses.back()) * character_frame(scene, e.poses.front()).inverse();
  for (size_t f = 1; f < e.poses.size(); ++f) poses.push_back(carried(e.poses[f], t));
}

// A state in character space at `pose`, as the explorer compares states.
struct LocalState {
  std::vector<float> x, v;
};

LocalState local_state(const CharacterScene& scene, const ClothState& state,
                       const std::vector<JointPose>& pose) {
  const Eigen::Isometry3d frame = character_frame(scene, pose);
  return {to_character_space(state.x, frame, false), to_character_space(state.v, frame, true)};
}

// One history's poses and where it arrives, ends its walk and ends holding still (frame indices
// into poses).
struct HistoryPlan {
  std::vector<std::vector<JointPose>> poses;
  size_t first = 0;  // frame it starts simulating from (the shared part is done before)
  size_t arrive = 0, halfway = 0, walked = 0, held = 0;
  int start_frame = 0;  // fallback: frame of the start edge settled at
};

struct HistoryResult {
  LocalState met, halfway, walked, held;
  long frames = 0;
  double cpu = 0;
  std::string error;
};

// Simulates plan.poses[from..to] (one solver step per frame) into `state`; throws naming the
// history on an unstable step.
void run_segment(const CharacterScene& scene, Solver& solver, const HistoryPlan& plan, size_t from,
                 size_t to, double rate, ClothState& state, int history, long* frames) {
  if (to <= from) return;
  const std::vector<std::vector<JointPose>> poses(plan.poses.begin() + static_cast<long>(from),
                                                  plan.poses.begin() + static_cast<long>(to) + 1);
  const PoseRun run = simulate_poses(scene, solver, poses, rate, state);
  *frames += static_cast<long>(to - from);
  if (!run.stable)
    throw std::runtime_error("error floor: history " + std::to_string(history) +
                             " is unstable at frame " + std::to_string(from) + " + " + run.message);
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double largest(const std::vector<double>& v) {
  return v.empty() ? 0 : *std::max_element(v.begin(), v.end());
}

void check_options(const ErrorFloorOptions& o) {
  if (!(o.histories >= 2 && o.histories <= 64))
    throw std::invalid_argument("error floor: histories: must be in [2, 64]");
  const std::pair<const char*, double> seconds[] = {
      {"history_seconds", o.history_seconds},
      {"continuation_seconds", o.continuation_seconds},
      {"hold_seconds", o.hold_seconds}};
  for (const auto& [name, value] : seconds)
    if (!(value >= 0 && value <= 600))
      throw std::invalid_argument(std::string("error floor: ") + name + ": must be in [0, 600] s");
  if (!(o.threads >= 0 && o.threads <= 1024))
    throw std::invalid_argument("error floor: threads: must be in [0, 1024]");
}

}  // namespace

ErrorFloor measure_error_floor(const CharacterScene& scene, const ExploreGraph& graph,
                               const ErrorFloorOptions& options) {
  check_options(options);
  if (graph.edges.empty()) throw std::runtime_error("error floor: the motion graph has no edges");
  const std::vector<std::vector<int>> out = ways_out(graph);
  if (out[static_cast<size_t>(graph.start_node)].empty())
    throw std::runtime_error("error floor: no edge leaves the motion graph's start node");
  // The explorer's start edge and start pose (explore(): the first edge leaving the start node).
  const int start_edge = out[static_cast<size_t>(graph.start_node)].front();
  const ExploreEdge& first = graph.edges[static_cast<size_t>(start_edge)];
  SolverSettings settings = scene.file.settings;
  settings.threads = 1;  // parallel across histories, not inside one
  const double tau = 1.0 / graph.rate;

  ErrorFloor floor;
  std::string why;
  std::vector<std::vector<int>> walks = walk_histories(graph, options, &floor.common_node, &why);
  floor.fallback = walks.empty();
  std::vector<HistoryPlan> plans;
  if (!floor.fallback) {
    floor.history_edges = walks;
  } else {
    // Settled at different frames of the start edge, then walked along the rest of it.
    const int last = frames_of(graph, start_edge);
    for (int k = 0; k < options.histories; ++k) {
      const int f = k * last / options.histories;
      if (!floor.start_frames.empty() && floor.start_frames.back() == f) continue;
      floor.start_frames.push_back(f);
      floor.history_edges.push_back({start_edge});
    }
    if (floor.start_frames.size() < 2)
      throw std::runtime_error("error floor: " + why + ", and the start edge '" + first.name +
                               "' has too few frames to settle the garment at different ones");
    floor.common_node = first.to_node;
    std::string frames;
    for (int f : floor.start_frames) frames += (frames.empty() ? "" : ", ") + std::to_string(f);
    floor.note = why + "; the histories are the garment settled at frames " + frames +
                 " of the start edge '" + first.name +
                 "' (held still there), then walked to its end";
  }

  // The common continuation and the hold.
  std::mt19937_64 rng(options.seed * 1000003ULL + 0x9e3779b97f4a7c15ULL);
  walk_on(graph, out, floor.common_node,
          static_cast<int>(std::lround(options.continuation_seconds * graph.rate)), rng,
          floor.continuation_edges);
  for (int e : floor.continuation_edges) floor.continuation_frames += frames_of(graph, e);
  floor.hold_frames = static_cast<int>(std::lround(options.hold_seconds * graph.rate));

  const int k_count = floor.histories();
  plans.resize(static_cast<size_t>(k_count));
  for (int k = 0; k < k_count; ++k) {
    HistoryPlan& p = plans[static_cast<size_t>(k)];
    if (floor.fallback) {
      p.start_frame = floor.start_frames[static_cast<size_t>(k)];
      p.poses.assign(first.poses.begin() + p.start_frame, first.poses.end());
    } else {
      p.poses.push_back(first.poses.front());
      for (int e : floor.history_edges[static_cast<size_t>(k)])
        append_edge(scene, graph.edges[static_cast<size_t>(e)], p.poses);
    }
    p.arrive = p.poses.size() - 1;
    p.halfway = p.arrive;
    for (int e : floor.continuation_edges) {
      // Halfway: the first node of the continuation at least half of it along (a node, as a
      // clip end is).
      if (2 * (p.halfway - p.arrive) < static_cast<size_t>(floor.continuation_frames))
        p.halfway = p.poses.size() - 1;
      append_edge(scene, graph.edges[static_cast<size_t>(e)], p.poses);
    }
    if (2 * (p.halfway - p.arrive) < static_cast<size_t>(floor.continuation_frames))
      p.halfway = p.poses.size() - 1;
    p.walked = p.poses.size() - 1;
    for (int f = 0; f < floor.hold_frames; ++f) p.poses.push_back(p.poses.back());
    p.held = p.poses.size() - 1;
  }

  // The shared part: the start state, and the walk all histories take before their first choice.
  const double cpu0 = thread_cpu_seconds();
  ClothState shared_state;
  size_t shared_frames = 0;
  if (!floor.fallback) {
    auto solver = make_scene_solver(scene, scene.file.solver, settings);
    shared_state = settle_garment(scene, *solver, first.poses.front());
    floor.frames += scene.file.settle_frames;
    size_t common_edges = 0;
    while (std::all_of(walks.begin(), walks.end(), [&](const std::vector<int>& w) {
      return common_edges < w.size() && w[common_edges] == walks.front()[common_edges];
    }))
      shared_frames += static_cast<size_t>(frames_of(graph, walks.front()[common_edges++]));
    run_segment(scene, *solver, plans.front(), 0, shared_frames, graph.rate, shared_state, 0,
                &floor.frames);
    for (HistoryPlan& p : plans) p.first = shared_frames;
  }
  floor.cpu_seconds = thread_cpu_seconds() - cpu0;

  std::vector<HistoryResult> results(static_cast<size_t>(k_count));
  // The progress lines' time left: the frames every history will simulate are known from the
  // plans, so the pace so far gives it.
  long planned_frames = 0, done_frames = 0;
  int done_histories = 0;
  for (const HistoryPlan& p : plans)
    planned_frames += static_cast<long>(p.held - p.first) +
                      (floor.fallback ? static_cast<long>(scene.file.settle_frames) : 0);
  const auto histories_start = std::chrono::steady_clock::now();
  const int threads = options.threads > 0 ? options.threads : omp_get_num_procs();
#pragma omp parallel for schedule(dynamic, 1) num_threads(std::max(1, threads))
  for (int k = 0; k < k_count; ++k) {
    HistoryResult& r = results[static_cast<size_t>(k)];
    const HistoryPlan& p = plans[static_cast<size_t>(k)];
    const double t0 = thread_cpu_seconds();
    try {
      auto solver = make_scene_solver(scene, scene.file.solver, settings);
      ClothState state;
      if (floor.fallback) {
        state = settle_garment(scene, *solver, p.poses.front());
        r.frames += scene.file.settle_frames;
      } else {
        state = shared_state;
      }
      run_segment(scene, *solver, p, p.first, p.arrive, graph.rate, state, k, &r.frames);
      r.met = local_state(scene, state, p.poses[p.arrive]);
      run_segment(scene, *solver, p, p.arrive, p.halfway, graph.rate, state, k, &r.frames);
      r.halfway = local_state(scene, state, p.poses[p.halfway]);
      run_segment(scene, *solver, p, p.halfway, p.walked, graph.rate, state, k, &r.frames);
      r.walked = local_state(scene, state, p.poses[p.walked]);
      run_segment(scene, *solver, p, p.walked, p.held, graph.rate, state, k, &r.frames);
      r.held = local_state(scene, state, p.poses[p.held]);
    } catch (const std::exception& e) {
      r.error = e.what();
    }
    r.cpu = thread_cpu_seconds() - t0;
    if (options.progress) {
#pragma omp critical(clothdb_error_floor_progress)
      {
        done_frames += r.frames;
        ++done_histories;
        char left[48] = "";
        if (done_histories < k_count && done_frames > 0 && done_frames < planned_frames) {
          const double wall =
              std::chrono::duration<double>(std::chrono::steady_clock::now() - histories_start)
                  .count();
          std::snprintf(left, sizeof left, "; about %.0f s left",
                        wall / double(done_frames) * double(planned_frames - done_frames));
        }
        std::fprintf(stderr, "error floor: history %d of %d simulated (%ld frames, %.1f CPU s)%s\n",
                     k + 1, k_count, r.frames, r.cpu, left);
      }
    }
  }
  for (const HistoryResult& r : results) {
    if (!r.error.empty()) throw std::runtime_error(r.error);
    floor.frames += r.frames;
    floor.cpu_seconds += r.cpu;
  }

  for (size_t a = 0; a < results.size(); ++a)
    for (size_t b = a + 1; b < results.size(); ++b) {
      auto distance = [&](const LocalState HistoryResult::*which) {
        const LocalState& sa = results[a].*which;
        const LocalState& sb = results[b].*which;
        return db::state_distance(sa.x, sa.v, sb.x, sb.v, tau);
      };
      floor.met.push_back(distance(&HistoryResult::met));
      floor.halfway.push_back(distance(&HistoryResult::halfway));
      floor.walked.push_back(distance(&HistoryResult::walked));
      floor.held.push_back(distance(&HistoryResult::held));
    }
  floor.floor = median(floor.walked);
  floor.walked_max = largest(floor.walked);
  floor.halfway_median = median(floor.halfway);
  floor.held_median = median(floor.held);
  floor.held_max = largest(floor.held);
  floor.met_median = median(floor.met);
  floor.met_max = largest(floor.met);
  std::vector<double> nearest(results.size(), std::numeric_limits<double>::infinity());
  for (size_t a = 0, pair = 0; a < results.size(); ++a)
    for (size_t b = a + 1; b < results.size(); ++b, ++pair) {
      nearest[a] = std::min(nearest[a], floor.walked[pair]);
      nearest[b] = std::min(nearest[b], floor.walked[pair]);
    }
  floor.nearest_median = median(nearest);
  return floor;
}

std::string error_floor_summary(const ErrorFloor& f) {
  char line[320];
  std::snprintf(line, sizeof line,
                "%.2f mm (median of %zu pairwise distances, %d histories meeting at node %d, "
                "largest %.2f mm; held still: %.2f mm, largest %.2f mm)",
                1e3 * f.floor, f.walked.size(), f.histories(), f.common_node, 1e3 * f.walked_max,
                1e3 * f.held_median, 1e3 * f.held_max);
  std::string text = line;
  if (f.still_falling()) {
    std::snprintf(line, sizeof line,
                  "; still falling while walking (%.2f mm halfway): a longer continuation may "
                  "measure it lower",
                  1e3 * f.halfway_median);
    text += line;
  }
  return text;
}

double suggested_epsilon(double floor) {
  return 1e-3 * std::max(1.0, std::ceil(1.5 * 1e3 * floor - 1e-9));
}

std::string error_floor_json(const ErrorFloor& f, const ExploreGraph& graph,
                             const ErrorFloorOptions& options, bool with_timing) {
  auto mm = [](const std::vector<double>& v) {
    std::vector<double> out;
    for (double d : v) out.push_back(1e3 * d);
    return out;
  };
  auto names = [&](const std::vector<int>& edges) {
    std::vector<std::string> out;
    for (int e : edges) out.push_back(graph.edges[static_cast<size_t>(e)].name);
    return out;
  };
  nlohmann::json histories = nlohmann::json::array();
  for (size_t k = 0; k < f.history_edges.size(); ++k) {
    nlohmann::json h = {{"edges", names(f.history_edges[k])}};
    if (f.fallback) h["start_frame"] = f.start_frames[k];
    histories.push_back(h);
  }
  nlohmann::json j = {{"floor_mm", 1e3 * f.floor},
                      {"walked_max_mm", 1e3 * f.walked_max},
                      {"held_median_mm", 1e3 * f.held_median},
                      {"held_max_mm", 1e3 * f.held_max},
                      {"met_median_mm", 1e3 * f.met_median},
                      {"met_max_mm", 1e3 * f.met_max},
                      {"nearest_median_mm", 1e3 * f.nearest_median},
                      {"walked_mm", mm(f.walked)},
                      {"halfway_mm", mm(f.halfway)},
                      {"halfway_median_mm", 1e3 * f.halfway_median},
                      {"still_falling", f.still_falling()},
                      {"held_mm", mm(f.held)},
                      {"met_mm", mm(f.met)},
                      {"common_node", f.common_node},
                      {"histories", histories},
                      {"continuation", names(f.continuation_edges)},
                      {"continuation_frames", f.continuation_frames},
                      {"hold_frames", f.hold_frames},
                      {"fallback", f.fallback},
                      {"note", f.note},
                      {"frames", f.frames},
                      {"options",
                       {{"histories", options.histories},
                        {"history_seconds", options.history_seconds},
                        {"continuation_seconds", options.continuation_seconds},
                        {"hold_seconds", options.hold_seconds},
                        {"seed", options.seed}}}};
  if (with_timing) j["cpu_seconds"] = f.cpu_seconds;
  return j.dump();
}

}  // namespace clothdb
