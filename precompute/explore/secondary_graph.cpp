#include "explore/secondary_graph.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>

#include "character_scene/character_space.hpp"
#include "database/format/cloth_graph.hpp"
#include "database/codec/codec.hpp"

namespace clothdb {

SecondaryGraph empty_secondary_graph(const ExploreGraph& graph) {
  SecondaryGraph sg;
  sg.tau = 1.0 / graph.rate;
  sg.out_edges.resize(static_cast<size_t>(graph.node_count));
  for (size_t e = 0; e < graph.edges.size(); ++e)
    sg.out_edges[static_cast<size_t>(graph.edges[e].from_node)].push_back(static_cast<int>(e));
  sg.states_at_node.assign(static_cast<size_t>(graph.node_count), {});
  return sg;
}

SecondaryGraph load_secondary_graph(db::Reader& reader, const std::string& path,
                                    const ExploreGraph& graph, long* frames,
                                    double* worst_blend_error) {
  SecondaryGraph sg = empty_secondary_graph(graph);
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
  codec::DecodeScratch scratch;
  for (const auto& s : stored_states) {
    StateRec rec;
    rec.id = s.id;
    if (!edge_of_clip.count(s.primary_clip))
      throw std::runtime_error(path + ": state " + std::to_string(s.id) +
                               " is at an unknown primary clip");
    rec.node = graph.edges[static_cast<size_t>(edge_of_clip[s.primary_clip])].from_node;
    if (reader.read_state(s.id, &rec.x, &rec.v, scratch, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": state " + std::to_string(s.id) + ": " +
                               std::string(err.message));
    sg.states.push_back(std::move(rec));
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
  // Priorities are a function of the states alone (distance to the nearest other state at the
  // same node), so a resumed run rebuilds the same queue.
  std::vector<StateRec>& states = sg.states;
  for (size_t i = 0; i < states.size(); ++i) {
    states[i].priority = kNoNeighbour;
    sg.states_at_node[static_cast<size_t>(states[i].node)].push_back(static_cast<int>(i));
  }
  for (const std::vector<int>& here : sg.states_at_node)
    for (size_t a = 0; a < here.size(); ++a)
      for (size_t b = 0; b < a; ++b) {
        StateRec& sa = states[static_cast<size_t>(here[a])];
        StateRec& sb = states[static_cast<size_t>(here[b])];
        const double d = db::state_distance(sa.x, sa.v, sb.x, sb.v, sg.tau);
        sa.priority = std::min(sa.priority, d);
        sb.priority = std::min(sb.priority, d);
      }
  // Clip ends that linked back: an edge into a state its own clip did not make.
  std::map<int64_t, int64_t> made_by;
  for (const auto& st : stored_states) made_by[st.id] = st.source_clip;
  sg.clips = static_cast<long>(stored_edges.size());
  for (const auto& e : stored_edges) sg.linked += made_by[e.to_state] != e.from_clip;
  return sg;
}

Nearest nearest_state(const SecondaryGraph& sg, int node, const std::vector<float>& x,
                      const std::vector<float>& v) {
  Nearest out;
  double best = std::numeric_limits<double>::infinity();
  const std::vector<int>& here = sg.states_at_node[static_cast<size_t>(node)];
  out.distances.resize(here.size());
  for (size_t k = 0; k < here.size(); ++k) {
    const StateRec& other = sg.states[static_cast<size_t>(here[k])];
    out.distances[k] = db::state_distance(x, v, other.x, other.v, sg.tau);
    if (out.distances[k] < best) best = out.distances[k], out.state = here[k];
  }
  out.distance = best;
  return out;
}

int add_state(SecondaryGraph& sg, StateRec rec, const Nearest& nearest) {
  rec.priority = nearest.state >= 0 ? nearest.distance : kNoNeighbour;
  std::vector<int>& here = sg.states_at_node[static_cast<size_t>(rec.node)];
  for (size_t k = 0; k < here.size(); ++k) {
    StateRec& other = sg.states[static_cast<size_t>(here[k])];
    other.priority = std::min(other.priority, nearest.distances[k]);
  }
  const int index = static_cast<int>(sg.states.size());
  here.push_back(index);
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
  rec.x = roundtrip(raw_x, codec.position_bound);
  rec.v = roundtrip(raw_v, codec.velocity_bound);
  rec.id = writer.add_cloth_state(node_anchor_clip(graph, rec.node), 0, raw_x.data(), raw_v.data(),
                                  static_cast<uint32_t>(raw_x.size() / 3), run_id);
  add_state(sg, std::move(rec), Nearest{});
}

}  // namespace clothdb
