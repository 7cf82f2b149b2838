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

#include "database/schema.hpp"

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

// Every key of the meta table, and what it holds. Typed accessors below read and write them.
namespace meta {
inline constexpr const char* kFormat = "format";                 // "clothdb"
inline constexpr const char* kFormatVersion = "format_version";  // schema version (integer)
inline constexpr const char* kCreated = "created";               // ISO 8601 UTC
inline constexpr const char* kUnits = "units";                   // text for people
inline constexpr const char* kCodecPositionBound = "codec.position_bound";  // m
inline constexpr const char* kCodecVelocityBound = "codec.velocity_bound";  // m/s
inline constexpr const char* kCodecKeyInterval = "codec.key_interval";
inline constexpr const char* kCodecZstdLevel = "codec.zstd_level";
inline constexpr const char* kCodecFormatVersion = "codec.format_version";
inline constexpr const char* kScene = "scene";               // the scene file's text
inline constexpr const char* kScenePath = "scene_path";      // as given to precompute
inline constexpr const char* kSceneHash = "scene_hash";      // content_hash of kScene
inline constexpr const char* kMotionGraph = "motion_graph";  // the primary graph, JSON
inline constexpr const char* kStartClip = "start_clip";      // primary clip id (integer)
inline constexpr const char* kAutoSolver = "auto_solver";    // --auto's table (Markdown)
// "1": the explorer linked every dead end when its last run ended (schema 4, ClothLink), so db
// check requires a clip or a link for every way out of every state a cloth edge leads into.
inline constexpr const char* kDeadEndsLinked = "dead_ends_linked";
// The garment's error floor on the motion graph (explore/error_floor.hpp), measured by the
// precompute before it explored: m (a number), and the measurement's detail (JSON: pairwise
// distances in mm, histories, options). An epsilon below the floor cannot link clip ends.
inline constexpr const char* kErrorFloor = "error_floor";
inline constexpr const char* kErrorFloorDetail = "error_floor_detail";
// The explorer's forecast of the CPU-hours to converge, made when its last run ended
// (precompute/explore/forecast.hpp): text as `db info` shows it after "forecast  ".
inline constexpr const char* kForecast = "forecast";
// The keys a file may hold; `db check` reports any other.
const std::vector<std::string>& known_keys();
}  // namespace meta

// Typed reads. Each returns nullopt when the key is absent and throws ClothdbError naming the file
// and key when it is there but not of its type. (The runtime, which must not throw, has
// parse_start_clip below.)
std::optional<std::string> meta_text(Reader& reader, const char* key);
std::optional<int64_t> meta_integer(Reader& reader, const char* key);
std::optional<double> meta_number(Reader& reader, const char* key);
// Typed writes (inside the caller's transaction, if any).
void set_meta_text(Writer& writer, const char* key, const std::string& value);
void set_meta_integer(Writer& writer, const char* key, int64_t value);
// Written with 17 significant digits: meta_number reads back the same double.
void set_meta_number(Writer& writer, const char* key, double value);

// meta start_clip as the runtime reads it: an id (or, from older tools, a primary clip's name).
// Returns the index into `clips` or -1 when the value names none of them.
int parse_start_clip(const std::string& value, const std::vector<PrimaryClip>& clips);

}  // namespace clothdb::db
