// The secondary graph as the explorer holds it between batches (Kim et al. 2013, section 4): the
// cloth states at each node of the primary graph, which (state, way out) pairs have a clip, and
// Kim et al.'s query, the nearest state at a node. Memory is bounded (explore/state_store.hpp): a
// state is held as a reduced form, and its exact positions and velocities (as decoded from the
// file, so a resumed run measures the same distances) are read back through an LRU cache.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "database/store/writer.hpp"
#include "explore/explorer.hpp"
#include "explore/state_store.hpp"

namespace clothdb {

// Priority of a node's only state (no other state to measure it against): ahead of every measured
// error. It is not a distance: the curve counts such ways out as unexplored.
inline constexpr double kNoNeighbour = 1e9;

// The motion basis: its modes, the state count that builds the first one (then x4), and the
// states its sample holds (docs/notebook/explorer.md, "The motion basis").
inline constexpr size_t kMotionModes = 16;
inline constexpr size_t kFirstMotionBasis = 128;
inline constexpr size_t kMotionSample = 48;
// States a node holds before its states are projected (a projection costs about as much as a
// few state distances; at a node of a few states the reduced forms suffice).
inline constexpr size_t kMotionNode = 32;

struct StateRec {
  int64_t id = 0;
  int node = 0;
  std::vector<double> reduced;  // reduce(): a lower bound of the state distance to any other
  // Unresolved error of its dead ends: the distance to the nearest OTHER state at its node (older
  // or newer), kept up to date as states are added there, so a dead end that a later state came
  // close to no longer counts as far from everything. kNoNeighbour while it is alone.
  double priority = 0;
  // The reduced form's projection onto fields constant over the garment (mean position, tau x
  // mean velocity): a coarser lower bound, 6 doubles, that the search scans first.
  std::array<double, 6> coarse{};
  // Its coefficients in the garment's motion basis (SecondaryGraph::basis; empty while there is
  // none): with `reduced`, a much tighter lower bound (motion_bound).
  Projection motion;
};

struct SecondaryGraph {
  double tau = 0;                           // s, the state distance's velocity weight (1 / rate)
  std::vector<std::vector<int>> out_edges;  // per node: edges leaving it
  std::vector<StateRec> states;
  std::vector<std::vector<int>> states_at_node;  // indices into states, per node
  // Stop a state distance as soon as its partial sum proves it exceeds what it is compared with
  // (the best so far, a priority). false only for `clothdb bench nearest`: the answers are the
  // same.
  bool early_exit = true;
  // Order the candidates by the coarse form's bound (6 doubles, a heap) and compute the fine one
  // only for those popped; false (as before: every candidate's fine bound, then in its order)
  // only for `clothdb bench nearest`.
  bool coarse_first = true;
  // The motion basis (explore/state_store.hpp): built from a sample of the states at nodes of
  // kMotionNode states or more, in the order they were added, when their count reaches
  // kFirstMotionBasis (128), then 512, 2048, ... (x4), and those states projected again then; so a
  // resume, adding the same states in the same order, builds the same bases. motion_modes = 0 (only
  // `clothdb bench nearest`) never builds one: the answers are the same.
  size_t motion_modes = kMotionModes;
  MotionBasis basis;
  long basis_generation = 0;  // bases built so far
  size_t next_basis_at = kFirstMotionBasis;
  size_t large_node_states = 0;  // states at nodes of kMotionNode states or more
  long clips = 0, linked = 0;    // clip ends so far, and those that linked back within epsilon
  std::set<std::pair<int64_t, int>> done;              // (state id, edge) with a clip
  std::map<std::pair<int64_t, int>, int64_t> clip_of;  // (state id, edge) -> its cloth clip id
  StateReducer reducer;
  std::shared_ptr<StateCache> exact;  // exact states by id, read from the file when not cached
  long exact_evaluations = 0;         // state distances measured (the pruning's effect)
  // The exact state (x, v) of states[index].
  ExactStatePtr state(int index) const { return exact->get(states[size_t(index)].id); }
};

// Bytes the store holds per state besides the cache: the StateRec, its reduced form and its index
// at its node (the figure docs/notebook/explorer.md documents; set/map entries of its clips come
// on top).
size_t bytes_per_state(const SecondaryGraph& sg);

// The graph's nodes and ways out, with no state yet, for a garment of `vertices` vertices; exact
// states are read through `reader` (which must outlive the graph) and cached up to cache_bytes.
SecondaryGraph empty_secondary_graph(const ExploreGraph& graph, uint32_t vertices,
                                     db::Reader& reader, size_t cache_bytes);

// What the file at `reader` holds (a resumed run; nothing for a new file), with every state's
// priority. Adds the stored clips' frames to *frames and takes the worst stored blend error into
// *worst_blend_error. Throws std::runtime_error naming `path` and the table when a read fails: a
// run that went on would settle again, or explore states twice.
SecondaryGraph load_secondary_graph(db::Reader& reader, const std::string& path,
                                    const ExploreGraph& graph, uint32_t vertices,
                                    size_t cache_bytes, long* frames, double* worst_blend_error);

// Kim et al.'s query: the state at `node` nearest to (x, v) in the state distance
// (db::state_distance), ties to the one added first. state: -1 when the node has none. Exact
// distances are measured only for states whose reduced form does not rule them out, so the
// answer is the exhaustive search's.
struct Nearest {
  int state = -1;  // index into states
  double distance = 0;
  std::vector<double> reduced;     // the query's reduced form
  std::array<double, 6> coarse{};  // the query's coarse form
  Projection motion;               // the query's coefficients in the basis of basis_generation
  long basis_generation = 0;
  // To each of states_at_node[node] whose distance was stopped early (as soon as it exceeded both
  // the best so far and the state's priority): the larger of the two, a lower bound of its
  // distance; 0 elsewhere.
  std::vector<double> above;
  // To each of states_at_node[node], in order: the state distance where it was measured, NaN
  // where the reduced forms ruled the state out (add_state reuses what was measured).
  std::vector<double> distances;
};
Nearest nearest_state(SecondaryGraph& sg, int node, const std::vector<float>& x,
                      const std::vector<float>& v);

// Adds a state (id already given by the file) at rec.node, with its exact form (x, v) as stored;
// `nearest` is nearest_state's answer for it. Its priority is its distance to that state, and the
// states already there have a new neighbour: their dead ends' errors may fall (measured only
// where the reduced forms allow it). Returns its index.
int add_state(SecondaryGraph& sg, StateRec rec, ExactState exact, const Nearest& nearest);

// A clip now leaves state `state_id` along `edge`.
void record_clip(SecondaryGraph& sg, int64_t state_id, int edge, int64_t clip_id);

// What a state looks like after a trip through the database (the codec's quantisation), so that
// every simulation starts from exactly what a resumed run would read back.
std::vector<float> roundtrip(const std::vector<float>& values, double bound);

// The first state of a new file: the garment settled at the start node's first edge's first pose,
// stored (in the caller's run) and added.
void add_start_state(const CharacterScene& scene, const ExploreGraph& graph, db::Writer& writer,
                     int64_t run_id, SecondaryGraph& sg);

}  // namespace clothdb
