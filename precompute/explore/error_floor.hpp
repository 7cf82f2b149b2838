// The error floor of a garment on a motion (docs/GUIDE.md#choosing-epsilon-the-error-floor): how
// far apart cloth states stay that reach the SAME node of the primary graph by DIFFERENT histories.
// The explorer links a clip's end to a state at its node only when their state distance is at most
// epsilon; if the garment has many resting shapes for one pose (a strongly flared skirt with soft
// bending buckles into one of many stable fold patterns), the states at a node stay this far apart
// however long the exploration runs, and an epsilon below it never links: every clip makes a new
// state.
//
// The measurement, before exploring (seconds on a small garment, about a CPU-minute on the demo's
// 3,000-vertex skirt):
//   1. the garment settled at the start node (the explorer's start state);
//   2. K histories: weighted random walks through the graph (ExploreEdge::weight) that take
//      different first edges where the walk first has a choice (history k takes the k-th way out,
//      modulo their number), walk on for history_seconds, then go by the shortest way (in frames)
//      to a common node, the one nearest to all of them;
//   3. the SAME continuation from that node for every history (a seeded random walk of whole
//      edges, at least continuation_seconds): the distances after it are the "walked" distances;
//   4. the continuation's last pose held still for hold_seconds: the "held" distances.
// When no two different walks can meet (every node on the way has one way out, or no node is
// reachable from all), the histories are the garment settled at different frames of the start
// edge instead (held still there), each walked along the rest of it to its end node; the result
// says so (ErrorFloor::fallback, ErrorFloor::note).
//
// Distances are db::state_distance (the explorer's one definition) in character space. Histories
// run in parallel (OpenMP), each with its own single-threaded solver from the same start state,
// so the result does not depend on the thread count. The part of the walk all histories share
// (up to their first choice) is simulated once.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

struct ErrorFloorOptions {
  int histories = 4;                  // K, in [2, 64]
  double history_seconds = 1.0;       // s walked at random after the first choice
  double continuation_seconds = 2.0;  // s of the common continuation (whole edges: at least this)
  double hold_seconds = 2.0;          // s of the last pose held still
  uint64_t seed = 1;                  // of the random walks
  int threads = 0;                    // OpenMP threads across histories (0: all cores)
  bool progress = false;              // one line per history on stderr
};

struct ErrorFloor {
  // m: the median of the pairwise walked distances. Why the median of "walked": a clip end is a
  // state that arrived along an edge, so what a clip end can approach is a state that reached the
  // same node by another walk, not one held still; the median (not the max) because the explorer
  // links to the NEAREST state of many, so one unlucky pair must not set the bound. An epsilon
  // below it cannot link: the clip ends stay apart by about this much.
  double floor = 0;
  double walked_max = 0;   // m
  double held_median = 0;  // m, after holding the last pose still
  double held_max = 0;     // m
  double met_median = 0;   // m, on arrival at the common node (before the continuation)
  double met_max = 0;      // m
  // m: the median over histories of the walked distance to the nearest OTHER history. Not the
  // floor: with few histories it mostly says whether they fell into a few shared shapes (close
  // pairs) or each into its own; shown next to the floor.
  double nearest_median = 0;
  // m: halfway through the continuation (at its first node at least half of it along). A floor
  // well below it means the histories were still converging while walking: the floor then holds
  // part of the transient of a garment that forgets its history slowly, and a longer continuation
  // would measure it lower (still_falling()).
  double halfway_median = 0;
  // Pairwise distances, m, in the order (0,1), (0,2), ..., (1,2), ...
  std::vector<double> met, halfway, walked, held;
  // What was simulated.
  std::vector<std::vector<int>> history_edges;  // per history: edges (ExploreGraph indices)
  std::vector<int> start_frames;  // per history: frame of the start edge settled at (fallback)
  std::vector<int> continuation_edges;
  int common_node = 0;
  int continuation_frames = 0, hold_frames = 0;
  bool fallback = false;   // the histories differ by their start frame, not by their walk
  std::string note;        // why the fallback was taken ("" otherwise)
  long frames = 0;         // solver steps taken, the shared part counted once
  double cpu_seconds = 0;  // thread CPU time of the simulations

  int histories() const { return static_cast<int>(history_edges.size()); }
  // The walked distance fell by more than a fifth over the second half of the continuation.
  bool still_falling() const { return floor < 0.8 * halfway_median; }
};

// Throws std::invalid_argument naming the option when one is out of range, std::runtime_error
// when the graph has nothing to walk or a simulation is unstable (naming the history and edge).
ErrorFloor measure_error_floor(const CharacterScene& scene, const ExploreGraph& graph,
                               const ErrorFloorOptions& options);

// "12.3 mm (median of 6 pairwise distances, 4 histories meeting at node 7; held still: 11.8 mm,
// largest 14.0 mm)".
std::string error_floor_summary(const ErrorFloor& floor);

// The smallest epsilon worth exploring with: 1.5 x the floor, rounded up to a whole mm (at least
// 1 mm), in m. The 1.5 leaves room for the spread of the pairwise distances around their median.
double suggested_epsilon(double floor);

// The measurement as JSON: the distances (mm), the histories and continuation by edge name, the
// options. with_timing: include the CPU seconds (not in the database's meta, which must be the
// same whoever measured it).
std::string error_floor_json(const ErrorFloor& floor, const ExploreGraph& graph,
                             const ErrorFloorOptions& options, bool with_timing);

}  // namespace clothdb
