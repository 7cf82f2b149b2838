// The primary motion graph as the explorer and the database see it (docs/SECONDARY_GRAPH.md,
// "Primary graph"): every motion-graph edge becomes one primary clip with its poses, and the graph
// goes into the database once, either from `clothdb graph build --db` or from the first
// `clothdb precompute`; later runs must use the same graph.
#pragma once

#include <string>
#include <vector>

#include "database/store/writer.hpp"
#include "explore/explorer.hpp"
#include "graph/motion_graph.hpp"

namespace clothdb {

// The explorer's view of `graph`: one ExploreEdge per graph edge (in graph order) with its poses
// (edge_poses) and its reach (edge_reach); the start node is the first edge's source. `clips`
// must be the graph's clips, in its order (checked by name; `where` names the graph in errors).
ExploreGraph make_explore_graph(const MotionGraph& graph, const std::vector<MotionClip>& clips,
                                const std::string& where);

// "xxh64:<16 hex digits>" of bytes, and of a file's content (throws naming the file).
std::string content_hash(const std::string& bytes);
std::string file_content_hash(const std::string& path);

// Writes the primary graph into the database in one transaction: the motion files (with their
// content hashes), one primary clip per edge, the implicit nodes as primary transitions, meta
// `motion_graph` (graph_json) and `start_clip`. Sets every edge's db_clip.
void write_primary_graph(db::Writer& writer, ExploreGraph& graph, const std::string& graph_json,
                         const std::vector<std::string>& motion_files);

// The motion graph JSON text a database holds (meta `motion_graph`), empty if none.
std::string stored_motion_graph(db::Reader& reader);

// If the database holds a primary graph: checks that it is `graph_json` (as JSON values; throws a
// message naming the database and what to do otherwise) and that its primary clips are the
// edges, sets every edge's db_clip and returns true. Returns false when it holds none.
bool attach_primary_graph(db::Reader& reader, ExploreGraph& graph, const std::string& graph_json);

// Throws if a motion file recorded in the database changed since (its content hash differs):
// `files` are where the scene's manifest points now, in the recorded order; a recorded file
// without one is checked at its recorded path.
void check_motion_files(db::Reader& reader, const std::vector<std::string>& files);

}  // namespace clothdb
