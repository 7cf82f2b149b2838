#include "explore/secondary_graph.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "character_scene/character_space.hpp"
#include "database/codec/codec.hpp"
#include "database/format/cloth_graph.hpp"

namespace clothdb {

SecondaryGraph empty_secondary_graph(const ExploreGraph& graph, uint32_t vertices,
                                     db::Reader& reader, size_t cache_bytes) {
  SecondaryGraph sg;
  sg.tau = 1.0 / graph.rate;
  sg.out_edges.resize(static_cast<size_t>(graph.node_count));
  for (size_t e = 0; e < graph.edges.size(); ++e)
    sg.out_edges[static_cast<size_t>(graph.edges[e].from_node)].push_back(static_cast<int>(e));
  sg.states_at_node.assign(static_cast<size_t>(graph.node_count), {});
  sg.reducer = make_reducer(vertices, sg.tau);
  db::Reader* from = &reader;
  // One scratch for every read (the cache calls this under its lock): a decoder context is
  // costly to make, more than decoding a small state.
  auto scratch = std::make_shared<codec::DecodeScratch>();
  sg.exact = std::make_shared<StateCache>(
      cache_bytes,
      [from, vertices, scratch](int64_t id) {
        ExactState s;
        db::Error err;
        if (from->read_state(id, &s.x, &s.v, *scratch, &err) != db::Status::Ok)
          throw std::runtime_error(from->path() + ": reading cloth state " + std::to_string(id) +
                                   " back: " + std::string(err.message));
        if (s.x.size() != 3 * size_t(vertices) || s.v.size() != s.x.size())
          throw std::runtime_error(from->path() + ": cloth state " + std::to_string(id) + " has " +
                                   std::to_string(s.x.size() / 3) + " vertices, the garment " +
                                   std::to_string(vertices));
        return s;
      },
      [from](int64_t id) {
        StateBlobs b;
        db::Error err;
        if (from->state_blobs(id, &b.x, &b.v, &err) != db::Status::Ok)
          throw std::runtime_error(from->path() + ": reading cloth state " + std::to_string(id) +
                                   "'s blobs: " + std::string(err.message));
        return b;
      });
  return sg;
}

size_t bytes_per_state(const SecondaryGraph& sg) {
  return sizeof(StateRec) + sg.reducer.size() * sizeof(double) + sizeof(int) +
         sg.motion_modes * sizeof(double);
}

SecondaryGraph load_secondary_graph(db::Reader& reader, const std::string& path,
                                    const ExploreGraph& graph, uint32_t vertices,
                                    size_t cache_bytes, long* frames, double* worst_blend_error) {
  SecondaryGraph sg = empty_secondary_graph(graph, vertices, reader, cache_bytes);
  std::map<int64_t, int> edge_of_clip;
  for (size_t e = 0; e < graph.edges.size(); ++e)
    edge_of_clip[graph.edges[e].db_clip] = static_cast<int>(e);
  db::Error err;
  auto check = [&](db::Status status, const char* table) {
    if (status != db::Status::Ok)
      throw std::runtime_error(path + ": reading " + table +
                               " to resume: " + std::string(err.message));
  };
  std::vector<db::StoredState> stored_states;
  std::vector<db::ClothClip> stored_clips;
  std::vector<db::ClothEdge> stored_edges;
  check(reader.cloth_states(&stored_states, &err), "cloth_state");
  check(reader.cloth_clips(&stored_clips, &err), "cloth_clip");
  check(reader.cloth_edges(&stored_edges, &err), "cloth_edge");
  // Ids in the order they were added, as an uninterrupted run added them.
  std::sort(stored_states.begin(), stored_states.end(),
            [](const db::StoredState& a, const db::StoredState& b) { return a.id < b.id; });
  codec::DecodeScratch scratch;
  // Priorities are a function of the states alone (distance to the nearest other state at the
  // same node), so a resumed run rebuilds the same queue. Each state is added as the run added it
  // (nearest_state, then add_state): the minimum over the same distances, but measured only where
  // the reduced forms allow, instead of every pair of states at a node.
  for (const auto& s : stored_states) {
    StateRec rec;
    rec.id = s.id;
    if (!edge_of_clip.count(s.primary_clip))
      throw std::runtime_error(path + ": state " + std::to_string(s.id) +
                               " is at an unknown primary clip");
    rec.node = graph.edges[static_cast<size_t>(edge_of_clip[s.primary_clip])].from_node;
    ExactState exact;
    if (reader.read_state(s.id, &exact.x, &exact.v, scratch, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": state " + std::to_string(s.id) + ": " +
                               std::string(err.message));
    if (exact.x.size() != 3 * size_t(vertices) || exact.v.size() != exact.x.size())
      throw std::runtime_error(path + ": state " + std::to_string(s.id) + " has " +
                               std::to_string(exact.x.size() / 3) + " vertices, the garment " +
                               std::to_string(vertices));
    const Nearest nearest = nearest_state(sg, rec.node, exact.x, exact.v);
    add_state(sg, std::move(rec), std::move(exact), nearest);
  }
  for (const auto& c : stored_clips) {
    const auto edge = edge_of_clip.find(c.primary_clip);
    if (edge == edge_of_clip.end())
      throw std::runtime_error(path + ": cloth clip " + std::to_string(c.id) +
                               " follows a primary clip that is not an edge of the motion graph");
    record_clip(sg, c.start_state, edge->second, c.id);
    *frames += c.frame_count;
  }
  for (const auto& e : stored_edges)
    *worst_blend_error = std::max(*worst_blend_error, e.blend_error);
  // Clip ends that linked back: an edge into a state its own clip did not make.
  std::map<int64_t, int64_t> made_by;
  for (const auto& st : stored_states) made_by[st.id] = st.source_clip;
  sg.clips = static_cast<long>(stored_edges.size());
  for (const auto& e : stored_edges) sg.linked += made_by[e.to_state] != e.from_clip;
  return sg;
}

namespace {

// The coarse form: the projection of the reduced form onto fields constant over the whole garment
// (6 doubles: mean position and tau x mean velocity, in the distance's normalisation). A
// projection of a projection, so its distance is at most the reduced distance.
std::array<double, 6> coarse_form(const StateReducer& reducer, const std::vector<double>& reduced) {
  std::array<double, 6> c{};
  for (size_t b = 0; b + 1 < reducer.block_start.size(); ++b) {
    const double w =
        std::sqrt(double(reducer.block_start[b + 1] - reducer.block_start[b]) / reducer.vertices);
    for (size_t i = 0; i < 6; ++i) c[i] += w * reduced[6 * b + i];
  }
  return c;
}

double coarse_distance(const std::array<double, 6>& a, const std::array<double, 6>& b) {
  return reduced_distance(a.data(), b.data(), 6);
}

// db::state_distance (database/format/cloth_graph.cpp: the same sum in the same order, so the same
// double), or +infinity as soon as the partial sum proves the distance exceeds `limit`: the terms
// are not negative, so a partial sum above limit^2 x vertices (with a 1e-9 relative margin for
// the rounding of the division and the root) only grows. Checked every 32 vertices.
double distance_within(const std::vector<float>& xa, const std::vector<float>& va,
                       const std::vector<float>& xb, const std::vector<float>& vb, double tau,
                       double limit) {
  if (!std::isfinite(limit) || xa.size() != xb.size() || va.size() != xa.size() ||
      vb.size() != xa.size() || xa.size() % 3 != 0)
    return db::state_distance(xa, va, xb, vb, tau);
  const size_t vertices = xa.size() / 3, n = 3 * vertices;
  const double cap = limit * limit * double(vertices) * (1 + 1e-9);
  double sum = 0;
  for (size_t i = 0; i < n; ++i) {
    const double dx = double(xa[i]) - double(xb[i]), dv = double(va[i]) - double(vb[i]);
    sum += dx * dx + tau * tau * dv * dv;
    if (i % 96 == 95 && sum > cap) return std::numeric_limits<double>::infinity();
  }
  return vertices ? std::sqrt(sum / double(vertices)) : 0.0;
}

// The state distance from (x, v) to states[index]; +infinity when it exceeds `limit` (finite
// limits only when sg.early_exit).
double exact_distance(SecondaryGraph& sg, const std::vector<float>& x, const std::vector<float>& v,
                      int index, double limit = std::numeric_limits<double>::infinity()) {
  const ExactStatePtr other = sg.state(index);
  ++sg.exact_evaluations;
  if (!sg.early_exit) limit = std::numeric_limits<double>::infinity();
  return distance_within(x, v, other->x, other->v, sg.tau, limit);
}

// A new motion basis from kMotionSample states spread evenly over those (in the order added) at
// nodes of kMotionNode states or more, then those states' coefficients in it. The states are read
// one at a time (the cache's bound holds); the sample is copied as doubles while the basis is
// built.
void rebuild_motion_basis(SecondaryGraph& sg) {
  std::vector<int> candidates;
  for (size_t i = 0; i < sg.states.size(); ++i)
    if (sg.states_at_node[size_t(sg.states[i].node)].size() >= kMotionNode)
      candidates.push_back(int(i));
  if (candidates.size() < 2) return;
  const size_t take = std::min(kMotionSample, candidates.size());
  std::vector<ExactState> sample;
  std::vector<int> group;
  for (size_t j = 0; j < take; ++j) {
    const int i = candidates[j * candidates.size() / take];
    sample.push_back(*sg.state(i));
    group.push_back(sg.states[size_t(i)].node);
  }
  std::vector<const ExactState*> pointers;
  for (const ExactState& e : sample) pointers.push_back(&e);
  sg.basis = build_motion_basis(sg.reducer, pointers, group, sg.motion_modes);
  sample.clear();
  ++sg.basis_generation;
  for (size_t i = 0; i < sg.states.size(); ++i) {
    if (sg.states_at_node[size_t(sg.states[i].node)].size() < kMotionNode) continue;
    const ExactStatePtr e = sg.state(int(i));
    sg.states[i].motion = project(sg.basis, e->x.data(), e->v.data());
  }
}

}  // namespace

Nearest nearest_state(SecondaryGraph& sg, int node, const std::vector<float>& x,
                      const std::vector<float>& v) {
  Nearest out;
  out.reduced = reduce(sg.reducer, x.data(), v.data());
  const std::vector<int>& here = sg.states_at_node[static_cast<size_t>(node)];
  const size_t n = sg.reducer.size();
  out.distances.assign(here.size(), std::numeric_limits<double>::quiet_NaN());
  out.above.assign(here.size(), 0.0);
  double best = std::numeric_limits<double>::infinity();
  // Coarse to fine: candidates come in order of the coarse bound (a heap, popped only as far as
  // needed); one whose coarse bound exceeds the best distance measured so far ends the search
  // (every later one's does too), one whose fine bound (the reduced form) exceeds it is skipped,
  // the rest are measured, stopping early beyond the best and their own priority. A candidate is
  // left out only when its distance provably exceeds the best so far, so the answer (ties to the
  // lower position, the older state) is the exhaustive search's.
  out.coarse = coarse_form(sg.reducer, out.reduced);
  std::vector<std::pair<double, size_t>> order(here.size());
  if (here.size() >= kMotionNode) out.motion = project(sg.basis, x.data(), v.data());
  out.basis_generation = sg.basis_generation;
  const auto fine = [&](size_t k) {
    const StateRec& s = sg.states[static_cast<size_t>(here[k])];
    return motion_bound(sg.basis, reduced_distance(out.reduced.data(), s.reduced.data(), n),
                        out.motion, s.motion);
  };
  for (size_t k = 0; k < here.size(); ++k)
    order[k] = {
        sg.coarse_first
            ? motion_bound(sg.basis, coarse_distance(out.coarse, sg.states[size_t(here[k])].coarse),
                           out.motion, sg.states[size_t(here[k])].motion)
            : fine(k),
        k};
  const auto later = [](const std::pair<double, size_t>& a, const std::pair<double, size_t>& b) {
    return a > b;  // a min-heap: the smallest bound, then the lowest position, first
  };
  std::make_heap(order.begin(), order.end(), later);
  int best_k = -1;
  double best_d = std::numeric_limits<double>::infinity();
  for (auto end = order.end(); end != order.begin(); --end) {
    std::pop_heap(order.begin(), end, later);
    const auto [bound, k] = *(end - 1);
    if (bound_exceeds(bound, best)) break;
    const StateRec& s = sg.states[static_cast<size_t>(here[k])];
    if (sg.coarse_first && bound_exceeds(fine(k), best)) continue;
    // Farther than the best so far cannot be the answer (nor tie it), and farther than the
    // state's priority cannot lower it when the query becomes a state (add_state): stopped early
    // beyond both, and add_state knows it is beyond them.
    const double limit = std::max(best, s.priority);
    const double d = exact_distance(sg, x, v, here[k], limit);
    if (std::isinf(d)) {
      out.above[k] = limit;
      continue;
    }
    out.distances[k] = d;
    best = std::min(best, d);
    if (best_k < 0 || d < best_d || (d == best_d && int(k) < best_k)) best_d = d, best_k = int(k);
  }
  if (best_k >= 0) {
    out.state = here[static_cast<size_t>(best_k)];
    out.distance = best_d;
  }
  return out;
}

int add_state(SecondaryGraph& sg, StateRec rec, ExactState exact, const Nearest& nearest) {
  rec.priority = nearest.state >= 0 ? nearest.distance : kNoNeighbour;
  rec.reduced = nearest.reduced.empty() ? reduce(sg.reducer, exact.x.data(), exact.v.data())
                                        : nearest.reduced;
  rec.coarse = coarse_form(sg.reducer, rec.reduced);
  std::vector<int>& here = sg.states_at_node[static_cast<size_t>(rec.node)];
  if (here.size() + 1 >= kMotionNode)
    rec.motion = nearest.basis_generation == sg.basis_generation && !nearest.motion.c.empty()
                     ? nearest.motion
                     : project(sg.basis, exact.x.data(), exact.v.data());
  if (here.size() + 1 == kMotionNode)  // the node is now large enough: its states projected
    for (int i : here) {
      const ExactStatePtr e = sg.state(i);
      sg.states[size_t(i)].motion = project(sg.basis, e->x.data(), e->v.data());
    }
  const size_t n = sg.reducer.size();
  for (size_t j = 0; j < here.size(); ++j) {
    StateRec& other = sg.states[static_cast<size_t>(here[j])];
    if (j < nearest.distances.size() && !std::isnan(nearest.distances[j])) {
      other.priority = std::min(other.priority, nearest.distances[j]);  // measured by the query
      continue;
    }
    // Its priority can only fall to the new distance, which is at least the bounds: skipped when
    // they already exceed it.
    // Stopped early by the query beyond its priority: the distance cannot lower it.
    if (j < nearest.above.size() && nearest.above[j] > 0 && nearest.above[j] >= other.priority)
      continue;
    if (sg.coarse_first &&
        bound_exceeds(motion_bound(sg.basis, coarse_distance(rec.coarse, other.coarse), rec.motion,
                                   other.motion),
                      other.priority))
      continue;
    if (bound_exceeds(
            motion_bound(sg.basis, reduced_distance(rec.reduced.data(), other.reduced.data(), n),
                         rec.motion, other.motion),
            other.priority))
      continue;
    // Only a distance below its priority changes it: stopped early above that.
    other.priority =
        std::min(other.priority, exact_distance(sg, exact.x, exact.v, here[j], other.priority));
  }
  const int index = static_cast<int>(sg.states.size());
  here.push_back(index);
  sg.exact->put(rec.id, std::move(exact));
  sg.states.push_back(std::move(rec));
  if (here.size() >= kMotionNode)
    sg.large_node_states += here.size() == kMotionNode ? here.size() : 1;
  if (sg.motion_modes > 0 && sg.large_node_states >= sg.next_basis_at) {
    rebuild_motion_basis(sg);
    sg.next_basis_at *= 4;
  }
  return index;
}

void record_clip(SecondaryGraph& sg, int64_t state_id, int edge, int64_t clip_id) {
  sg.done.insert({state_id, edge});
  sg.clip_of[{state_id, edge}] = clip_id;
}

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

void add_start_state(const CharacterScene& scene, const ExploreGraph& graph, db::Writer& writer,
                     int64_t run_id, SecondaryGraph& sg) {
  SolverSettings settings = scene.file.settings;
  auto solver = make_scene_solver(scene, scene.file.solver, settings);
  const ExploreEdge& first =
      graph.edges[static_cast<size_t>(sg.out_edges[static_cast<size_t>(graph.start_node)].front())];
  const ClothState rest = settle_garment(scene, *solver, first.poses.front());
  const Eigen::Isometry3d frame = character_frame(scene, first.poses.front());
  // The writer stores encode(raw); keeping roundtrip(raw) in memory is exactly what a resumed
  // run decodes (re-encoding an already decoded state could round differently).
  const std::vector<float> raw_x = to_character_space(rest.x, frame, false),
                           raw_v = to_character_space(rest.v, frame, true);
  const db::CodecSettings codec = writer.codec();
  StateRec rec;
  rec.node = graph.start_node;
  ExactState exact;
  exact.x = roundtrip(raw_x, codec.position_bound);
  exact.v = roundtrip(raw_v, codec.velocity_bound);
  rec.id = writer.add_cloth_state(node_anchor_clip(graph, rec.node), 0, raw_x.data(), raw_v.data(),
                                  static_cast<uint32_t>(raw_x.size() / 3), run_id);
  add_state(sg, std::move(rec), std::move(exact), Nearest{});
}

}  // namespace clothdb
