// Body colliders: one capsule per bone segment (a joint to each child joint, or to its end site),
// with radii derived from the skeleton's proportions and overridable per bone. A scene models only
// the bones it needs: it lists them, or selects those within a distance of the garment; the other
// bones are never turned into colliders. Capsules follow a MotionClip, with the pose at the start
// of each step in a_start/b_start so that solvers sweep them through the step.
#pragma once

#include <Eigen/Core>
#include <map>
#include <string>
#include <vector>

#include "character/skeleton.hpp"
#include "cloth/collision.hpp"

namespace clothdb {

// Body region of a bone, from its name (the conventions of CMU, Motion Builder, Mixamo and
// Blender rigs); it sets the default radius.
enum class BodyRegion {
  Torso,
  Neck,
  Head,
  Clavicle,
  UpperArm,
  Forearm,
  Hand,
  Thigh,
  Shin,
  Foot,
  Other
};
const char* body_region_name(BodyRegion region);

struct BoneCapsule {
  int joint = -1;  // the bone: the capsule starts at this joint
  int child = -1;  // ends at this child joint, or at the joint's end site when -1
  BodyRegion region = BodyRegion::Other;
  double radius = 0.05;  // metres
};

struct Body {
  std::vector<BoneCapsule> capsules;
};

// Scene-side description of the body colliders.
struct BodySpec {
  // Bones (joint names) that collide; every capsule starting at a listed joint is used. Empty:
  // all bones (or, with make_body_near, the bones near the garment).
  std::vector<std::string> bones;
  // Radius in metres for particular bones, replacing the proportional default.
  std::map<std::string, double> radius;
};

// Span of the skeleton: the longest path between two of its joints along the bones, the sum of
// the rest distances from joint to joint (metres). End sites do not count: glTF stores none, and
// a rigid re-posing keeps every bone's length, so BVH, Blender's FBX (whose rest pose is the pose
// of its export frame) and glTF of the same rig agree to single precision.
double skeleton_span(const Skeleton& skeleton);

// Size of the skeleton, the reference for the default radii: a stature estimated from the span,
// kStatureOverSpan * skeleton_span (metres). It does not depend on the file format.
double skeleton_size(const Skeleton& skeleton);
// On CMU's rig (01_01.bvh) the rest pose's extent with the end sites, the size the radii were
// tuned on before, is 0.6659 of the span (docs/notebook/blender_motion.md, "Capsule radii from
// the skeleton's span").
inline constexpr double kStatureOverSpan = 0.666;

BodyRegion classify_bone(const Skeleton& skeleton, int joint);
// Default radius of a bone of `region` on a skeleton of the given size (metres).
double default_radius(BodyRegion region, double skeleton_size);

// Every bone segment of the skeleton longer than 1 mm at rest (zero-length segments, like CMU's
// LHipJoint under Hips, add nothing a neighbouring capsule does not cover), default radii.
std::vector<BoneCapsule> all_bone_capsules(const Skeleton& skeleton);

// The capsules of the bones `spec` lists (all if it lists none), with its radius overrides.
// Throws MotionError "<skeleton file>: bone 'X' not found ..." for a name that is not a joint, and
// for a listed joint with no bone segment (a zero-length leaf) or a radius that is not positive.
Body make_body(const Skeleton& skeleton, const BodySpec& spec);

// The capsules whose surface comes within `distance` metres of any garment point at clip frame
// `frame` (garment points in the clip's world frame, metres), after spec's radius overrides. If
// spec lists bones, only those are candidates.
Body make_body_near(const Skeleton& skeleton, const MotionClip& clip,
                    const Eigen::Matrix3Xd& garment_points, double distance, const BodySpec& spec,
                    int frame = 0);

// Capsules at the pose `end`, moving from the pose `start` (a/b from end, a_start/b_start from
// start). `bone` is set to the capsule's joint.
std::vector<CapsuleCollider> body_capsules(const Body& body, const Skeleton& skeleton,
                                           const std::vector<JointPose>& start,
                                           const std::vector<JointPose>& end);

// Capsules at clip frame `frame`, moving from frame - 1 (from itself at frame 0).
std::vector<CapsuleCollider> body_capsules_at_frame(const Body& body, const Skeleton& skeleton,
                                                    const MotionClip& clip, int frame);

// Capsules for a step from time t_start to t_end (seconds, clamped to the clip), which need not
// fall on frames: poses are interpolated (lerp positions, slerp rotations).
std::vector<CapsuleCollider> body_capsules_between(const Body& body, const Skeleton& skeleton,
                                                   const MotionClip& clip, double t_start,
                                                   double t_end);

}  // namespace clothdb
