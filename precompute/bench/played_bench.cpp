#include "bench/played_bench.hpp"

#include <omp.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <stdexcept>

#include "character_scene/character_space.hpp"
#include "clothrt.h"
#include "database/format/cloth_graph.hpp"
#include "report/cpu_time.hpp"
#include "report/stats.hpp"
#include "report/svg_plot.hpp"

namespace clothdb {

namespace {

// A walk: the primary edges in order and the poses of the whole walk, each edge's poses carried
// rigidly so that its first pose's character frame is the previous edge's last (the character
// walks on; docs/SECONDARY_GRAPH.md), consecutive edges sharing the node's pose.
struct Walk {
  std::vector<int> edges;
  std::vector<int> first_frame;  // frame of the walk at which each edge starts
  std::vector<std::vector<JointPose>> poses;
  int ways_without_cloth = 0;
};

Walk random_walk(const CharacterScene& scene, const ExploreGraph& graph, int start_edge,
                 const std::vector<bool>& has_cloth, size_t frames, uint64_t seed) {
  std::mt19937_64 rng(seed);
  Walk w;
  int edge = start_edge;
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  while (true) {
    const ExploreEdge& e = graph.edges[static_cast<size_t>(edge)];
    w.edges.push_back(edge);
    w.first_frame.push_back(static_cast<int>(w.poses.empty() ? 0 : w.poses.size() - 1));
    if (!w.poses.empty()) {
      // Carry the edge so its start frame is where the walk is.
      const Eigen::Isometry3d here = character_frame(scene, w.poses.back());
      const Eigen::Isometry3d there = character_frame(scene, e.poses.front());
      t = here * there.inverse();
    }
    for (size_t f = w.poses.empty() ? 0 : 1; f < e.poses.size() && w.poses.size() < frames; ++f)
      w.poses.push_back(carried(e.poses[f], t));
    if (w.poses.size() >= frames) break;
    std::vector<int> ways;
    double total = 0;
    for (size_t k = 0; k < graph.edges.size(); ++k) {
      if (graph.edges[k].from_node != e.to_node) continue;
      if (!has_cloth[k]) {
        ++w.ways_without_cloth;
        continue;
      }
      ways.push_back(static_cast<int>(k));
      total += graph.edges[k].weight;
    }
    if (ways.empty()) break;  // nowhere to go with cloth: the walk ends here
    double u = std::uniform_real_distribution<double>(0.0, total)(rng);
    edge = ways.back();
    for (int k : ways) {
      u -= graph.edges[static_cast<size_t>(k)].weight;
      if (u < 0) {
        edge = k;
        break;
      }
    }
  }
  return w;
}

// The walk simulated continuously from `start` (world), in character space per frame.
struct Simulated {
  std::vector<Eigen::Matrix3Xd> frames;  // character space, frame 0 = start
  bool stable = true;
  std::string message;
  double cpu = 0;
};

Simulated simulate_walk(const CharacterScene& scene, const ExploreGraph& graph, const Walk& walk,
                        SolverKind kind, const SolverSettings& settings, ClothState state,
                        const std::function<void(size_t)>& on_frames) {
  Simulated out;
  auto solver = make_scene_solver(scene, kind, settings);
  const double t0 = thread_cpu_seconds();
  auto local = [&](const Eigen::Matrix3Xd& x, size_t f) {
    const Eigen::Isometry3d inv = character_frame(scene, walk.poses[f]).inverse();
    Eigen::Matrix3Xd l(3, x.cols());
    for (Eigen::Index i = 0; i < x.cols(); ++i) l.col(i) = inv * Vec3(x.col(i));
    return l;
  };
  out.frames.push_back(local(state.x, 0));
  // In segments, so that progress can be shown; the state (and the solver) carry on.
  constexpr size_t kSegment = 30;
  for (size_t begin = 0; begin + 1 < walk.poses.size(); begin += kSegment) {
    const size_t end = std::min(walk.poses.size() - 1, begin + kSegment);
    const std::vector<std::vector<JointPose>> poses(
        walk.poses.begin() + static_cast<long>(begin),
        walk.poses.begin() + static_cast<long>(end) + 1);
    const PoseRun run = simulate_poses(scene, *solver, poses, graph.rate, state);
    for (size_t k = 0; k < run.frames.size(); ++k)
      out.frames.push_back(local(run.frames[k], begin + 1 + k));
    if (on_frames) on_frames(run.frames.size());
    if (!run.stable) {
      out.stable = false;
      out.message = run.message;
      break;
    }
  }
  out.cpu = thread_cpu_seconds() - t0;
  return out;
}

// No samples (no played frame) reads as 0 mm, as before the shared definition.
double percentile(const std::vector<double>& v, double p) {
  return v.empty() ? 0 : report::percentile(v, p);
}

struct RtDb {
  clothrt_db* db = nullptr;
  ~RtDb() { clothrt_db_close(db); }
};
struct RtPlayer {
  clothrt_player* p = nullptr;
  ~RtPlayer() { clothrt_player_destroy(p); }
};

}  // namespace

PlayedReport bench_played(const std::string& db_path, const CharacterScene& scene,
                          const ExploreGraph& graph, SolverKind solver,
                          const SolverSettings& settings_given, const PlayedOptions& options) {
  if (!(options.paths >= 1 && options.paths <= 1000))
    throw std::invalid_argument("--paths: must be in [1, 1000]");
  if (!(options.seconds > 0 && options.seconds <= 3600))
    throw std::invalid_argument("--seconds: must be in (0, 3600]");
  if (!(options.perturbation > 0 && options.perturbation < 1e-2))
    throw std::invalid_argument("perturbation: must be in (0, 0.01) m");
  SolverSettings settings = settings_given;
  settings.threads = 1;  // parallel across simulations, not inside one

  RtDb rt;
  clothrt_db_options o;
  clothrt_db_options_init(&o);
  o.prefetch_threads = 0;  // decode on this thread: the same frames whatever the timing
  if (clothrt_db_open(db_path.c_str(), &o, &rt.db) != CLOTHRT_OK)
    throw std::runtime_error(std::string(clothrt_last_open_errmsg()));
  const size_t n = clothrt_db_vertex_count(rt.db);
  if (n != static_cast<size_t>(scene.model.vertex_count()))
    throw std::runtime_error(db_path + ": garment of " + std::to_string(n) +
                             " vertices, the scene makes " +
                             std::to_string(scene.model.vertex_count()));
  // Which primary clips have cloth, and the start clip.
  std::map<int64_t, bool> clip_has_cloth;
  for (size_t i = 0; i < clothrt_db_clip_count(rt.db); ++i) {
    clothrt_clip_info info;
    if (clothrt_db_clip_info(rt.db, i, &info) == CLOTHRT_OK)
      clip_has_cloth[info.id] = info.has_cloth != 0;
  }
  std::vector<bool> has_cloth(graph.edges.size());
  int start_edge = -1;
  const int64_t start_clip = clothrt_db_start_clip(rt.db);
  for (size_t e = 0; e < graph.edges.size(); ++e) {
    has_cloth[e] = clip_has_cloth[graph.edges[e].db_clip];
    if (graph.edges[e].db_clip == start_clip && start_edge < 0) start_edge = static_cast<int>(e);
  }
  if (start_edge < 0 || !has_cloth[static_cast<size_t>(start_edge)])
    throw std::runtime_error(db_path + ": its start clip has no cloth to play");

  // Which clip made each state (for "followed a linked edge").
  db::Reader reader;
  db::Error err;
  if (reader.open(db_path, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  std::vector<db::StoredState> states;
  if (reader.cloth_states(&states, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  std::map<int64_t, int64_t> source_clip;
  for (const auto& s : states) source_clip[s.id] = s.source_clip;

  const size_t frames = static_cast<size_t>(std::llround(options.seconds * graph.rate)) + 1;
  PlayedReport report;
  report.paths.resize(static_cast<size_t>(options.paths));
  std::vector<Walk> walks(static_cast<size_t>(options.paths));
  std::vector<std::vector<float>> played(walks.size());
  std::vector<ClothState> starts(walks.size());
  const double dt = 1.0 / graph.rate;

  // 1. Play each walk with the runtime (cheap; one thread) and find its start state.
  for (size_t p = 0; p < walks.size(); ++p) {
    walks[p] = random_walk(scene, graph, start_edge, has_cloth, frames, options.seed + 7919 * p);
    const Walk& w = walks[p];
    PlayedPath& path = report.paths[p];
    path.ways_without_cloth = w.ways_without_cloth;
    for (int e : w.edges) path.edges.push_back(graph.edges[static_cast<size_t>(e)].name);
    RtPlayer player;
    auto check = [&](int rc, const char* what) {
      if (rc != CLOTHRT_OK)
        throw std::runtime_error(db_path + ": playing path " + std::to_string(p) + ": " + what +
                                 ": " + clothrt_player_errmsg(player.p));
    };
    check(clothrt_player_create(rt.db, &player.p), "create");
    check(clothrt_player_start(player.p, graph.edges[static_cast<size_t>(w.edges[0])].db_clip),
          "start");
    size_t next = 1;
    if (next < w.edges.size())
      check(clothrt_player_set_next(player.p,
                                    graph.edges[static_cast<size_t>(w.edges[next])].db_clip),
            "next clip");
    clothrt_frame_info info{};
    check(clothrt_player_info(player.p, &info), "info");
    {
      std::vector<float> x, v;
      codec::DecodeScratch scratch;
      if (reader.read_state(info.cloth_state, &x, &v, scratch, &err) != db::Status::Ok)
        throw std::runtime_error(err.message);
      const Eigen::Isometry3d f0 = character_frame(scene, w.poses.front());
      starts[p].x = from_character_space(x, f0, false);
      starts[p].v = from_character_space(v, f0, true);
      const Eigen::Matrix3Xd pins = skin_pins(scene.garment, scene.bind, w.poses.front());
      for (size_t k = 0; k < scene.garment.pins.size(); ++k)
        starts[p].x.col(scene.garment.pins[k]) = pins.col(static_cast<Eigen::Index>(k));
    }
    played[p].resize(w.poses.size() * n * 3);
    uint64_t transitions = info.transitions;
    int64_t clip_now = info.cloth_clip;
    bool linked = false;
    for (size_t f = 0; f < w.poses.size(); ++f) {
      PlayedFrame fr;
      if (f > 0) {
        check(clothrt_player_advance(player.p, dt), "advance");
        check(clothrt_player_info(player.p, &info), "info");
        if (info.transitions != transitions) {
          transitions = info.transitions;
          fr.transition = true;
          // A linked edge: the state the new clip starts from was not made by the clip before
          // it (the same cloth clip may follow itself round a loop).
          linked = source_clip[info.cloth_state] != clip_now;
          clip_now = info.cloth_clip;
          ++next;
          if (next < w.edges.size())
            clothrt_player_set_next(player.p,
                                    graph.edges[static_cast<size_t>(w.edges[next])].db_clip);
        }
      }
      check(clothrt_player_get_positions(player.p, played[p].data() + f * n * 3, 12, nullptr),
            "positions");
      fr.time = static_cast<double>(f) * dt;
      fr.primary_clip = info.primary_clip;
      fr.cloth_clip = info.cloth_clip;
      fr.blending = info.blending != 0;
      fr.fallback = info.fallback != 0;
      fr.linked = linked;
      path.frames.push_back(fr);
    }
  }

  // 2. The reference simulations: per walk, the same walk continuously, and from the perturbed
  // start (task 2p and 2p + 1), in parallel.
  const size_t tasks = 2 * walks.size();
  std::vector<Simulated> sims(tasks);
  size_t total_frames = 0;
  for (const Walk& w : walks) total_frames += 2 * (w.poses.size() - 1);
  std::atomic<size_t> done{0};
  const auto wall0 = std::chrono::steady_clock::now();
  auto progress = [&](size_t k) {
    const size_t now = done.fetch_add(k) + k;
    if (!options.progress) return;
    const double fraction = static_cast<double>(now) / static_cast<double>(total_frames);
    const double wall =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
    const int full = static_cast<int>(24 * fraction);
#pragma omp critical(clothdb_played_progress)
    std::fprintf(stderr, "\rsimulating [%s%s] %zu / %zu frames  ETA %.0f s   ",
                 std::string(static_cast<size_t>(full), '#').c_str(),
                 std::string(static_cast<size_t>(24 - full), '.').c_str(), now, total_frames,
                 fraction > 0 ? wall / fraction * (1 - fraction) : 0.0);
  };
  const int threads = options.threads > 0 ? options.threads : omp_get_num_procs();
  std::exception_ptr error;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (size_t k = 0; k < tasks; ++k) {
    try {
      const size_t p = k / 2;
      ClothState start = starts[p];
      if (k % 2 == 1) {
        // 1 um in a direction that varies from vertex to vertex, free vertices only.
        std::vector<bool> pinned(static_cast<size_t>(start.x.cols()), false);
        for (int i : scene.garment.pins) pinned[static_cast<size_t>(i)] = true;
        for (Eigen::Index i = 0; i < start.x.cols(); ++i) {
          if (pinned[static_cast<size_t>(i)]) continue;
          const double a = 2.399963229728653 * static_cast<double>(i);  // golden angle
          const Vec3 d(std::cos(a), std::sin(1.7 * a), std::sin(a));
          start.x.col(i) += options.perturbation * d.normalized();
        }
      }
      sims[k] = simulate_walk(scene, graph, walks[p], solver, settings, start, progress);
    } catch (...) {
#pragma omp critical(clothdb_played_error)
      if (!error) error = std::current_exception();
    }
  }
  if (options.progress) std::fprintf(stderr, "\n");
  if (error) std::rethrow_exception(error);

  // 3. Per frame: played against simulated, simulated against perturbed.
  std::vector<double> rms_all, chaos_all;
  long fallback = 0, blending = 0, linked = 0;
  for (size_t p = 0; p < walks.size(); ++p) {
    const Simulated& sim = sims[2 * p];
    const Simulated& chaos = sims[2 * p + 1];
    report.simulated_seconds += sim.cpu + chaos.cpu;
    if (!sim.stable)
      std::fprintf(stderr, "bench played: path %zu: the simulation stopped at frame %zu (%s)\n", p,
                   sim.frames.size(), sim.message.c_str());
    PlayedPath& path = report.paths[p];
    const size_t compared = std::min({path.frames.size(), sim.frames.size(), chaos.frames.size()});
    path.frames.resize(compared);
    for (size_t f = 0; f < compared; ++f) {
      double sum = 0, worst = 0, chaos_sum = 0;
      const float* x = played[p].data() + f * n * 3;
      for (size_t i = 0; i < n; ++i) {
        const Eigen::Index c = static_cast<Eigen::Index>(i);
        const Vec3 s = sim.frames[f].col(c);
        const Vec3 d(double(x[3 * i]) - s.x(), double(x[3 * i + 1]) - s.y(),
                     double(x[3 * i + 2]) - s.z());
        sum += d.squaredNorm();
        worst = std::max(worst, d.norm());
        chaos_sum += (chaos.frames[f].col(c) - s).squaredNorm();
      }
      PlayedFrame& fr = path.frames[f];
      fr.rms_mm = 1e3 * std::sqrt(sum / static_cast<double>(n));
      fr.max_mm = 1e3 * worst;
      fr.chaos_rms_mm = 1e3 * std::sqrt(chaos_sum / static_cast<double>(n));
      rms_all.push_back(fr.rms_mm);
      chaos_all.push_back(fr.chaos_rms_mm);
      report.played_max_mm = std::max(report.played_max_mm, fr.max_mm);
      fallback += fr.fallback;
      blending += fr.blending;
      linked += fr.linked;
    }
  }
  for (size_t p = 0; p < walks.size(); ++p) {
    const PopsAndJitter pj =
        pops_and_jitter(played[p].data(), sims[2 * p].frames, report.paths[p].frames.size(), n);
    report.max_pop_mm = std::max(report.max_pop_mm, pj.max_pop_mm);
    report.jitter_mm = std::max(report.jitter_mm, pj.jitter_mm);
  }
  report.frames = static_cast<long>(rms_all.size());
  report.played_rms_mm_p50 = percentile(rms_all, 0.5);
  report.played_rms_mm_p95 = percentile(rms_all, 0.95);
  report.chaos_floor_rms_mm_p50 = percentile(chaos_all, 0.5);
  report.chaos_floor_rms_mm_p95 = percentile(chaos_all, 0.95);
  const double count = std::max<double>(1.0, static_cast<double>(report.frames));
  report.fallback_fraction = static_cast<double>(fallback) / count;
  report.blending_fraction = static_cast<double>(blending) / count;
  report.linked_fraction = static_cast<double>(linked) / count;
  return report;
}

PopsAndJitter pops_and_jitter(const float* played, const std::vector<Eigen::Matrix3Xd>& simulated,
                              size_t frames, size_t vertices) {
  PopsAndJitter out;
  frames = std::min(frames, simulated.size());
  auto p = [&](size_t f, size_t i) {
    const float* x = played + 3 * (f * vertices + i);
    return Vec3(double(x[0]), double(x[1]), double(x[2]));
  };
  auto s = [&](size_t f, size_t i) { return Vec3(simulated[f].col(Eigen::Index(i))); };
  auto e = [&](size_t f, size_t i) { return (p(f, i) - s(f, i)).norm(); };
  for (size_t f = 0; f + 1 < frames; ++f)
    for (size_t i = 0; i < vertices; ++i) {
      const double jump = (p(f + 1, i) - p(f, i)).norm() - (s(f + 1, i) - s(f, i)).norm();
      out.max_pop_mm = std::max(out.max_pop_mm, 1e3 * jump);
      if (f >= 1)
        out.jitter_mm =
            std::max(out.jitter_mm, 1e3 * std::abs(e(f + 1, i) - 2 * e(f, i) + e(f - 1, i)));
    }
  return out;
}

std::string played_json(const PlayedReport& r, const PlayedOptions& options,
                        const std::string& db_path) {
  nlohmann::json j = {{"database", db_path},
                      {"paths", options.paths},
                      {"seconds", options.seconds},
                      {"seed", options.seed},
                      {"perturbation_m", options.perturbation},
                      {"frames", r.frames},
                      {"played_rms_mm_p50", r.played_rms_mm_p50},
                      {"played_rms_mm_p95", r.played_rms_mm_p95},
                      {"played_max_mm", r.played_max_mm},
                      {"chaos_floor_rms_mm_p50", r.chaos_floor_rms_mm_p50},
                      {"chaos_floor_rms_mm_p95", r.chaos_floor_rms_mm_p95},
                      {"max_pop_mm", r.max_pop_mm},
                      {"jitter_mm", r.jitter_mm},
                      {"fallback_fraction", r.fallback_fraction},
                      {"blending_fraction", r.blending_fraction},
                      {"linked_fraction", r.linked_fraction},
                      {"simulation_cpu_seconds", r.simulated_seconds}};
  nlohmann::json walks = nlohmann::json::array();
  for (const PlayedPath& p : r.paths)
    walks.push_back({{"edges", p.edges},
                     {"frames", p.frames.size()},
                     {"ways_without_cloth", p.ways_without_cloth}});
  j["walks"] = walks;
  return j.dump(2) + "\n";
}

std::string played_path_csv(const PlayedPath& path) {
  std::ostringstream o;
  o << "frame,time_s,primary_clip,cloth_clip,played_rms_mm,played_max_mm,chaos_rms_mm,transition,"
       "blending,fallback,linked\n";
  char buf[256];
  for (size_t f = 0; f < path.frames.size(); ++f) {
    const PlayedFrame& fr = path.frames[f];
    std::snprintf(buf, sizeof buf, "%zu,%.4f,%lld,%lld,%.4f,%.4f,%.6f,%d,%d,%d,%d\n", f, fr.time,
                  static_cast<long long>(fr.primary_clip), static_cast<long long>(fr.cloth_clip),
                  fr.rms_mm, fr.max_mm, fr.chaos_rms_mm, fr.transition, fr.blending, fr.fallback,
                  fr.linked);
    o << buf;
  }
  return o.str();
}

std::string played_path_svg(const PlayedPath& path, const std::string& title) {
  PlotSpec spec;
  spec.title = title;
  spec.x_label = "time, s";
  spec.y_label = "RMS distance to the simulated cloth, mm";
  PlotSeries rms, chaos, transitions, blends, fallbacks;
  rms.label = "played vs simulated";
  rms.color = palette_color(0);
  rms.line = true;
  rms.markers = false;
  chaos.label = "chaos floor (1 um start)";
  chaos.color = "#555555";
  chaos.line = true;
  chaos.dashed = true;
  chaos.markers = false;
  transitions.label = "node passed";
  transitions.color = "#2ca02c";
  blends.label = "blending";
  blends.color = palette_color(1);
  fallbacks.label = "fallback";
  fallbacks.color = "#d62728";
  for (const PlayedFrame& fr : path.frames) {
    rms.x.push_back(fr.time);
    rms.y.push_back(fr.rms_mm);
    chaos.x.push_back(fr.time);
    chaos.y.push_back(fr.chaos_rms_mm);
    if (fr.transition) transitions.x.push_back(fr.time), transitions.y.push_back(0.0);
    if (fr.blending) blends.x.push_back(fr.time), blends.y.push_back(fr.rms_mm);
    if (fr.fallback) fallbacks.x.push_back(fr.time), fallbacks.y.push_back(fr.rms_mm);
  }
  spec.series = {rms, chaos, transitions, blends, fallbacks};
  return render_svg(spec);
}

}  // namespace clothdb
