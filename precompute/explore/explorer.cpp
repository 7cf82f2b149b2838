#include "explore/explorer.hpp"

#include <omp.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <sstream>

#include "character_scene/character_space.hpp"
#include "compress/recode.hpp"
#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"
#include "database/store/basis_store.hpp"
#include "explore/auto_solver.hpp"
#include "explore/primary_graph.hpp"
#include "graph/motion_graph.hpp"
#include "quality/clip_quality.hpp"
#include "report/cpu_time.hpp"
#include "report/svg_plot.hpp"

namespace clothdb {

namespace {

constexpr double kNoNeighbour = 1e9;  // priority of the first state at a node: explore first
// Strain a steered tail may add to the unsteered tail's worst edge strain (0.02: 2 % of rest
// length) before the steering is refused.
constexpr double kSteerStrainAllowance = 0.02;

// What a state looks like after a trip through the database (the codec's quantisation), so that
// every simulation starts from exactly what a resumed run would read back.
std::vector<float> roundtrip(const std::vector<float>& values, double bound) {
  codec::EncodeSettings settings;
  settings.bound = bound;
  const uint32_t n = static_cast<uint32_t>(values.size() / 3);
  const std::vector<uint8_t> blob = codec::encode(values.data(), 1, n, settings);
  std::vector<float> out;
  codec::DecodeScratch scratch;
  db::Error err;
  if (codec::decode_all(blob.data(), blob.size(), out, scratch, &err) != db::Status::Ok)
    throw std::runtime_error(std::string("codec round trip failed: ") + err.message);
  return out;
}

struct StateRec {
  int64_t id = 0;
  int node = 0;
  std::vector<float> x, v;  // character space, as stored
  // Unresolved error of its dead ends: the distance to the nearest OTHER state at its node (older
  // or newer), kept up to date as states are added there, so a dead end that a later state came
  // close to no longer counts as far from everything.
  double priority = 0;
};

struct Job {
  int state = 0;  // index into states
  int edge = 0;
  double priority = 0;
};

// Encodes as the writer would store it (the file's key interval and zstd level). With a basis,
// also as codec version 2 and keeps the smaller blob (version 2 whenever `always`).
std::vector<uint8_t> encode_with(const std::vector<float>& frames, uint32_t frame_count,
                                 uint32_t vertices, double bound, const db::CodecSettings& codec,
                                 double* max_error, const codec::Basis* basis = nullptr,
                                 const BodyAnchors* body = nullptr, bool always = false) {
  const codec::EncodeSettings settings = db::encode_settings(codec, bound);
  codec::EncodeStats stats;
  std::vector<uint8_t> blob = codec::encode(frames.data(), frame_count, vertices, settings, &stats);
  if (basis) {
    codec::EncodeStats v2_stats;
    codec::SubspaceSettings subspace;
    std::vector<float> transforms;
    if (body) {
      transforms = fit_body_frames(frames.data(), frame_count, vertices, *body);
      subspace.body_frames = transforms.data();
    }
    std::vector<uint8_t> v2 = codec::encode_v2(frames.data(), frame_count, vertices, *basis,
                                               settings, subspace, &v2_stats);
    if (always || v2.size() < blob.size()) {
      blob.swap(v2);
      stats = v2_stats;
    }
  }
  if (max_error) *max_error = stats.max_error;
  return blob;
}

// What the explorer knows between batches: the states (as stored), which dead ends have a clip,
// and which failed in this run.
struct Exploration {
  Exploration(const CharacterScene& s, const ExploreGraph& g) : scene(s), graph(g) {}
  const CharacterScene& scene;
  const ExploreGraph& graph;
  double tau = 0;
  int64_t min_state_id = 0;                 // ExploreOptions::min_state_id
  std::vector<std::vector<int>> out_edges;  // per node: edges leaving it
  std::vector<StateRec> states;
  std::vector<std::vector<int>> states_at_node;  // indices into states, per node
  long clips = 0, linked = 0;  // clip ends so far, and those that linked back within epsilon
  std::set<std::pair<int64_t, int>> done;              // (state id, edge) with a clip
  std::map<std::pair<int64_t, int>, int64_t> clip_of;  // (state id, edge) -> its cloth clip id
  std::set<std::pair<int64_t, int>> failed;            // unstable in this run: not retried
  // Codec version 2 (ExploreOptions::subspace_modes): the newest basis (null until one is built
  // or loaded), how many bases the file holds, and the ids of those this run built.
  std::shared_ptr<const codec::Basis> basis;
  int bases_in_file = 0;
  std::set<int64_t> bases_built;
};

// Kim et al. expand the dead end whose unresolved error matters most: its error times how often
// the game takes its edge (ExploreEdge::reach, 1 for the most taken edge;
// docs/SECONDARY_GRAPH.md). A node's first state (no neighbour yet) stays ahead of every measured
// error.
double weighted_priority(const Exploration& ex, double error, int edge) {
  const double reach = ex.graph.edges[edge].reach;
  return error >= kNoNeighbour ? kNoNeighbour * (1 + reach) : error * reach;
}

// Every dead end, in the explorer's total order: largest weighted error first, then state id,
// then edge.
std::vector<Job> dead_ends(const Exploration& ex) {
  std::vector<Job> jobs;
  for (size_t s = 0; s < ex.states.size(); ++s) {
    if (ex.states[s].id < ex.min_state_id) continue;
    for (int e : ex.out_edges[ex.states[s].node])
      if (!ex.done.count({ex.states[s].id, e}))
        jobs.push_back({static_cast<int>(s), e, weighted_priority(ex, ex.states[s].priority, e)});
  }
  std::sort(jobs.begin(), jobs.end(), [&](const Job& a, const Job& b) {
    if (a.priority != b.priority) return a.priority > b.priority;
    if (ex.states[a.state].id != ex.states[b.state].id)
      return ex.states[a.state].id < ex.states[b.state].id;
    return a.edge < b.edge;
  });
  return jobs;
}

// The next batch: the first `size` dead ends of the queue that did not fail in this run.
std::vector<Job> choose_batch(const Exploration& ex, const std::vector<Job>& queue, int size) {
  std::vector<Job> batch;
  for (const Job& j : queue) {
    if (static_cast<int>(batch.size()) >= size) break;
    if (ex.failed.count({ex.states[j.state].id, j.edge})) continue;
    batch.push_back(j);
  }
  return batch;
}

// Integrates a batch's results in batch order in one transaction: each clip is stored, and its
// end links to the closest state at its target node within epsilon or becomes a new state.
void integrate_batch(Exploration& ex, db::Writer& writer, const std::vector<Job>& batch,
                     const std::vector<JobResult>& results, int64_t run_id,
                     const ExploreOptions& options, ExploreReport& report) {
  const auto t0 = std::chrono::steady_clock::now();
  codec::DecodeScratch scratch;
  db::Writer::Transaction tx(writer);
  for (size_t b = 0; b < batch.size(); ++b) {
    const Job& job = batch[b];
    const JobResult& r = results[b];
    report.cpu_seconds += r.cpu_seconds;
    const int64_t start_id = ex.states[job.state].id;
    const ExploreEdge& edge = ex.graph.edges[job.edge];
    if (!r.stable) {
      ex.failed.insert({start_id, job.edge});
      std::fprintf(stderr,
                   "\nexplore: state %lld along '%s' is unstable (%s); left as a dead end\n",
                   static_cast<long long>(start_id), edge.name.c_str(), r.message.c_str());
      continue;
    }
    db::NewClothClip clip;
    clip.set_metrics(to_clip_metrics(r.quality));
    clip.start_state = start_id;
    clip.primary_clip = edge.db_clip;
    clip.first_frame = 0;
    clip.run = run_id;
    const int64_t clip_id = writer.add_cloth_clip_blob(clip, r.clip_blob, r.clip_max_error);
    {
      codec::BlobInfo info;
      db::Error info_err;
      if (codec::read_info(r.clip_blob.data(), r.clip_blob.size(), &info, &info_err) ==
              db::Status::Ok &&
          info.version == codec::kFormatVersionV2)
        ++report.clips_v2;
    }
    if (r.steer_target != 0) {
      writer.set_clip_steering(
          {clip_id, r.steer_target, r.steer_distance, r.steer_displacement, r.steer_acceleration});
      ++report.steered;
      report.worst_steering = std::max(report.worst_steering, r.steer_displacement);
    }
    ex.done.insert({start_id, job.edge});
    ex.clip_of[{start_id, job.edge}] = clip_id;
    report.frames += r.frame_count;
    report.frames_this_run += r.frame_count;
    // The end as it is stored (and as a resumed run reads it), then the closest state at the end
    // node.
    std::vector<float> end_x, end_v;
    db::Error err;
    if (codec::decode_all(r.end_x_blob.data(), r.end_x_blob.size(), end_x, scratch, &err) !=
            db::Status::Ok ||
        codec::decode_all(r.end_v_blob.data(), r.end_v_blob.size(), end_v, scratch, &err) !=
            db::Status::Ok)
      throw std::runtime_error("explore: the end state of state " + std::to_string(start_id) +
                               " along '" + edge.name + "' does not decode: " + err.message);
    double best = std::numeric_limits<double>::infinity();
    int best_state = -1;
    const std::vector<int>& here = ex.states_at_node[static_cast<size_t>(edge.to_node)];
    std::vector<double> distance(here.size());
    for (size_t k = 0; k < here.size(); ++k) {
      const StateRec& other = ex.states[static_cast<size_t>(here[k])];
      distance[k] = db::state_distance(end_x, end_v, other.x, other.v, ex.tau);
      if (distance[k] < best) best = distance[k], best_state = here[k];
    }
    ++ex.clips;
    if (best_state >= 0 && best <= options.epsilon) {
      ++ex.linked;
      writer.add_cloth_edge(
          clip_id, ex.states[best_state].id, best,
          transition_pop(r.last.data(), ex.states[best_state].x.data(), r.vertex_count));
      report.worst_blend_error = std::max(report.worst_blend_error, best);
    } else {
      StateRec rec;
      rec.node = edge.to_node;
      rec.x = std::move(end_x);
      rec.v = std::move(end_v);
      rec.priority = best_state >= 0 ? best : kNoNeighbour;
      // The states already here have a new neighbour: their dead ends' errors may fall.
      for (size_t k = 0; k < here.size(); ++k) {
        StateRec& other = ex.states[static_cast<size_t>(here[k])];
        other.priority = std::min(other.priority, distance[k]);
      }
      rec.id = writer.add_cloth_state_blobs(node_anchor_clip(ex.graph, rec.node), 0, r.end_x_blob,
                                            r.end_v_blob, run_id, clip_id);
      writer.add_cloth_edge(clip_id, rec.id, 0.0,
                            transition_pop(r.last.data(), rec.x.data(), r.vertex_count));
      ex.states_at_node[static_cast<size_t>(rec.node)].push_back(
          static_cast<int>(ex.states.size()));
      ex.states.push_back(std::move(rec));
    }
  }
  tx.commit();
  report.jobs_this_run += static_cast<long>(batch.size());
  report.integrate_seconds +=
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// When the budget ends (issue 16: no runtime fallback), every dead end (a state and a way out of
// its node with no clip) continues with the clip that the nearest state at the same node has along
// that way out; the state distance is its blend error. A way out that no state at the node has
// explored gets no link (db check reports it). Deterministic: nodes, edges and states in order,
// ties to the older state.
std::vector<db::ClothLink> link_dead_ends(const Exploration& ex, int64_t run_id) {
  std::vector<db::ClothLink> links;
  for (size_t node = 0; node < ex.states_at_node.size(); ++node) {
    const std::vector<int>& here = ex.states_at_node[node];
    for (int e : ex.out_edges[node]) {
      std::vector<int> with_clip;
      for (int s : here)
        if (ex.clip_of.count({ex.states[static_cast<size_t>(s)].id, e})) with_clip.push_back(s);
      if (with_clip.empty()) continue;
      for (int s : here) {
        const StateRec& from = ex.states[static_cast<size_t>(s)];
        if (ex.clip_of.count({from.id, e})) continue;
        double best = std::numeric_limits<double>::infinity();
        int best_state = with_clip.front();
        for (int w : with_clip) {
          const StateRec& to = ex.states[static_cast<size_t>(w)];
          const double d = db::state_distance(from.x, from.v, to.x, to.v, ex.tau);
          if (d < best) best = d, best_state = w;
        }
        db::ClothLink link;
        link.from_state = from.id;
        link.primary_clip = ex.graph.edges[static_cast<size_t>(e)].db_clip;
        link.to_clip = ex.clip_of.at({ex.states[static_cast<size_t>(best_state)].id, e});
        link.blend_error = std::isfinite(best) ? best : 1.0;
        link.run = run_id;
        links.push_back(link);
      }
    }
  }
  return links;
}

std::string bar(double fraction, int width) {
  fraction = std::clamp(fraction, 0.0, 1.0);
  const int full = static_cast<int>(fraction * width);
  return std::string(full, '#') + std::string(width - full, '.');
}

// Steered clip ends (issue 16; SceneFile::steering). The clip is simulated as usual, keeping the
// state K frames before its end. If its end is farther than epsilon from the nearest state at the
// end node, but within max_distance, the last K frames are simulated again with a pull toward
// that state, ramped in (smoothstep), applied to the velocities before each step so that the
// solver's constraints, strain limit and collisions still act on the cloth (see `pull` below), and
// what is left closed after the last step (the clip ends on the target state). The
// steered tail is kept only if it stretches no edge more than kSteerStrainAllowance beyond the
// unsteered tail; the explorer then links its end like any other (within epsilon or not).
PoseRun simulate_with_steering(const CharacterScene& scene, const ExploreGraph& graph,
                               const JobInput& input, ClothState& state, JobResult& result) {
  const ExploreEdge& edge = graph.edges[static_cast<size_t>(input.edge)];
  const size_t poses = edge.poses.size();
  const size_t k = scene.file.steering.frames > 0 && !input.targets.empty() && poses > 2
                       ? std::min(static_cast<size_t>(scene.file.steering.frames), poses - 2)
                       : 0;
  if (k == 0) {
    auto solver = make_solver(input.solver, scene.model, input.settings);
    return simulate_poses(scene, *solver, edge.poses, graph.rate, state);
  }
  const std::vector<std::vector<JointPose>> head(edge.poses.begin(),
                                                 edge.poses.end() - static_cast<long>(k)),
      tail(edge.poses.end() - static_cast<long>(k) - 1, edge.poses.end());
  auto solver = make_solver(input.solver, scene.model, input.settings);
  PoseRun run = simulate_poses(scene, *solver, head, graph.rate, state);
  if (!run.stable) return run;
  const ClothState before_tail = state;
  PoseRun rest = simulate_poses(scene, *solver, tail, graph.rate, state);
  auto append = [](PoseRun& to, PoseRun& from) {
    to.frames.insert(to.frames.end(), from.frames.begin(), from.frames.end());
    to.metrics.insert(to.metrics.end(), from.metrics.begin(), from.metrics.end());
    to.end_velocity = from.end_velocity;
    to.stable = from.stable;
    to.message = from.message;
    to.seconds += from.seconds;
    to.step_halvings += from.step_halvings;
  };
  if (!rest.stable) {
    append(run, rest);
    return run;
  }
  const Eigen::Isometry3d end_frame = character_frame(scene, edge.poses.back());
  const std::vector<float> end_x = to_character_space(state.x, end_frame, false),
                           end_v = to_character_space(state.v, end_frame, true);
  const double tau = 1.0 / graph.rate;
  double nearest = std::numeric_limits<double>::infinity();
  const SteerTarget* target = nullptr;
  for (const SteerTarget& t : input.targets) {
    const double d = db::state_distance(end_x, end_v, t.x, t.v, tau);
    if (d < nearest) nearest = d, target = &t;
  }
  if (!target || nearest <= input.epsilon || nearest > scene.file.steering.max_distance) {
    append(run, rest);
    return run;
  }
  // The unsteered tail in character space, and the end's offset to the target.
  const size_t n = end_x.size();
  std::vector<std::vector<float>> unsteered(k + 1);
  for (size_t f = 1; f <= k; ++f)
    unsteered[f] = to_character_space(rest.frames[f - 1], character_frame(scene, tail[f]), false);
  std::vector<float> offset(n);
  for (size_t i = 0; i < n; ++i) offset[i] = target->x[i] - end_x[i];
  auto ramp = [k](size_t f) {
    const double t = static_cast<double>(f) / static_cast<double>(k);
    return t * t * (3 - 2 * t);
  };
  double largest = 0;
  // Before each step to frame f, every free vertex's velocity is moved a fraction s_f of the way to
  // the velocity that would carry it to the goal G_f = U_f + s_f offset (U: the unsteered frames,
  // character space) in one frame. The step's constraints, strain limit and collisions then act on
  // the pulled cloth, so the pull cannot stretch it beyond what the solver allows. At f = K,
  // s = 1: the step aims at the target itself, and the velocities are set to the target's after
  // it (the explorer's state distance counts them).
  auto pull = [&](size_t f, ClothState& st) {
    const double s = ramp(f);
    const Eigen::Isometry3d frame = character_frame(scene, tail[f]);
    const std::vector<float> goal_local = [&] {
      std::vector<float> g(n);
      for (size_t i = 0; i < n; ++i) g[i] = static_cast<float>(unsteered[f][i] + s * offset[i]);
      return g;
    }();
    const Eigen::Matrix3Xd goal = from_character_space(goal_local, frame, false);
    for (Eigen::Index v = 0; v < st.x.cols(); ++v) {
      if (scene.model.inv_mass(v) <= 0) continue;  // pins follow the bones
      const Vec3 wanted = (goal.col(v) - st.x.col(v)) * graph.rate;
      const Vec3 dv = s * (wanted - st.v.col(v));
      largest = std::max(largest, dv.norm() / graph.rate);
      st.v.col(v) += dv;
    }
  };
  state = before_tail;
  auto fresh = make_solver(input.solver, scene.model, input.settings);
  PoseRun steered = simulate_poses(scene, *fresh, tail, graph.rate, state, pull);
  // What the velocity pull left (a few mm RMS on the test scene) is closed after the last step:
  // the free vertices are put on the target (positions and velocities), so the clip ends on it;
  // that last move counts as steering displacement too, and the strain guard below sees it.
  if (steered.stable) {
    const Eigen::Matrix3Xd target_x = from_character_space(target->x, end_frame, false);
    for (Eigen::Index v = 0; v < state.v.cols(); ++v)
      if (scene.model.inv_mass(v) > 0) {
        const size_t i = 3 * static_cast<size_t>(v);
        largest = std::max(largest, (target_x.col(v) - state.x.col(v)).norm());
        state.x.col(v) = target_x.col(v);
        state.v.col(v) =
            end_frame.linear() * Vec3(target->v[i], target->v[i + 1], target->v[i + 2]);
      }
    steered.frames.back() = state.x;
    steered.end_velocity = state.v;
    steered.metrics.back().max_strain = max_edge_strain(scene.model, state.x);
  }
  // The pull must not tear the cloth: a steered tail that stretches an edge by more than
  // kSteerStrainAllowance beyond the unsteered tail's worst is thrown away, and the clip keeps its
  // unsteered end (a new state). Measured on the demo: unguarded, transitions of 11 frames steered
  // 28 mm in 9 frames reached 45-90 % strain.
  auto worst_strain = [](const PoseRun& r) {
    double w = 0;
    for (const FrameMetrics& m : r.metrics) w = std::max(w, m.max_strain);
    return w;
  };
  if (!steered.stable || worst_strain(steered) > worst_strain(rest) + kSteerStrainAllowance) {
    state.x = rest.frames.back();
    state.v = rest.end_velocity;
    append(run, rest);
    return run;
  }
  append(run, steered);
  if (steered.stable) {
    result.steer_target = target->state;
    result.steer_distance = nearest;
    result.steer_displacement = largest;
    result.steer_acceleration = largest * graph.rate * graph.rate;
  }
  return run;
}

}  // namespace

JobResult run_job(const CharacterScene& scene, const ExploreGraph& graph, const JobInput& input) {
  if (input.edge < 0 || input.edge >= static_cast<int>(graph.edges.size()))
    throw std::runtime_error("explore: job names edge " + std::to_string(input.edge) +
                             " of a graph of " + std::to_string(graph.edges.size()));
  const ExploreEdge& edge = graph.edges[input.edge];
  const size_t per_frame = static_cast<size_t>(scene.model.vertex_count()) * 3;
  if (input.x.size() != per_frame || input.v.size() != per_frame)
    throw std::runtime_error("explore: job's start state has " +
                             std::to_string(input.x.size() / 3) +
                             " vertices, the scene's garment " + std::to_string(per_frame / 3));
  JobResult r;
  const double t0 = thread_cpu_seconds();
  const Eigen::Isometry3d frame0 = character_frame(scene, edge.poses.front());
  ClothState state;
  state.x = from_character_space(input.x, frame0, false);
  state.v = from_character_space(input.v, frame0, true);
  // Pins exactly on their bones (the stored state is within the codec bound of them).
  const Eigen::Matrix3Xd pins = skin_pins(scene.garment, scene.bind, edge.poses.front());
  for (size_t k = 0; k < scene.garment.pins.size(); ++k)
    state.x.col(scene.garment.pins[k]) = pins.col(static_cast<Eigen::Index>(k));
  PoseRun run = simulate_with_steering(scene, graph, input, state, r);
  // The budget counts simulations: measuring the quality and encoding are not in cpu_seconds.
  r.cpu_seconds = thread_cpu_seconds() - t0;
  if (!run.stable) {
    r.stable = false;
    r.message = run.message;
    return r;
  }
  std::vector<float> frames;
  frames.reserve(per_frame * edge.poses.size());
  frames.insert(frames.end(), input.x.begin(), input.x.end());
  for (size_t f = 0; f < run.frames.size(); ++f) {
    const std::vector<float> local =
        to_character_space(run.frames[f], character_frame(scene, edge.poses[f + 1]), false);
    frames.insert(frames.end(), local.begin(), local.end());
  }
  r.vertex_count = static_cast<uint32_t>(per_frame / 3);
  r.frame_count = static_cast<uint32_t>(frames.size() / per_frame);
  const std::vector<float> end_x(frames.end() - static_cast<long>(per_frame), frames.end());
  const std::vector<float> end_v =
      to_character_space(state.v, character_frame(scene, edge.poses.back()), true);
  // On a worker thread an exception would end the process: a clip that cannot be measured or
  // encoded (e.g. non-finite coordinates) is reported and left as a dead end, like an unstable one.
  try {
    r.quality = measure_clip(scene, edge.poses, frames);
    r.quality.halved_steps = run.step_halvings;
    r.clip_blob =
        encode_with(frames, r.frame_count, r.vertex_count, input.codec.position_bound, input.codec,
                    &r.clip_max_error, input.basis.get(), input.body.get(), input.subspace_always);
    r.end_x_blob =
        encode_with(end_x, 1, r.vertex_count, input.codec.position_bound, input.codec, nullptr);
    r.end_v_blob =
        encode_with(end_v, 1, r.vertex_count, input.codec.velocity_bound, input.codec, nullptr);
    // The last frame as the runtime decodes it, for the pop at the clip's cloth edge.
    r.last.resize(per_frame);
    codec::DecodeScratch scratch;
    db::Error err;
    if (codec::decode_frames(r.clip_blob.data(), r.clip_blob.size(), r.frame_count - 1, 1,
                             r.last.data(), r.last.size(), scratch, &err,
                             input.basis.get()) != db::Status::Ok)
      throw std::runtime_error(std::string("decoding a clip just encoded: ") + err.message);
  } catch (const std::exception& e) {
    JobResult failed;
    failed.stable = false;
    failed.message = e.what();
    failed.cpu_seconds = r.cpu_seconds;
    return failed;
  }
  return r;
}

std::vector<size_t> longest_first(const ExploreGraph& graph, const std::vector<JobInput>& jobs) {
  // A batch mixes 300-frame clip segments with 10-frame transitions: a long job started last would
  // leave the other threads idle.
  std::vector<size_t> order(jobs.size());
  for (size_t b = 0; b < jobs.size(); ++b) order[b] = b;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return graph.edges[jobs[a].edge].poses.size() > graph.edges[jobs[b].edge].poses.size();
  });
  return order;
}

BatchRunner openmp_runner(const CharacterScene& scene, const ExploreGraph& graph, int threads) {
  return [&scene, &graph, threads](const std::vector<JobInput>& jobs,
                                   std::vector<JobResult>& results) {
    const std::vector<size_t> order = longest_first(graph, jobs);
    // An exception must not leave an OpenMP region: keep the first and rethrow after it.
    std::exception_ptr error;
#pragma omp parallel for schedule(dynamic, 1) num_threads(std::max(1, threads))
    for (size_t k = 0; k < order.size(); ++k) {
      try {
        results[order[k]] = run_job(scene, graph, jobs[order[k]]);
      } catch (...) {
#pragma omp critical(clothdb_explore_error)
        if (!error) error = std::current_exception();
      }
    }
    if (error) std::rethrow_exception(error);
  };
}

std::vector<db::NodeEdge> node_edges(const ExploreGraph& graph) {
  std::vector<db::NodeEdge> out;
  out.reserve(graph.edges.size());
  for (const ExploreEdge& e : graph.edges) out.push_back({e.from_node, e.to_node, e.db_clip});
  return out;
}

int64_t node_anchor_clip(const ExploreGraph& graph, int node) {
  const int64_t clip = db::node_anchor_clip(node_edges(graph), node);
  if (clip == 0)
    throw std::runtime_error("explore: node " + std::to_string(node) + " has no edge leaving it");
  return clip;
}

int node_of_primary_clip(const ExploreGraph& graph, int64_t primary_clip) {
  return db::node_of_primary_clip(node_edges(graph), primary_clip);
}

ExploreGraph explore_graph(const CharacterScene& scene, const MotionGraph& graph,
                           const std::string& where) {
  return make_explore_graph(graph, scene.clips, where);
}

DatabaseScene load_database_scene(db::Reader& reader, const std::string& scene_file) {
  const std::string& path = reader.path();
  db::Error err;
  auto meta = [&](const char* key) {
    std::string value;
    if (reader.meta(key, &value, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": no meta '" + key +
                               "': not made by `clothdb precompute`, so its scene is unknown");
    return value;
  };
  const std::string scene_path = scene_file.empty() ? meta(db::meta::kScenePath) : scene_file;
  const std::string scene_hash = meta(db::meta::kSceneHash);
  if (!std::filesystem::exists(scene_path))
    throw std::runtime_error(
        path + ": its scene file " + scene_path +
        " does not exist (a relative path is relative to where `precompute` ran; "
        "give the scene file explicitly)");
  const SceneFile file = load_scene_file(scene_path);
  const std::string now = content_hash(file.text);
  if (now != scene_hash)
    throw std::runtime_error(path + ": the scene file " + scene_path +
                             " changed since this database was made (" + scene_hash + ", now " +
                             now + ")");
  DatabaseScene out{build_character_scene(file), {}};
  nlohmann::json graph_json;
  try {
    graph_json = nlohmann::json::parse(meta(db::meta::kMotionGraph));
  } catch (const nlohmann::json::parse_error& e) {
    throw std::runtime_error(path + ": meta motion_graph: not valid JSON: " + e.what());
  }
  const MotionGraph graph = motion_graph_from_json(graph_json, path + ": meta motion_graph");
  out.graph = explore_graph(out.scene, graph, path + ": meta motion_graph");
  std::vector<db::PrimaryClip> clips;
  if (reader.primary_clips(&clips, &err) != db::Status::Ok) throw std::runtime_error(err.message);
  std::map<std::string, int64_t> ids;
  for (const auto& c : clips) ids[c.name] = c.id;
  for (auto& e : out.graph.edges) {
    if (!ids.count(e.name))
      throw std::runtime_error(path + ": has no primary clip '" + e.name +
                               "' of its own motion graph");
    e.db_clip = ids[e.name];
  }
  return out;
}

void prepare_database(db::Writer& writer, const CharacterScene& scene, ExploreGraph& graph,
                      const std::string& graph_json) {
  db::Reader reader;
  db::Error err;
  if (reader.open(writer.path(), &err) != db::Status::Ok)
    throw std::runtime_error(writer.path() + ": " + std::string(err.message));
  const std::string scene_hash = content_hash(scene.file.text);
  const bool has_graph = attach_primary_graph(reader, graph, graph_json);
  check_motion_files(reader);

  db::Garment existing;
  if (reader.garment(&existing, &err) == db::Status::Ok) {
    // Resuming: the scene must be the one this database was made from.
    std::string stored;
    if (reader.meta(db::meta::kSceneHash, &stored, &err) == db::Status::Ok && stored != scene_hash)
      throw std::runtime_error(writer.path() + ": was made from a different version of " +
                               scene.file.path.string() + " (scene hash " + stored + ", now " +
                               scene_hash + "); use a new --db, or restore the scene file");
    if (existing.vertex_count() != static_cast<uint32_t>(scene.model.vertex_count()))
      throw std::runtime_error(
          writer.path() + ": garment has " + std::to_string(existing.vertex_count()) +
          " vertices, the scene makes " + std::to_string(scene.model.vertex_count()));
    if (!has_graph) throw std::runtime_error(writer.path() + ": has a garment but no motion graph");
    return;
  }
  db::Writer::Transaction tx(writer);
  if (!has_graph) {
    std::vector<std::string> files;
    for (const auto& name : scene.file.clips)
      files.push_back(scene.file.manifest.clips[scene.file.manifest.require(name)].file.string());
    write_primary_graph(writer, graph, graph_json, files);
  }
  db::Garment g;
  for (const auto& t : scene.model.mesh.triangles)
    for (int k = 0; k < 3; ++k) g.triangles.push_back(static_cast<uint32_t>(t[k]));
  const std::vector<float> rest =
      to_character_space(scene.model.mesh.rest, Eigen::Isometry3d::Identity(), false);
  g.rest_positions = rest;
  const Material& m = scene.file.material;
  char mat[256];
  std::snprintf(mat, sizeof mat,
                "{\"density\": %g, \"youngs_modulus\": %g, \"poisson\": %g, \"thickness\": %g, "
                "\"bending_stiffness\": %g, \"damping\": %g}",
                m.density, m.youngs_modulus, m.poisson, m.thickness, m.bending_rigidity(),
                m.damping);
  g.material = mat;
  g.solver = solver_settings_json(scene.file.solver, scene.file.settings);
  writer.put_garment(g);
  db::set_meta_text(writer, db::meta::kUnits,
                    "metres, seconds; cloth in character space (docs/SECONDARY_GRAPH.md)");
  db::set_meta_text(writer, db::meta::kScene, scene.file.text);
  db::set_meta_text(writer, db::meta::kScenePath, scene.file.path.string());
  db::set_meta_text(writer, db::meta::kSceneHash, scene_hash);
  tx.commit();
}

db::RunSettings make_run_settings(const CharacterScene& scene, const ExploreOptions& options,
                                  const db::CodecSettings& codec) {
  db::RunSettings run;
  run.epsilon = options.epsilon;
  run.solver = scene.file.solver;
  run.settings = scene.file.settings;
  run.codec = codec;
  run.cpu_hours = options.cpu_hours;
  run.max_frames = options.max_frames;
  run.threads = options.threads;
  run.batch = options.batch;
  run.auto_solver = options.auto_solver;
  run.resim_clip = options.resim_clip;
  run.subspace_modes = options.subspace_modes;
  run.subspace_body_frame = options.subspace_body_frame;
  db::validate_run_settings(run, "run settings");
  return run;
}

// Removes the bases explorer runs built (source "explore: ...") that no clip or state blob names,
// and returns how many. With edits in the file, only those of this run (`built`): an edit's undo
// record may hold a blob of an older basis that no row names any more.
static int remove_unchosen_bases(db::Reader& reader, db::Writer& writer,
                                 const std::set<int64_t>& built) {
  db::Error err;
  std::vector<db::BasisRow> bases;
  std::vector<db::EditLogEntry> edits;
  if (db::list_bases(reader.handle(), writer.path(), &bases, &err) != db::Status::Ok ||
      reader.edit_log(&edits, &err) != db::Status::Ok)
    throw std::runtime_error(writer.path() + ": " + std::string(err.message));
  std::set<int64_t> candidates;
  for (const db::BasisRow& b : bases)
    if (built.count(b.id) || (edits.empty() && b.source.rfind("explore: ", 0) == 0))
      candidates.insert(b.id);
  if (candidates.empty()) return 0;
  std::set<int64_t> named;
  auto name = [&](const std::vector<uint8_t>& blob) {
    codec::BlobInfo info;
    if (codec::read_info(blob.data(), blob.size(), &info, &err) == db::Status::Ok &&
        info.version == codec::kFormatVersionV2)
      named.insert(info.basis_id);
  };
  std::vector<db::ClothClip> clips;
  std::vector<db::StoredState> states;
  // A read that fails here must stop the compaction: a basis missing from `named` would be
  // deleted while blobs still name it.
  db::throw_if_error(reader.cloth_clips(&clips, &err), err);
  db::throw_if_error(reader.cloth_states(&states, &err), err);
  std::vector<uint8_t> blob, velocities;
  for (const db::ClothClip& c : clips) {
    db::throw_if_error(reader.clip_blob(c.id, &blob, &err), err);
    name(blob);
  }
  for (const db::StoredState& st : states) {
    db::throw_if_error(reader.state_blobs(st.id, &blob, &velocities, &err), err);
    name(blob);
    name(velocities);
  }
  int removed = 0;
  for (int64_t id : candidates)
    if (!named.count(id)) {
      db::remove_basis(writer, id);
      ++removed;
    }
  return removed;
}

ExploreReport explore(const CharacterScene& scene, const ExploreGraph& graph, db::Writer& writer,
                      const ExploreOptions& options, const BatchRunner& given_runner) {
  const db::RunSettings run = make_run_settings(scene, options, writer.codec());
  if (options.subspace_modes > 0 &&
      (options.subspace_first_frames < 1 || !(options.subspace_growth > 1.0) ||
       options.subspace_sample_frames < 2))
    throw std::invalid_argument(
        "explore: codec v2 needs subspace_first_frames >= 1, subspace_growth > 1 and "
        "subspace_sample_frames >= 2");
  const BatchRunner runner =
      given_runner ? given_runner : openmp_runner(scene, graph, options.threads);
  ExploreReport report;
  Exploration ex(scene, graph);
  ex.tau = 1.0 / graph.rate;
  ex.min_state_id = options.min_state_id;
  const db::CodecSettings codec_settings = writer.codec();
  const double pos_bound = codec_settings.position_bound, vel_bound = codec_settings.velocity_bound;
  ex.out_edges.resize(graph.node_count);
  std::map<int64_t, int> edge_of_clip;
  for (size_t e = 0; e < graph.edges.size(); ++e) {
    ex.out_edges[graph.edges[e].from_node].push_back(static_cast<int>(e));
    edge_of_clip[graph.edges[e].db_clip] = static_cast<int>(e);
  }
  std::vector<StateRec>& states = ex.states;

  // Load what the database holds (a resumed run), or make the rest state. Through the writer's
  // connection, so an edit that explores from a state it has just added (clip resim) sees it.
  db::Reader reader;
  db::Error err;
  if (reader.open_borrowed(writer.handle(), writer.path(), &err) != db::Status::Ok)
    throw std::runtime_error(writer.path() + ": " + std::string(err.message));
  std::vector<db::StoredState> stored_states;
  std::vector<db::ClothClip> stored_clips;
  std::vector<db::ClothEdge> stored_edges;
  // A failed read must abort the resume: with no states read it would settle again and insert a
  // second start state.
  db::throw_if_error(reader.cloth_states(&stored_states, &err), err);
  db::throw_if_error(reader.cloth_clips(&stored_clips, &err), err);
  db::throw_if_error(reader.cloth_edges(&stored_edges, &err), err);
  codec::DecodeScratch scratch;
  for (const auto& s : stored_states) {
    StateRec rec;
    rec.id = s.id;
    if (!edge_of_clip.count(s.primary_clip))
      throw std::runtime_error(writer.path() + ": state " + std::to_string(s.id) +
                               " is at an unknown primary clip");
    rec.node = graph.edges[edge_of_clip[s.primary_clip]].from_node;
    if (reader.read_state(s.id, &rec.x, &rec.v, scratch, &err) != db::Status::Ok)
      throw std::runtime_error(writer.path() + ": state " + std::to_string(s.id) + ": " +
                               std::string(err.message));
    states.push_back(std::move(rec));
  }
  for (const auto& c : stored_clips) {
    ex.done.insert({c.start_state, edge_of_clip.at(c.primary_clip)});
    ex.clip_of[{c.start_state, edge_of_clip.at(c.primary_clip)}] = c.id;
  }
  for (const auto& c : stored_clips) report.frames += c.frame_count;
  for (const auto& e : stored_edges)
    report.worst_blend_error = std::max(report.worst_blend_error, e.blend_error);
  report.resumed = !states.empty();
  // Priorities are a function of the states alone (distance to the nearest other state at the
  // same node), so a resumed run rebuilds the same queue.
  ex.states_at_node.assign(static_cast<size_t>(graph.node_count), {});
  for (size_t i = 0; i < states.size(); ++i) {
    states[i].priority = kNoNeighbour;
    ex.states_at_node[static_cast<size_t>(states[i].node)].push_back(static_cast<int>(i));
  }
  for (const std::vector<int>& here : ex.states_at_node)
    for (size_t a = 0; a < here.size(); ++a)
      for (size_t b = 0; b < a; ++b) {
        StateRec& sa = states[static_cast<size_t>(here[a])];
        StateRec& sb = states[static_cast<size_t>(here[b])];
        const double d = db::state_distance(sa.x, sa.v, sb.x, sb.v, ex.tau);
        sa.priority = std::min(sa.priority, d);
        sb.priority = std::min(sb.priority, d);
      }
  // Clip ends that linked back: an edge into a state its own clip did not make.
  {
    std::map<int64_t, int64_t> made_by;
    for (const auto& st : stored_states) made_by[st.id] = st.source_clip;
    ex.clips = static_cast<long>(stored_edges.size());
    for (const auto& e : stored_edges) ex.linked += made_by[e.to_state] != e.from_clip;
  }
  const uint32_t vertex_count = static_cast<uint32_t>(scene.model.vertex_count());
  std::shared_ptr<const BodyAnchors> body;
  if (options.subspace_modes > 0 && options.subspace_body_frame) {
    // From the file's garment row, as `db recode` takes them.
    db::Garment garment;
    if (reader.garment(&garment, &err) != db::Status::Ok)
      throw std::runtime_error(writer.path() + ": " + std::string(err.message));
    body = std::make_shared<const BodyAnchors>(body_anchors(garment.rest_positions));
  }
  if (options.subspace_modes > 0) {
    // A resumed run continues from the file's newest basis.
    std::vector<db::BasisRow> bases;
    if (db::list_bases(reader.handle(), writer.path(), &bases, &err) != db::Status::Ok)
      throw std::runtime_error(writer.path() + ": " + std::string(err.message));
    ex.bases_in_file = static_cast<int>(bases.size());
    if (!bases.empty()) {
      auto newest = std::make_shared<codec::Basis>();
      if (db::load_basis(reader.handle(), writer.path(), bases.back().id, newest.get(), &err) !=
          db::Status::Ok)
        throw std::runtime_error(writer.path() + ": " + std::string(err.message));
      if (newest->vertex_count == vertex_count) ex.basis = std::move(newest);
    }
  }
  // Codec version 2: after a batch, a new basis when the stored frames have reached
  // first_frames x growth^(bases in the file) (ExploreOptions::subspace_modes).
  auto maybe_build_basis = [&]() {
    if (options.subspace_modes == 0) return;
    const double due = static_cast<double>(options.subspace_first_frames) *
                       std::pow(options.subspace_growth, ex.bases_in_file);
    if (static_cast<double>(report.frames) < due) return;
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<db::ClothClip> clips;
    if (reader.cloth_clips(&clips, &err) != db::Status::Ok)
      throw std::runtime_error(writer.path() + ": " + std::string(err.message));
    BuiltBasis built = build_basis_from_clips(reader, clips, vertex_count, options.subspace_modes,
                                              options.subspace_sample_frames, body.get());
    built.basis.id = db::store_basis(writer, built.basis, "explore: " + built.source);
    ex.bases_built.insert(built.basis.id);
    ++ex.bases_in_file;
    ++report.bases_built;
    if (options.progress)
      std::fprintf(stderr, "\nexplore: basis %lld of %u modes from %llu stored frames in %.1f s\n",
                   static_cast<long long>(built.basis.id), built.basis.mode_count,
                   static_cast<unsigned long long>(built.frames),
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    ex.basis = std::make_shared<const codec::Basis>(std::move(built.basis));
  };

  const int64_t run_id = writer.begin_run(db::run_settings_json(run));
  if (states.empty()) {
    SolverSettings settings = scene.file.settings;
    auto solver = make_solver(scene.file.solver, scene.model, settings);
    const ExploreEdge& first = graph.edges[ex.out_edges[graph.start_node].front()];
    const ClothState rest = settle_garment(scene, *solver, first.poses.front());
    const Eigen::Isometry3d frame = character_frame(scene, first.poses.front());
    // The writer stores encode(raw); keeping roundtrip(raw) in memory is exactly what a resumed
    // run decodes (re-encoding an already decoded state could round differently).
    const std::vector<float> raw_x = to_character_space(rest.x, frame, false),
                             raw_v = to_character_space(rest.v, frame, true);
    StateRec rec;
    rec.node = graph.start_node;
    rec.x = roundtrip(raw_x, pos_bound);
    rec.v = roundtrip(raw_v, vel_bound);
    rec.priority = kNoNeighbour;
    ex.states_at_node[static_cast<size_t>(rec.node)].push_back(0);
    rec.id = writer.add_cloth_state(node_anchor_clip(ex.graph, rec.node), 0, raw_x.data(),
                                    raw_v.data(), static_cast<uint32_t>(raw_x.size() / 3), run_id);
    states.push_back(std::move(rec));
  }

  auto curve_point = [&](const std::vector<Job>& queue) {
    CurvePoint p;
    p.cpu_seconds = report.cpu_seconds;
    p.frames = report.frames;
    p.states = static_cast<int>(states.size());
    p.dead_ends = static_cast<int>(queue.size());
    double sum = 0;
    int counted = 0;
    for (const Job& j : queue) {
      // The very first state at a node has no neighbour: its error is the whole unknown; it is
      // explored first and counted as 0 here (nothing to compare it with yet).
      const double error = states[j.state].priority;  // metres
      const double e = error >= kNoNeighbour ? 0.0 : error;
      p.worst_error = std::max(p.worst_error, e);
      p.weighted_worst_error = std::max(p.weighted_worst_error, e * graph.edges[j.edge].reach);
      sum += e;
      ++counted;
    }
    p.mean_error = counted ? sum / counted : 0.0;
    p.linked_fraction = ex.clips ? static_cast<double>(ex.linked) / ex.clips : 0.0;
    return p;
  };

  const auto wall_start = std::chrono::steady_clock::now();
  std::vector<Job> queue = dead_ends(ex);
  report.curve.push_back(curve_point(queue));
  while (true) {
    const std::vector<Job> batch = choose_batch(ex, queue, options.batch);
    if (batch.empty()) break;
    if (options.cpu_hours > 0 && report.cpu_seconds >= options.cpu_hours * 3600) break;
    if (options.max_frames > 0 && report.frames_this_run >= options.max_frames) break;

    std::vector<JobInput> inputs(batch.size());
    for (size_t b = 0; b < batch.size(); ++b) {
      inputs[b].edge = batch[b].edge;
      inputs[b].x = states[batch[b].state].x;
      inputs[b].v = states[batch[b].state].v;
      inputs[b].solver = scene.file.solver;
      inputs[b].settings = scene.file.settings;
      inputs[b].settings.threads =
          1;  // parallel across jobs, not inside one (a runner may change it)
      inputs[b].codec = codec_settings;
      inputs[b].basis = ex.basis;
      inputs[b].body = ex.basis ? body : nullptr;
      inputs[b].subspace_always = options.subspace_always;
      inputs[b].epsilon = options.epsilon;
      if (scene.file.steering.frames > 0)
        for (int t : ex.states_at_node[static_cast<size_t>(graph.edges[batch[b].edge].to_node)])
          inputs[b].targets.push_back({states[static_cast<size_t>(t)].id,
                                       states[static_cast<size_t>(t)].x,
                                       states[static_cast<size_t>(t)].v});
    }
    std::vector<JobResult> results(batch.size());
    runner(inputs, results);
    integrate_batch(ex, writer, batch, results, run_id, options, report);
    maybe_build_basis();

    queue = dead_ends(ex);
    report.curve.push_back(curve_point(queue));
    if (options.progress) {
      const CurvePoint& p = report.curve.back();
      const size_t done = ex.done.size();
      double fraction = 0, eta = 0;
      const double wall =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
      if (options.max_frames > 0)
        fraction = static_cast<double>(report.frames_this_run) / options.max_frames;
      if (options.cpu_hours > 0)
        fraction = std::max(fraction, report.cpu_seconds / (options.cpu_hours * 3600));
      if (fraction > 0) {
        eta = wall / fraction * (1 - fraction);
      } else {
        // No budget: at least the dead ends left at the current pace (new ones may appear).
        const double per_job = wall / std::max<size_t>(1, done);
        fraction = static_cast<double>(done) / (done + queue.size());
        eta = per_job * queue.size();
      }
      std::fprintf(
          stderr,
          "\r[%s] frames %ld  states %d  dead ends %d  worst %.1f mm  cpu %.0f s  ETA %s%.0f s   ",
          bar(fraction, 24).c_str(), report.frames, p.states, p.dead_ends, 1e3 * p.worst_error,
          report.cpu_seconds, options.max_frames > 0 || options.cpu_hours > 0 ? "" : ">=", eta);
    }
  }
  if (options.progress) std::fprintf(stderr, "\n");
  const std::vector<db::ClothLink> links = link_dead_ends(ex, run_id);
  writer.replace_cloth_links(links);
  db::set_meta_text(writer, db::meta::kDeadEndsLinked, "1");
  // A basis no blob chose (version 1 was smaller every time) costs bytes and the runtime's memory
  // for nothing. Only once the exploration has converged: until then a resumed run must find
  // every basis an uninterrupted one would have, to choose as it would.
  if (options.subspace_modes > 0 && queue.empty())
    report.bases_removed = remove_unchosen_bases(reader, writer, ex.bases_built);
  report.links = static_cast<int>(links.size());
  for (const db::ClothLink& l : links) {
    report.worst_link_error = std::max(report.worst_link_error, l.blend_error);
    report.mean_link_error += l.blend_error / static_cast<double>(links.size());
  }
  const CurvePoint& last = report.curve.back();
  char notes[384];
  std::snprintf(
      notes, sizeof notes,
      "%s; unresolved error worst %.2f mm, reach-weighted worst %.2f mm; %.1f %% of "
      "clip ends linked within epsilon; %d dead ends linked to the nearest state (blend error "
      "mean %.2f mm, worst %.2f mm)",
      queue.empty() ? "converged" : (std::to_string(queue.size()) + " dead ends left").c_str(),
      1e3 * last.worst_error, 1e3 * last.weighted_worst_error, 100 * last.linked_fraction,
      report.links, 1e3 * report.mean_link_error, 1e3 * report.worst_link_error);
  writer.finish_run(run_id, report.cpu_seconds, notes);
  if (report.bases_removed > 0) {
    // The removed bases' pages (a few MB each) would otherwise stay in the file as free pages.
    reader.close();
    std::string why;
    if (!db::compact_file(writer, &why))
      std::fprintf(stderr, "explore: %s: not compacted after removing unused bases: %s\n",
                   writer.path().c_str(), why.c_str());
  }
  report.states = static_cast<int>(states.size());
  report.clips = static_cast<int>(ex.done.size());
  report.dead_ends = static_cast<int>(queue.size());
  report.edges = report.clips;
  report.worst_error = report.curve.back().worst_error;
  report.weighted_worst_error = report.curve.back().weighted_worst_error;
  report.linked_fraction = report.curve.back().linked_fraction;
  report.converged = queue.empty();
  return report;
}

std::string curve_csv(const std::vector<CurvePoint>& curve) {
  std::ostringstream o;
  o << "cpu_seconds,frames,states,dead_ends,worst_error_mm,weighted_worst_error_mm,mean_error_mm,"
       "linked_percent\n";
  for (const auto& p : curve)
    o << p.cpu_seconds << ',' << p.frames << ',' << p.states << ',' << p.dead_ends << ','
      << 1e3 * p.worst_error << ',' << 1e3 * p.weighted_worst_error << ',' << 1e3 * p.mean_error
      << ',' << 100 * p.linked_fraction << '\n';
  return o.str();
}

std::string curve_svg(const std::vector<CurvePoint>& curve, double epsilon) {
  PlotSpec spec;
  spec.title = "Unresolved error against CPU time";
  spec.x_label = "CPU seconds";
  spec.y_label = "unresolved error, mm";
  PlotSeries worst, weighted, mean, eps;
  weighted.label = "worst x reach (how often the game takes the edge)";
  weighted.color = palette_color(2);
  weighted.line = true;
  worst.label = "worst";
  worst.color = palette_color(1);
  worst.line = true;
  mean.label = "mean";
  mean.color = palette_color(0);
  mean.line = true;
  eps.label = "epsilon";
  eps.color = "#333333";
  eps.line = true;
  eps.markers = false;
  eps.dashed = true;
  for (const auto& p : curve) {
    worst.x.push_back(p.cpu_seconds);
    worst.y.push_back(1e3 * p.worst_error);
    weighted.x.push_back(p.cpu_seconds);
    weighted.y.push_back(1e3 * p.weighted_worst_error);
    mean.x.push_back(p.cpu_seconds);
    mean.y.push_back(1e3 * p.mean_error);
  }
  if (!curve.empty()) {
    eps.x = {curve.front().cpu_seconds, curve.back().cpu_seconds};
    eps.y = {1e3 * epsilon, 1e3 * epsilon};
  }
  spec.series = {worst, weighted, mean, eps};
  return render_svg(spec);
}

}  // namespace clothdb
