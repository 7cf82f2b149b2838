// Pictures of a motion graph: a built-in SVG drawing that needs nothing installed, and Graphviz
// DOT for those who have Graphviz (rendered to SVG by `dot` when it is on PATH).
#pragma once

#include <string>

#include "graph/motion_graph.hpp"

namespace clothdb {

// One horizontal lane per clip with x = frame (the same scale for every clip), the clip's full
// extent in light grey, the clip edges kept as arrows along the lane, transitions as curves
// (between lanes, or arcs above the lane going forward in the clip and below going back), nodes as
// dots with tooltips. The title gives the node, edge, transition and clip counts.
std::string motion_graph_svg(const MotionGraph& graph);

// The graph in Graphviz's DOT language: one cluster per clip, clip edges solid, transitions
// dashed and labelled with their distance; the graph label carries the counts.
std::string motion_graph_dot(const MotionGraph& graph);

// Whether an executable `dot` is on PATH.
bool graphviz_available();

// Renders DOT text to an SVG file with Graphviz (`dot -Tsvg`), atomically; throws GraphError
// naming the file when Graphviz is missing or fails.
void render_dot_svg(const std::string& dot, const std::string& svg_path);

}  // namespace clothdb
