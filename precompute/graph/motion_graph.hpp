// The primary motion graph (Kovar, Gleicher and Pighin 2002, "Motion Graphs"; used as the primary
// graph of Kim et al. 2013): transition points between clips are found automatically from a
// distance between short windows of poses, transitions blend the two clips over a few frames, and
// the graph is pruned to its largest strongly connected component so that a character walking it
// never reaches a dead end.
//
// Terms. A clip is a MotionClip (per-frame joint world positions and orientations). A transition
// (A, i) -> (B, j) puts frame i of A in correspondence with frame j of B: its motion blends
// A[i + p] with B[j + p] (aligned in the floor plane) for p = 0 .. blend, so it leaves A at frame i
// and arrives in B at frame j + blend, where B's own motion continues. Nodes are points (clip,
// frame) where transitions leave or arrive, plus clip starts and ends before pruning; edges are
// clip segments between consecutive nodes of one clip and transitions.
//
// Frames and continuity (what the cloth needs). Each edge's poses are expressed in the world frame
// of the clip it starts in (its "edge frame"): a clip edge in its clip's frame, a transition in
// its source clip's frame, the target clip being brought there by the edge's floor alignment
// `align` (Kovar's rigid 2D alignment, sec. 3.1). The last pose of an edge therefore equals
// align * (first pose of every edge leaving its target node), exactly up to rounding, and a path
// accumulates the 2D transforms: world = align(e1) * align(e2) * ... * pose of the current edge.
// The cloth is simulated per edge in the edge's canonical frame: the floor frame of its first pose
// (root projected on the floor, rotated so the root faces +z), which is fixed during the edge and
// so inertial (gravity stays -y). At the end of an edge, `edge_handoff` gives the rigid 2D
// transform that expresses the cloth state in the canonical frame of whichever edge comes next:
// all edges leaving a node start from the same pose, hence the same canonical frame, so the
// handoff depends on the finished edge only. Positions and velocities transform rigidly (the frames
// differ by a constant transform), so the cloth state is continuous across edges.
#pragma once

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "character/manifest.hpp"
#include "character/skeleton.hpp"

namespace clothdb {

// Thrown for every problem building, loading or using a motion graph; the message names the file
// or setting at fault.
struct GraphError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// A rigid transform of the floor plane: rotation by `theta` about +y, then translation (x, 0, z).
// p -> R_y(theta) p + (x, 0, z), where R_y(theta) maps +z to (sin theta, 0, cos theta).
struct FloorTransform {
  double theta = 0.0, x = 0.0, z = 0.0;

  Eigen::Quaterniond rotation() const;
  Eigen::Vector3d apply(const Eigen::Vector3d& p) const;   // a point
  Eigen::Vector3d rotate(const Eigen::Vector3d& v) const;  // a vector (velocity, direction)
  JointPose apply(const JointPose& pose) const;
  FloorTransform inverse() const;
  // Composition: (a * b).apply(p) == a.apply(b.apply(p)).
  FloorTransform operator*(const FloorTransform& other) const;
};

// Floor frame of a root pose: the root's position projected on the floor (y dropped) and its
// heading, so that frame.inverse() puts the root at the floor origin facing +z. The heading is the
// direction of the root's +z axis (forward for CMU BVH and most rigs) projected on the floor,
// averaged with root_x x (+y), the forward direction implied by the root's +x (hip-to-hip) axis:
// the first degenerates when the character bends far forward, the second when it rolls sideways,
// and their sum only when both happen at once.
FloorTransform floor_frame(const JointPose& root);

// Optimal alignment of two windows of poses (Kovar 2002, sec. 3.1) and the distance it leaves.
struct WindowAlignment {
  FloorTransform transform;  // takes the second window onto the first
  double distance = 0.0;     // min over the transform of sum_i w_i |p_i - T p'_i|^2 (sec. 3.1)
  double rms = 0.0;          // sqrt(distance / sum_i w_i): metres
};

// Point clouds p and q (same size) with weights w (empty: all 1): the rotation about +y and floor
// translation T minimising sum_i w_i |p_i - T q_i|^2, in Kovar's closed form (2002, sec. 3.1).
WindowAlignment align_point_clouds(const std::vector<Eigen::Vector3d>& p,
                                   const std::vector<Eigen::Vector3d>& q,
                                   const std::vector<double>& w = {});

// The point-cloud distance D(A_i, B_j) of Kovar 2002 (sec. 3.1): the joint positions of frames
// a[i .. i + window - 1] against b[j .. j + window - 1] as two point clouds, joint j weighted by
// joint_weights[j] (empty: all 1), aligned by align_point_clouds.
WindowAlignment align_windows(const MotionClip& a, int i, const MotionClip& b, int j, int window,
                              const std::vector<double>& joint_weights = {});

// D(A_i, B_j) as an RMS distance in metres for every pair of window starts: rows i in
// [0, rows), columns j in [0, cols); `rms` is row-major.
struct DistanceMatrix {
  int rows = 0, cols = 0;
  std::vector<double> rms;
  double at(int i, int j) const { return rms[static_cast<size_t>(i) * cols + j]; }
};
// Windows start at frames i <= a.frame_count - span and j <= b.frame_count - span, where
// span = max(window, blend + 1) frames so that every entry can also be blended. Same result as
// align_windows entry by entry, computed from per-frame-pair sums (OpenMP over rows).
DistanceMatrix window_distances(const MotionClip& a, const MotionClip& b, int window, int span,
                                const std::vector<double>& joint_weights = {});

enum class ThresholdMode {
  absolute,   // `threshold` is an RMS distance in metres
  percentile  // `threshold` is a percentile (0..100) of the distances of each pair of clips
};

struct GraphSettings {
  int window = 5;  // k: frames per window of the distance (5 at 30 Hz: 1/6 s)
  int blend = 10;  // frames of a transition: it blends blend + 1 poses, blend intervals
  ThresholdMode threshold_mode = ThresholdMode::percentile;
  // Local minima of D at or below the threshold become transitions. In percentile mode each pair
  // of clips (a clip with itself included) gets its own threshold, that percentile of its
  // distances, so that two different clips get their best transitions even though they are
  // further apart than the frames of one clip are from each other (on CMU 01_01 and 01_03 the
  // closest windows across the clips are 5.7 cm RMS apart, within 01_01 1.5 cm); never above
  // max_distance. The default keeps a handful: on the CMU demo (01_01 and 01_03) 10 transitions,
  // 7 of them between the two clips, after pruning.
  double threshold = 0.03;
  double max_distance = 0.10;  // metres RMS, percentile mode only
  // Local minima are minima over a (2 spacing + 1)^2 neighbourhood of D: Kovar (sec. 3.2) takes
  // local minima so that a good region gives one transition, not one per frame of it.
  int spacing = 10;
  // Within one clip, pairs with |i - j| < min_self_offset are trivially similar (neighbouring
  // frames) and are not considered.
  int min_self_offset = 15;
  std::vector<double> joint_weights;  // per joint; empty: all 1
  bool prune = true;                  // keep the largest strongly connected component only
  // Snapping (0: off). Transitions of different clip pairs leave or arrive a frame or two apart,
  // and each point becomes a node that needs its own cloth states. With min_segment_s > 0 the
  // found transitions' points within one clip are moved onto shared nodes at least
  // min_segment_frames() apart, so that every clip segment lasts at least this long except where
  // a clip starts or ends. A moved transition keeps its blend length; its Kovar distance is
  // recomputed at the frames it moved to and it is dropped if that exceeds the threshold.
  // Declared transitions are never moved.
  double min_segment_s = 0.0;

  // ceil(min_segment_s * rate) frames at `rate` Hz (0 when snapping is off).
  int min_segment_frames(double rate) const;
};

// The scene file's "graph" block (precompute/character_scene), e.g.
//   "graph": {"percentile": 0.3, "min_segment_s": 0.3, "spacing": 10}
// Fields: window, blend, spacing, self_offset (frames), percentile (0-100) or threshold (metres
// RMS, absolute), max_distance (metres), min_segment_s (seconds), prune (true/false); each
// absent field keeps GraphSettings' default. Throws GraphError "<where>: graph.<field>:
// <problem>" for an unknown field or a bad value.
GraphSettings graph_settings_from_scene(const nlohmann::json& block, const std::string& where);

struct GraphClip {
  std::string name;
  std::string source;  // file it came from
  int frame_count = 0;
  double rate = 30.0;
};

struct GraphNode {
  int clip = 0;
  int frame = 0;
};

enum class EdgeKind { clip, transition };
const char* edge_kind_name(EdgeKind kind);  // "clip", "transition"

struct GraphEdge {
  int from = 0, to = 0;  // node indices
  EdgeKind kind = EdgeKind::clip;
  // Frames of `clip` the edge plays: a clip edge first_frame .. last_frame; a transition the
  // source side of its blend, first_frame .. first_frame + blend.
  int clip = 0;
  int first_frame = 0, last_frame = 0;
  // Clip and frames the edge ends in: for a clip edge the same clip and last_frame; for a
  // transition the target side of the blend, target_first_frame .. target_frame
  // (= target_first_frame + blend), target_frame being the node it arrives at.
  int target_clip = 0;
  int target_first_frame = 0, target_frame = 0;
  int blend = 0;          // frames (0 for a clip edge)
  double distance = 0.0;  // Kovar's D at the transition as an RMS in metres (0 for a clip edge)
  // Takes the target clip's frame into this edge's frame (identity for a clip edge); see the
  // frame convention at the top of this file.
  FloorTransform align;
  bool manual = false;  // declared in the manifest rather than found
  // Relative likelihood that the game takes this edge at its source node (manifest "weight",
  // character/manifest.hpp; 1 when not given): probability weight / (sum over the node's edges).
  double weight = 1.0;

  int frame_count() const { return last_frame - first_frame + 1; }  // poses it plays
};

// The threshold used between two clips (clip_a <= clip_b), metres RMS.
struct PairThreshold {
  int clip_a = 0, clip_b = 0;
  double rms = 0.0;
};

struct MotionGraph {
  std::vector<GraphClip> clips;
  std::vector<std::string> joint_names;
  std::vector<int> parents;  // of the skeleton: edge_poses blends local rotations
  GraphSettings settings;
  std::vector<PairThreshold> thresholds;  // the thresholds used, every pair of clips
  std::vector<GraphNode> nodes;
  std::vector<GraphEdge> edges;
  // Before pruning: transitions found or declared, and nodes.
  int candidate_transitions = 0;
  int candidate_nodes = 0;
  // Snapping (settings.min_segment_s > 0): found transitions moved onto a shared node, and those
  // dropped because their distance at the snapped frames exceeded the threshold (or two became
  // the same transition).
  int snapped_transitions = 0;
  int snap_dropped = 0;

  int node_count() const { return static_cast<int>(nodes.size()); }
  int edge_count() const { return static_cast<int>(edges.size()); }
  int transition_count() const;
  int clip_edge_count() const { return edge_count() - transition_count(); }
  std::vector<int> outgoing(int node) const;  // edge indices, ascending
  std::vector<int> incoming(int node) const;
};

// A transition before it becomes an edge: frame `from_frame` of clip `from_clip` corresponds to
// frame `to_frame` of `to_clip` (the blend starts there on both sides).
struct TransitionCandidate {
  int from_clip = 0, from_frame = 0;
  int to_clip = 0, to_frame = 0;
  double distance = 0.0;  // RMS metres
  FloorTransform align;   // to_clip's frame -> from_clip's frame
  bool manual = false;
};

// Transitions found by Kovar's method: D for every pair of clips (a clip with itself included,
// minus |i - j| < min_self_offset), local minima at or below the threshold, each kept in both
// directions (D is symmetric). Sorted. `thresholds` receives the threshold used for each pair.
std::vector<TransitionCandidate> find_transitions(const std::vector<MotionClip>& clips,
                                                  const GraphSettings& settings,
                                                  std::vector<PairThreshold>* thresholds = nullptr);

// Builds the graph of `clips` (one skeleton, one frame rate) with the transitions found and the
// manifest's declared ones, pruned to its largest strongly connected component unless
// settings.prune is false. Deterministic: the same inputs give the same graph. Throws GraphError
// for inconsistent inputs (rates, skeletons, a declared transition out of range; messages name
// the clip or the manifest field) and when pruning leaves no edge (with the threshold to raise).
MotionGraph build_motion_graph(const std::vector<MotionClip>& clips, const Skeleton& skeleton,
                               const GraphSettings& settings,
                               const std::vector<ManifestTransition>& declared = {});

// Clips of a manifest and their common skeleton, ready for build_motion_graph.
struct GraphInput {
  std::vector<MotionClip> clips;
  Skeleton skeleton;
  std::vector<ManifestTransition> transitions;  // the manifest's, between the clips kept
  std::vector<double> clip_weights;             // the manifest's clip "weight", per clip kept
  std::vector<std::string> files;               // the motion file of each clip kept
};
// Loads the clips named in `clip_names` (empty: all of them, in manifest order) and checks that
// they share one skeleton; the manifest's declared transitions between clips not loaded are
// dropped.
GraphInput load_graph_input(const std::filesystem::path& manifest,
                            const std::vector<std::string>& clip_names = {});

// How much of the motion a pruned graph keeps (graph build, graph show, db info). Frames kept: the
// frames of a clip that some clip edge plays (first_frame .. last_frame; a transition's blend
// mixes two clips and is not counted). A segment is a clip edge; its length is last_frame -
// first_frame, in frames at the clip's rate (the time it lasts).
struct ClipCoverage {
  std::string name;
  int frames = 0;  // in the clip
  int kept = 0;    // played by a clip edge of the graph
};
struct GraphCoverage {
  std::vector<ClipCoverage> clips;
  int frames = 0, kept = 0;  // over all clips
  int segments = 0;          // clip edges
  int median_segment = 0;    // frames; the lower median (0 without segments)
  int shortest_segment = 0;  // frames
  // Segments shorter than settings.min_segment_frames() that neither start at a clip's first
  // frame nor end at its last (snapping promises none).
  int short_inner_segments = 0;
  double largest_transition = 0.0;  // largest Kovar distance of a transition edge, metres RMS
  double kept_fraction() const { return frames > 0 ? double(kept) / frames : 0.0; }
};
GraphCoverage graph_coverage(const MotionGraph& graph);
// The coverage as printed lines ("coverage ..."), and a warning naming the settings when the graph
// keeps under 50 % of the frames.
std::string coverage_text(const MotionGraph& graph);

// Strongly connected components of a directed graph (Kovar 2002 sec. 3.4 prunes to the largest;
// Tarjan 1972, iterative so that long clip chains cannot overflow the stack). Each component's
// nodes ascending; components in the order Tarjan completes them.
std::vector<std::vector<int>> strongly_connected_components(
    int node_count, const std::vector<std::pair<int, int>>& edges);
// Keeps the largest strongly connected component (most nodes, then most edges, then the one with
// the lowest node), merges nodes left with one clip edge in and one out, renumbers in sorted
// order.
void prune_to_largest_component(MotionGraph& graph);
bool is_strongly_connected(const MotionGraph& graph);

// Poses along edge `edge` at the clips' rate, in the edge frame (see the top of this file): a clip
// edge its clip's frames first_frame .. last_frame; a transition blend + 1 poses blending the
// source with the aligned target (Kovar 2002 sec. 3.3: root position linearly, every joint's
// rotation relative to its parent by slerp, weight 2s^3 - 3s^2 + 1 with s = p / blend so that the
// first pose is the source frame and the last the target frame exactly; bone offsets are taken
// from the data, so bone lengths are kept). `clips` must be the graph's clips, in order.
std::vector<std::vector<JointPose>> edge_poses(const MotionGraph& graph,
                                               const std::vector<MotionClip>& clips, int edge);
// The same poses in the edge's canonical frame: the first pose's root at the floor origin, facing
// +z (floor_frame).
std::vector<std::vector<JointPose>> edge_poses_canonical(const MotionGraph& graph,
                                                         const std::vector<MotionClip>& clips,
                                                         int edge);
// Takes coordinates in `edge`'s canonical frame to the canonical frame of every edge leaving its
// target node: the inverse of the floor frame of the edge's last canonical pose.
FloorTransform edge_handoff(const MotionGraph& graph, const std::vector<MotionClip>& clips,
                            int edge);
// A cloth state (positions, and velocities if given) at the end of `edge`, in its canonical
// frame, re-expressed in place in the canonical frame of the next edge.
void carry_to_next_edge(const FloorTransform& handoff, std::vector<Eigen::Vector3d>* positions,
                        std::vector<Eigen::Vector3d>* velocities = nullptr);

// Sets every edge's weight from the manifest (character/manifest.hpp): a declared transition's
// own weight if it has one, else the weight of the clip the edge plays into. `clip_weights` is
// per graph clip (empty: all 1).
void set_edge_weights(MotionGraph& graph, const std::vector<double>& clip_weights,
                      const std::vector<ManifestTransition>& declared);

// How often a game wandering the graph takes each edge, relative to the most taken one (so the
// most taken edge gets 1). The game is a Markov chain on the nodes: at node n it takes edge e
// with p(e) = weight(e) / sum of the weights leaving n. Its stationary distribution pi
// (pi = pi P, sum pi = 1; unique because the pruned graph is strongly connected) is found by
// power iteration on the lazy chain (I + P) / 2, which has the same pi and converges even when
// the graph is periodic. Edge e's reach is pi(from(e)) p(e), the long-run fraction of
// transitions that are e, divided by the largest. Deterministic (fixed order and iteration).
std::vector<double> edge_reach(const MotionGraph& graph);
// The same for any directed graph given as (from, to) per edge with weights. If a node has no edge
// out (an unpruned graph) there is no stationary chain: every edge gets reach 1.
std::vector<double> edge_reach(int node_count, const std::vector<std::pair<int, int>>& edges,
                               const std::vector<double>& weights);

// JSON form (what the database stores). motion_graph_from_json checks everything it reads and
// throws GraphError naming `where` and the field.
nlohmann::json motion_graph_to_json(const MotionGraph& graph);
MotionGraph motion_graph_from_json(const nlohmann::json& json, const std::string& where);
MotionGraph load_motion_graph(const std::filesystem::path& file);  // reads JSON from a file

}  // namespace clothdb
