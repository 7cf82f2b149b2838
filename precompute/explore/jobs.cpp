#include "explore/jobs.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "character_scene/character_space.hpp"
#include "compress/body_frame.hpp"
#include "database/codec/codec.hpp"
#include "report/cpu_time.hpp"

namespace clothdb {

namespace {

// Strain a steered tail may add to the unsteered tail's worst edge strain (0.02: 2 % of rest
// length) before the steering is refused.
constexpr double kSteerStrainAllowance = 0.02;

// Encodes as the writer would store it (the file's key interval and zstd level). With a basis,
// also as codec version 2 (version 3 within `contract` when its jitter cap is positive, its
// figures then in *figures) and keeps the smaller blob (the subspace one whenever `always`).
std::vector<uint8_t> encode_with(const std::vector<float>& frames, uint32_t frame_count,
                                 uint32_t vertices, double bound, const db::CodecSettings& codec,
                                 double* max_error, const codec::Basis* basis = nullptr,
                                 const BodyAnchors* body = nullptr, bool always = false,
                                 const codec::Contract& contract = {},
                                 codec::ContractFigures* figures = nullptr,
                                 bool* has_contract = nullptr) {
  const codec::EncodeSettings settings = db::encode_settings(codec, bound);
  codec::EncodeStats stats;
  std::vector<uint8_t> blob = codec::encode(frames.data(), frame_count, vertices, settings, &stats);
  if (has_contract) *has_contract = false;
  if (basis && contract.jitter > 0) {
    codec::V3Settings v3;
    v3.contract = contract;
    v3.zstd_level = settings.zstd_level;
    codec::V3Stats v3_stats;
    std::vector<uint8_t> coded =
        codec::encode_v3(frames.data(), frame_count, vertices, *basis, v3, &v3_stats);
    if (always || coded.size() < blob.size()) {
      blob.swap(coded);
      // A coordinate's error is at most its vertex's distance.
      stats.max_error = v3_stats.figures.max;
      if (figures) *figures = v3_stats.figures;
      if (has_contract) *has_contract = true;
    }
  } else if (basis) {
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

// Steered clip ends (docs/GUIDE.md#the-precompute-kim-et-al-2013; SceneFile::steering). The clip is
// simulated as usual, keeping the state K frames before its end. If its end is farther than epsilon
// from the nearest state at the end node, but within max_distance, the last K frames are simulated
// again with a pull toward that state, ramped in (smoothstep), applied to the velocities before
// each step so that the solver's constraints, strain limit and collisions still act on the cloth
// (see `pull` below), and what is left closed after the last step (the clip ends on the target
// state). The steered tail is kept only if it stretches no edge more than kSteerStrainAllowance
// beyond the unsteered tail; the explorer then links its end like any other (within epsilon or
// not).
PoseRun simulate_with_steering(const CharacterScene& scene, const ExploreGraph& graph,
                               const JobInput& input, ClothState& state, JobResult& result) {
  const ExploreEdge& edge = graph.edges[static_cast<size_t>(input.edge)];
  const size_t poses = edge.poses.size();
  const bool has_targets =
      !input.targets.empty() || (input.target_source && !input.target_source->ids.empty());
  const size_t k = scene.file.steering.frames > 0 && has_targets && poses > 2
                       ? std::min(static_cast<size_t>(scene.file.steering.frames), poses - 2)
                       : 0;
  if (k == 0) {
    auto solver = make_scene_solver(scene, input.solver, input.settings);
    return simulate_poses(scene, *solver, edge.poses, graph.rate, state);
  }
  const std::vector<std::vector<JointPose>> head(edge.poses.begin(),
                                                 edge.poses.end() - static_cast<long>(k)),
      tail(edge.poses.end() - static_cast<long>(k) - 1, edge.poses.end());
  auto solver = make_scene_solver(scene, input.solver, input.settings);
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
  SteerTarget read;  // a target read on demand
  if (input.target_source) {
    // The exhaustive search's answer, measuring only targets the reduced forms leave near.
    const SteerTargetSource& source = *input.target_source;
    const std::vector<double> q = reduce(source.reducer, end_x.data(), end_v.data());
    const PrunedNearest found = nearest_pruned(
        source.ids.size(),
        [&](size_t t) { return reduced_distance(q.data(), source.reduced[t].data(), q.size()); },
        [&](size_t t) {
          const ExactStatePtr s = source.exact->get(source.ids[t]);
          return db::state_distance(end_x, end_v, s->x, s->v, tau);
        });
    if (found.k >= 0) {
      const ExactStatePtr s = source.exact->get(source.ids[static_cast<size_t>(found.k)]);
      read = {source.ids[static_cast<size_t>(found.k)], s->x, s->v};
      nearest = found.distance;
      target = &read;
    }
  }
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
  auto fresh = make_scene_solver(scene, input.solver, input.settings);
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
    r.clip_blob = encode_with(frames, r.frame_count, r.vertex_count, input.codec.position_bound,
                              input.codec, &r.clip_max_error, input.basis.get(), input.body.get(),
                              input.subspace_always, input.contract, &r.contract, &r.has_contract);
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
std::vector<JobInput> job_inputs(const CharacterScene& scene, const ExploreGraph& graph,
                                 const SecondaryGraph& sg, const std::vector<Job>& batch,
                                 const ExploreOptions& options, const db::CodecSettings& codec,
                                 const std::shared_ptr<const codec::Basis>& basis,
                                 const std::shared_ptr<const BodyAnchors>& body) {
  std::vector<JobInput> inputs(batch.size());
  // One target source per end node, shared by the batch's jobs that end there.
  std::map<int, std::shared_ptr<const SteerTargetSource>> sources;
  for (size_t b = 0; b < batch.size(); ++b) {
    const ExactStatePtr start = sg.state(batch[b].state);
    inputs[b].edge = batch[b].edge;
    inputs[b].x = start->x;
    inputs[b].v = start->v;
    inputs[b].state = sg.states[static_cast<size_t>(batch[b].state)].id;
    inputs[b].store = sg.exact;
    inputs[b].solver = scene.file.solver;
    inputs[b].settings = scene.file.settings;
    inputs[b].settings.threads =
        1;  // parallel across jobs, not inside one (a runner may change it)
    inputs[b].codec = codec;
    inputs[b].basis = basis;
    inputs[b].body = basis ? body : nullptr;
    inputs[b].subspace_always = options.subspace_always;
    inputs[b].contract = options.subspace_contract;
    inputs[b].epsilon = options.epsilon;
    if (scene.file.steering.frames > 0) {
      const int end_node = graph.edges[static_cast<size_t>(batch[b].edge)].to_node;
      std::shared_ptr<const SteerTargetSource>& source = sources[end_node];
      if (!source) {
        auto made = std::make_shared<SteerTargetSource>();
        made->reducer = sg.reducer;
        made->exact = sg.exact;
        for (int t : sg.states_at_node[static_cast<size_t>(end_node)]) {
          made->ids.push_back(sg.states[static_cast<size_t>(t)].id);
          made->reduced.push_back(sg.states[static_cast<size_t>(t)].reduced);
        }
        source = std::move(made);
      }
      inputs[b].target_source = source;
    }
  }
  return inputs;
}

}  // namespace clothdb
