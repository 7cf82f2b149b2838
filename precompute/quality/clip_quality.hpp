// Quality metrics of a cloth clip (for finding bad clips): measured by the explorer for
// every clip it stores, recomputed by `clip import` / `clip resim`, listed by `clothdb clips list`.
// Solver side: Eigen and the cloth model, no SQLite.
// docs/DATABASE.md#clip-quality-metrics-version-2 repeats the definitions.
//
// A clip is F frames of V vertices (float x, y, z; frame-major, as stored in the database) in
// character space (docs/SECONDARY_GRAPH.md), with the body capsules at each frame in the same
// space. Definitions, all over the whole clip:
//
// - max_strain: max over mesh edges and frames of (l - l0) / l0, l0 the rest length; the measure
//   `clothdb simulate` and the hard cases report (max_edge_strain). Compression counts as 0.
// - max_penetration: max over free vertices (inverse mass > 0; pins follow their bone and may sit
//   inside it by construction) and frames of the depth below the nearest capsule surface
//   (penetration_depth in cloth/collision.hpp; the collision margin is not counted), metres.
// - mean_penetration: the mean depth over the penetrating (free vertex, frame) pairs only, 0 when
//   none penetrates. Over all pairs it would mostly measure how much of the garment is far from the
//   body; over the penetrating ones it says how deep a typical contact goes, next to the max that
//   catches a single spike. Same convention as the per-frame mean_penetration of `simulate`.
// - jitter: high-frequency motion, as the RMS over free vertices and frames 2 .. F-3 of the
//   normalised fourth difference |x[f-2] - 4x[f-1] + 6x[f] - 4x[f+1] + x[f+2]| / sqrt(70),
//   metres, measured in world space (what the viewer sees; the scene overload below converts).
//   Why a high-pass rather than "second differences on frames where the body is still": the
//   clips of a walk graph hardly ever hold still, so that metric would be undefined on most of
//   them, while cloth that moves smoothly with the body is exactly the motion that must not count.
//   The fourth difference has gain 16 sin^4(w dt / 2): 16 at the Nyquist frequency (a vertex
//   flipping back and forth every frame), 2e-3 for a 1 Hz swing at 30 fps (so a 10 cm swing reads
//   0.02 mm), and it is exactly 0 for any motion that is a cubic in time. sqrt(70) is the root of
//   the sum of its squared coefficients, so independent per-frame noise of RMS length r per vertex
//   reads as jitter r. What it cannot tell apart: a genuine impact (a leg hitting the hem changes
//   the cloth's velocity within a frame) is high-frequency too, so on a walking skirt every clip
//   reads about 1 to 4 mm; a clip that flickers reads more. (A measure of frame-to-frame
//   acceleration reversals, which ignores impacts, was tried and dropped: the cloth's smooth
//   acceleration of several mm per frame squared masks a flicker of the same size.) 0 for clips
//   shorter than 5 frames.
// - halved_steps: how many times the solver halved its step to recover (StepReport::
//   step_halvings summed over the clip; only the Newton solver halves, the others report 0).
//   Not visible in the frames: measure_clip returns -1 (unknown); whoever ran the solver sets it.
// - self_intersections: the most edge-triangle crossings in one frame (an edge through a triangle
//   it does not touch: cloth/self_intersection.hpp, docs/guide/self_collision.md),
//   self_intersection_frame the first frame with that many (-1: none), self_intersection_frames how
//   many frames have any.
// - worst_frame: the frame with the largest score max(strain / kVisibleStrain, penetration /
//   kVisiblePenetration, jitter / kVisibleJitter, crossings) of that frame's own values (first on
//   ties): the frame the contact sheet of `clothdb clip show` marks. One crossing already shows
//   (the cloth is visibly through itself), so it counts like a visible defect.
//
// The pop at a transition (transition_pop) is per cloth edge, not per clip.
#pragma once

#include <cstddef>
#include <vector>

#include "character_scene/character_scene.hpp"
#include "cloth/collision.hpp"
#include "cloth/model.hpp"
#include "database/store/writer.hpp"

namespace clothdb {

// The levels at which each defect starts to show; they only weigh the defects against each other
// to choose worst_frame. Strain: Provot's critical deformation rate (seed 001, 10 %), beyond
// which cloth reads as rubber. Penetration: 5 mm, about where a capsule pokes visibly through a
// garment hanging at the 4 mm collision margin. Jitter: 1 mm of buzz per frame.
constexpr double kVisibleStrain = 0.10;
constexpr double kVisiblePenetration = 0.005;  // m
constexpr double kVisibleJitter = 0.001;       // m

struct ClipQuality {
  double max_strain = 0;        // max (l - l0) / l0
  double max_penetration = 0;   // m
  double mean_penetration = 0;  // m, over penetrating vertex-frames
  double jitter = 0;            // m, RMS normalised fourth difference
  int halved_steps = -1;        // -1: unknown (set by the caller that ran the solver)
  int worst_frame = 0;
  int self_intersections = 0;  // most edge-triangle crossings in one frame
  int self_intersection_frame = -1;
  int self_intersection_frames = 0;
};

// The same measures for one frame (jitter: RMS over free vertices of that frame's normalised
// fourth difference, 0 for the first and last two frames).
struct FrameQuality {
  double strain = 0, max_penetration = 0, jitter = 0;
  int self_intersections = 0;
  double score = 0;  // what worst_frame maximises
};

// frames: frame_count * model.vertex_count() * 3 floats. capsules[f]: the body at frame f in the
// frames' space (capsules.size() == frame_count; a and b are used, the *_start ends are not).
// per_frame (optional) receives one FrameQuality per frame. Throws std::invalid_argument when the
// sizes do not match.
ClipQuality measure_clip(const ClothModel& model, const float* frames, int frame_count,
                         const std::vector<std::vector<CapsuleCollider>>& capsules,
                         std::vector<FrameQuality>* per_frame = nullptr);

// Body capsules at every pose, each in that pose's character space: the space a clip along these
// poses is stored in (character_frame in character_scene/character_scene.hpp).
std::vector<std::vector<CapsuleCollider>> character_space_capsules(
    const CharacterScene& scene, const std::vector<std::vector<JointPose>>& poses);

// The whole skeleton (every bone, at 60 % of its default collider radius) at every pose, in
// character space like character_space_capsules: what previews draw under the colliders.
std::vector<std::vector<CapsuleCollider>> character_space_skeleton(
    const CharacterScene& scene, const std::vector<std::vector<JointPose>>& poses);

// A clip simulated (or edited) along `poses`: frames.size() must be poses.size() * V * 3.
ClipQuality measure_clip(const CharacterScene& scene,
                         const std::vector<std::vector<JointPose>>& poses,
                         const std::vector<float>& frames,
                         std::vector<FrameQuality>* per_frame = nullptr);

// The pop at a cloth edge, metres: max over vertices of |last - target|, where `last` is the
// clip's last frame and `target` the positions of the state the edge leads to (the first frame of
// every clip that continues from it). The runtime (runtime/player.cpp) adds exactly this
// difference as an offset to the next clip and fades it out over its blend frames (8 by default)
// when the edge's blend error is > 0, so the garment moves at most pop / blend_frames further per
// frame than the clip does; when the blend error is 0 it switches without a blend and the pop is
// the codec's rounding, at most 2 sqrt(3) times the position bound.
double transition_pop(const float* last, const float* target, size_t vertex_count);

// The database's row form of a ClipQuality.
db::ClipMetrics to_clip_metrics(const ClipQuality& quality);

}  // namespace clothdb
