// What a clothdb file's secondary cloth graph means: the one definition of each rule that the
// explorer (which writes it), the runtime (which plays it), the edit tools and `db check` (which
// change and verify it) must agree on. docs/SECONDARY_GRAPH.md explains them.
//
// Plain C++ over the database's own rows (no Eigen, no JSON): both sides include it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "database/format/meta_keys.hpp"
#include "database/format/reader.hpp"
#include "database/format/rows.hpp"

namespace clothdb::db {

// The state distance of Kim et al. 2013 that epsilon bounds (docs/SECONDARY_GRAPH.md): RMS over
// vertices of sqrt(|dx|^2 + (tau |dv|)^2), in metres, with tau = one frame (1 / rate) so that a
// velocity difference counts as the displacement it makes in one frame. Differences are taken in
// double precision. `vertices` vertices of 3 floats in each array.
double state_distance(const float* xa, const float* va, const float* xb, const float* vb,
                      size_t vertices, double tau);
// The same over whole states; throws std::invalid_argument when the four sizes differ or are not
// multiples of 3 (two states of different garments have no distance).
double state_distance(const std::vector<float>& xa, const std::vector<float>& va,
                      const std::vector<float>& xb, const std::vector<float>& vb, double tau);

// An edge of the primary motion graph as the cloth graph sees it: the primary clip it plays
// (primary_clip.id) between two nodes.
struct NodeEdge {
  int from_node = 0, to_node = 0;
  int64_t primary_clip = 0;
};

// The node-anchor rule: a cloth state at `node` is stored under the primary clip of the FIRST
// edge (in graph order) leaving the node, at frame 0. Returns 0 when no edge leaves the node.
int64_t node_anchor_clip(const std::vector<NodeEdge>& edges, int node);
// The node a stored state is at, from the primary clip it is stored under (-1 if no edge of the
// graph plays that clip).
int node_of_primary_clip(const std::vector<NodeEdge>& edges, int64_t primary_clip);
// The start-clip rule: every path begins on the first edge leaving the start node (the explorer
// settles the garment at its first pose); stored as meta start_clip.
inline int64_t start_clip(const std::vector<NodeEdge>& edges, int start_node) {
  return node_anchor_clip(edges, start_node);
}
// The start state: the oldest (lowest id) state at the start node; 0 when there is none.
int64_t start_state(const std::vector<StoredState>& states, const std::vector<NodeEdge>& edges,
                    int start_node);

// Typed reads of meta keys (database/format/meta_keys.hpp). Each returns nullopt when the key is
// absent and throws ClothdbError naming the file and key when it is there but not of its type. (The
// runtime, which must not throw, has parse_start_clip below.)
std::optional<std::string> meta_text(Reader& reader, const char* key);
std::optional<int64_t> meta_integer(Reader& reader, const char* key);
std::optional<double> meta_number(Reader& reader, const char* key);

// meta start_clip as the runtime reads it: an id (or, from older tools, a primary clip's name).
// Returns the index into `clips` or -1 when the value names none of them.
int parse_start_clip(const std::string& value, const std::vector<PrimaryClip>& clips);

}  // namespace clothdb::db
