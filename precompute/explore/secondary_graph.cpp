#include "explore/secondary_graph.hpp"

#include <algorithm>
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
  sg.exact = std::make_shared<StateCache>(cache_bytes, [from, vertices, scratch](int64_t id) {
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
  });
  return sg;
}

size_t bytes_per_state(const SecondaryGraph& sg) {
  return sizeof(StateRec) + sg.reducer.size() * sizeof(double) + sizeof(int);
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

Nearest nearest_state(SecondaryGraph& sg, int node, const std::vector<float>& x,
                      const std::vector<float>& v) {
  Nearest out;
  out.reduced = reduce(sg.reducer, x.data(), v.data());
  const std::vector<int>& here = sg.states_at_node[static_cast<size_t>(node)];
  const size_t n = sg.reducer.size();
  out.distances.assign(here.size(), std::numeric_limits<double>::quiet_NaN());
  const PrunedNearest found = nearest_pruned(
      here.size(),
      [&](size_t k) {
        return reduced_distance(out.reduced.data(),
                                sg.states[static_cast<size_t>(here[k])].reduced.data(), n);
      },
      [&](size_t k) {
        const ExactStatePtr other = sg.state(here[k]);
        return out.distances[k] = db::state_distance(x, v, other->x, other->v, sg.tau);
      });
  sg.exact_evaluations += found.exact_evaluations;
  if (found.k >= 0) {
    out.state = here[static_cast<size_t>(found.k)];
    out.distance = found.distance;
  }
  return out;
}

int add_state(SecondaryGraph& sg, StateRec rec, ExactState exact, const Nearest& nearest) {
  rec.priority = nearest.state >= 0 ? nearest.distance : kNoNeighbour;
  rec.reduced = nearest.reduced.empty() ? reduce(sg.reducer, exact.x.data(), exact.v.data())
                                        : nearest.reduced;
  std::vector<int>& here = sg.states_at_node[static_cast<size_t>(rec.node)];
  const size_t n = sg.reducer.size();
  for (size_t j = 0; j < here.size(); ++j) {
    StateRec& other = sg.states[static_cast<size_t>(here[j])];
    if (j < nearest.distances.size() && !std::isnan(nearest.distances[j])) {
      other.priority = std::min(other.priority, nearest.distances[j]);  // measured by the query
      continue;
    }
    // Its priority can only fall to the new distance, which is at least the bound: skipped when
    // the bound already exceeds it.
    if (bound_exceeds(reduced_distance(rec.reduced.data(), other.reduced.data(), n),
                      other.priority))
      continue;
    const ExactStatePtr o = sg.state(here[j]);
    ++sg.exact_evaluations;
    other.priority =
        std::min(other.priority, db::state_distance(exact.x, exact.v, o->x, o->v, sg.tau));
  }
  const int index = static_cast<int>(sg.states.size());
  here.push_back(index);
  sg.exact->put(rec.id, std::move(exact));
  sg.states.push_back(std::move(rec));
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
  auto solver = make_solver(scene.file.solver, scene.model, settings);
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
