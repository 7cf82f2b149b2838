// The dead-end queue. A dead end is a pair (cloth state, primary edge leaving its node) with no
// clip yet. Kim et al. 2013 expand the dead end whose unresolved error is largest; this project
// weights that error by how often the game takes the edge (reach), takes dead ends in batches of
// fixed size in a total order (so the result does not depend on the thread count), and closes the
// dead ends left when a run ends with links to the nearest explored state (no runtime fallback).
#pragma once

#include <cstdint>
#include <set>
#include <utility>
#include <vector>

#include "database/format/cloth_graph.hpp"
#include "explore/secondary_graph.hpp"

namespace clothdb {

struct Job {
  int state = 0;  // index into SecondaryGraph::states
  int edge = 0;
  double priority = 0;
};

// (state id, edge) pairs whose simulation was unstable in this run: not retried by it.
using FailedDeadEnds = std::set<std::pair<int64_t, int>>;

// A dead end's priority: its unresolved error times its edge's reach (ExploreEdge::reach, 1 for
// the most taken edge; docs/SECONDARY_GRAPH.md). A node's only state (no neighbour yet) stays
// ahead of every measured error.
double weighted_priority(const ExploreGraph& graph, double error, int edge);

// Every dead end of the states with id >= min_state_id, in the explorer's total order: largest
// weighted error first, then state id, then edge.
std::vector<Job> dead_ends(const SecondaryGraph& sg, const ExploreGraph& graph,
                           int64_t min_state_id);

// The next batch: the first `size` dead ends of the queue that did not fail in this run.
std::vector<Job> choose_batch(const SecondaryGraph& sg, const FailedDeadEnds& failed,
                              const std::vector<Job>& queue, int size);

// When the budget ends, every dead end continues with the clip that the nearest state at the same
// node has along that way out; the state distance is its blend error. A way out that no state at
// the node has explored gets no link (db check reports it). Deterministic: nodes, edges and
// states in order, ties to the older state. Exact distances only where the reduced forms do not
// rule a state out (explore/state_store.hpp), so the links are the exhaustive search's.
std::vector<db::ClothLink> link_dead_ends(SecondaryGraph& sg, const ExploreGraph& graph,
                                          int64_t run_id);

}  // namespace clothdb
