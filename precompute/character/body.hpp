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

// Size of the skeleton: the largest extent of its rest pose (joints and end sites), metres. For a
// T-pose this is about the stature (or the arm span), the reference for the default radii.
double skeleton_size(const Skeleton& skeleton);

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
