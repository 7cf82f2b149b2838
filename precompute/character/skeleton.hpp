// Skeleton and sampled motion: plain data produced by the motion loader (character/motion_loader)
// and consumed by the body colliders (character/body) and the scenes. Everything is in metres in
// clothdb's frame (+y up) once loaded: unit scale and up axis are applied at import.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace clothdb {

// Thrown for every problem with a motion file or motion manifest: missing or unreadable file,
// truncated data, no skeleton, no animation, a bone that is not there, a bad manifest field. The
// message always starts with the file it is about.
struct MotionError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct Skeleton {
  std::string source;              // file the skeleton came from (for error messages)
  std::vector<std::string> names;  // joint names, unique
  std::vector<int> parents;        // parent joint index, -1 for a root; parents[j] < j
  // Rest (bind) transform of each joint relative to its parent, as stored in the file (file
  // units, possibly with node scale). A root's transform also carries everything above it: the
  // static transforms of non-joint ancestor nodes and the conversion to metres and +y up, so that
  // composing rest_local down the hierarchy gives world transforms in metres.
  std::vector<Eigen::Affine3d> rest_local;
  // Offset of a leaf joint's end site (BVH "End Site", or a childless helper node such as
  // Blender's FBX leaf bones) in the joint's frame, already in metres: it gives the far end of the
  // last bone of a chain (head top, toe tip). A leaf joint without one (glTF stores none) gets one
  // made up, so that every leaf has a capsule: along the joint's own bone axis where the rig's
  // frames follow its bones (Blender's +y), else its parent bone continued, in both cases by the
  // parent bone's length.
  std::vector<std::optional<Eigen::Vector3d>> end_site;
  // Per joint: true when its end site was in the file (BVH "End Site", an FBX leaf node), false
  // when the loader made it up for a leaf the file gives no end (glTF). Only file end sites are
  // measurements of the rig; a made-up one is the loader's guess (motion_loader.cpp).
  std::vector<bool> end_site_from_file;

  int joint_count() const { return static_cast<int>(names.size()); }
  // Index of the joint called `name`, or -1.
  int find(const std::string& name) const;
  // Index of the joint called `name`; throws MotionError "<source>: bone '<name>' not found ..."
  // listing the joints that exist, so a typo in a scene is easy to fix.
  int require(const std::string& name) const;
  // Children of joint j, in index order.
  std::vector<int> children(int j) const;
};

// World transforms of the rest pose (rigid part: position in metres and orientation).
struct JointPose {
  Eigen::Vector3d position{0, 0, 0};
  Eigen::Quaterniond rotation{1, 0, 0, 0};
};
std::vector<JointPose> rest_pose(const Skeleton& skeleton);
// Rigid part of an affine transform: its translation, and the orientation of its linear part with
// any scale removed. Node scales are legitimate in FBX rigs (a 0.01 armature over centimetre
// bones); a joint's frame is then the orientation of its scaled frame.
JointPose pose_from_affine(const Eigen::Affine3d& transform);

// A clip sampled at a fixed rate: per frame, per joint world positions (metres, +y up) and
// orientations (unit quaternions). Frame f is at time f / rate seconds from the clip start.
struct MotionClip {
  std::string name;    // clip name (manifest) or the file stem
  std::string source;  // file it was loaded from
  double rate = 30.0;  // frames per second of this clip
  int frame_count = 0;
  int joint_count = 0;
  // Frame-major: entry f * joint_count + j.
  std::vector<Eigen::Vector3d> positions;
  std::vector<Eigen::Quaterniond> rotations;
  // Where the clip came from in the source: its frames are sampled from source frames
  // first_source_frame + f * source_rate / rate.
  double source_rate = 0.0;
  int first_source_frame = 0;
  int source_frame_count = 0;  // frames in the whole source animation
  double scale = 1.0;          // file units -> metres applied at import

  double duration() const { return frame_count > 1 ? (frame_count - 1) / rate : 0.0; }
  const Eigen::Vector3d& position(int frame, int joint) const {
    return positions[static_cast<size_t>(frame) * joint_count + joint];
  }
  const Eigen::Quaterniond& rotation(int frame, int joint) const {
    return rotations[static_cast<size_t>(frame) * joint_count + joint];
  }
  Eigen::Isometry3d world(int frame, int joint) const;
  // Position of the root joint (joint 0) at every frame.
  std::vector<Eigen::Vector3d> root_trajectory() const;
};

// Pose at `time` seconds (clamped to the clip): positions interpolated linearly and orientations by
// slerp between the two nearest frames. At a frame's exact time it returns that frame unchanged.
std::vector<JointPose> sample_pose(const MotionClip& clip, double time);

// World position of a point given in joint j's frame in metres (e.g. Skeleton::end_site).
inline Eigen::Vector3d point_in_joint(const JointPose& pose, const Eigen::Vector3d& local) {
  return pose.position + pose.rotation * local;
}

}  // namespace clothdb
