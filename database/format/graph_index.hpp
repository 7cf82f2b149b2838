// The primary and cloth graphs of a file as one index over its rows, with the rules every reader
// of the graph shares (docs/SECONDARY_GRAPH.md), each written once:
// - nodes: the classes of primary clip ends joined by transitions (union-find over two endpoints
//   per primary clip; Kovar et al. 2002's graph, whose nodes are implicit in the rows);
// - completeness: at a node every clip in continues with every clip out;
// - a cloth clip spans its whole primary clip from a state at the primary clip's source node;
// - an edge lands at a state at its clip's end node (the closest, if a clip has several);
// - a link continues a state's dead end with a clip along the same primary clip at its node.
// The runtime builds its player index from it and stops at the first broken rule; `db check`
// collects them all. Plain C++ over the rows: no SQLite here beyond GraphRows::read.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <unordered_map>
#include <vector>

#include "database/format/reader.hpp"
#include "database/format/rows.hpp"

namespace clothdb::db {

// The rows the index is built from.
struct GraphRows {
  std::vector<PrimaryClip> primary_clips;
  std::vector<PrimaryTransition> transitions;
  std::vector<StoredState> states;
  std::vector<ClothClip> clips;
  std::vector<ClothEdge> edges;
  std::vector<ClothLink> links;  // empty before schema 4

  [[nodiscard]] Status read(Reader& reader, Error* err);
};

// A broken rule: which kind of row ("primary clip", "primary transition", "cloth clip", "cloth
// edge", "cloth link") and what is wrong with it.
struct GraphFinding {
  const char* kind;
  std::string message;
  // The row names a row that does not exist (what SQLite's foreign key check also finds).
  bool dangling = false;
};
// Receives each finding; returns true to go on, false to stop building.
using GraphFindingSink = std::function<bool(const GraphFinding&)>;

struct GraphIndex {
  struct Primary {
    int64_t id = 0;
    int32_t frames = 0;
    double rate = 0;
    int src_node = -1, tgt_node = -1;
    std::vector<int> successors;  // primary indices that continue it, sorted, unique
  };
  struct State {
    int64_t id = 0;
    int primary = -1;  // the primary clip index it is stored under (node-anchor rule)
    int node = -1;
  };
  struct Clip {
    int64_t id = 0;
    int state = -1, primary = -1;
    int32_t frames = 0;
    int to_state = -1;       // where its edge leads (-1: no edge)
    double blend_error = 0;  // of that edge (non-finite stored errors read as 1 m)
  };
  struct Link {
    int64_t id = 0;
    int state = -1, primary = -1, clip = -1;
    double blend_error = 0;
  };

  std::vector<Primary> primaries;
  int nodes = 0;
  std::vector<std::vector<int>> leaving, entering;  // node -> primary indices
  std::vector<State> states;
  std::vector<Clip> clips;
  std::vector<Link> links;
  std::unordered_map<int64_t, int> primary_by_id, state_by_id, clip_by_id;

  // Builds the index from the rows (indices follow the rows' order). Rows that break a rule are
  // reported to `sink` and left out of the index. Returns false when the sink stopped the build;
  // the index is then incomplete and must not be used.
  bool build(const GraphRows& rows, const GraphFindingSink& sink);
};

}  // namespace clothdb::db
