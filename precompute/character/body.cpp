#include "character/body.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>

namespace clothdb {

namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

bool contains(const std::string& s, const char* part) {
  return s.find(part) != std::string::npos;
}

// Segments shorter than this at rest are skipped: the joint and its child coincide (CMU's
// LHipJoint, Neck and LeftShoulder sit exactly on their parents).
constexpr double kMinSegment = 1e-3;

Eigen::Vector3d segment_end(const BoneCapsule& c, const Skeleton& sk,
                            const std::vector<JointPose>& pose) {
  if (c.child >= 0) return pose[c.child].position;
  return point_in_joint(pose[c.joint], *sk.end_site[c.joint]);
}

double point_segment_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                              const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
}

}  // namespace

const char* body_region_name(BodyRegion region) {
  switch (region) {
    case BodyRegion::Torso:
      return "torso";
    case BodyRegion::Neck:
      return "neck";
    case BodyRegion::Head:
      return "head";
    case BodyRegion::Clavicle:
      return "clavicle";
    case BodyRegion::UpperArm:
      return "upper arm";
    case BodyRegion::Forearm:
      return "forearm";
    case BodyRegion::Hand:
      return "hand";
    case BodyRegion::Thigh:
      return "thigh";
    case BodyRegion::Shin:
      return "shin";
    case BodyRegion::Foot:
      return "foot";
    case BodyRegion::Other:
      return "other";
  }
  return "?";
}

double skeleton_span(const Skeleton& skeleton) {
  const std::vector<JointPose> rest = rest_pose(skeleton);
  // The tree's diameter by bone length, children before parents (parents[j] < j): longest[j] is
  // the longest path from j down to one of its descendants; a path through j joins j's two
  // longest branches.
  const int n = skeleton.joint_count();
  std::vector<double> longest(n, 0.0), second(n, 0.0);
  double span = 0.0;
  for (int j = n - 1; j >= 0; --j) {
    span = std::max(span, longest[j] + second[j]);
    const int parent = skeleton.parents[j];
    if (parent < 0) continue;
    const double branch = longest[j] + (rest[j].position - rest[parent].position).norm();
    if (branch > longest[parent]) {
      second[parent] = longest[parent];
      longest[parent] = branch;
    } else if (branch > second[parent]) {
      second[parent] = branch;
    }
  }
  return span;
}

double skeleton_size(const Skeleton& skeleton) {
  return kStatureOverSpan * skeleton_span(skeleton);
}

BodyRegion classify_bone(const Skeleton& skeleton, int joint) {
  const std::string n = lower(skeleton.names[joint]);
  // Blender's armature object is a node above the rig, not an arm.
  if (contains(n, "armature")) return BodyRegion::Other;
  // Order matters: "hips" (the pelvis root) and "hipjoint" (CMU's pelvis sides) before "hip" (a
  // thigh in Motion Builder rigs), "upleg" before "leg", "forearm" before "arm".
  if (contains(n, "hips") || contains(n, "hipjoint") || contains(n, "pelvis") ||
      contains(n, "spine") || contains(n, "back") || contains(n, "chest") || contains(n, "torso") ||
      contains(n, "abdomen") || n == "ab" || n == "root")
    return BodyRegion::Torso;
  if (contains(n, "neck")) return BodyRegion::Neck;
  if (contains(n, "head")) return BodyRegion::Head;
  if (contains(n, "collar") || contains(n, "clavicle")) return BodyRegion::Clavicle;
  if (contains(n, "shoulder")) {
    // CMU and Mixamo call the clavicle "Shoulder" (its child is the "Arm"); Motion Builder-style
    // rigs (Boxing_Toes) call the upper arm "Shoulder" (its child is the "Elbow").
    for (int c : skeleton.children(joint)) {
      const std::string child = lower(skeleton.names[c]);
      if (contains(child, "arm") && !contains(child, "fore")) return BodyRegion::Clavicle;
    }
    return BodyRegion::UpperArm;
  }
  if (contains(n, "forearm") || contains(n, "elbow") || contains(n, "lowerarm"))
    return BodyRegion::Forearm;
  if (contains(n, "arm") || contains(n, "humerus")) return BodyRegion::UpperArm;
  if (contains(n, "hand") || contains(n, "wrist") || contains(n, "finger") ||
      contains(n, "thumb") || contains(n, "index") || contains(n, "palm"))
    return BodyRegion::Hand;
  if (contains(n, "upleg") || contains(n, "thigh") || contains(n, "hip") || contains(n, "femur"))
    return BodyRegion::Thigh;
  if (contains(n, "leg") || contains(n, "knee") || contains(n, "shin") || contains(n, "calf") ||
      contains(n, "tibia"))
    return BodyRegion::Shin;
  if (contains(n, "foot") || contains(n, "ankle") || contains(n, "toe")) return BodyRegion::Foot;
  return BodyRegion::Other;
}

double default_radius(BodyRegion region, double size) {
  // Fractions of the skeleton size (about the stature): for 1.75 m they give a 13 cm torso, 9 cm
  // thigh, 5 cm upper arm: a snug body, so cloth rests on the capsules rather than in the air.
  switch (region) {
    case BodyRegion::Torso:
      return 0.075 * size;
    case BodyRegion::Neck:
      return 0.033 * size;
    case BodyRegion::Head:
      return 0.055 * size;
    case BodyRegion::Clavicle:
      return 0.03 * size;
    case BodyRegion::UpperArm:
      return 0.029 * size;
    case BodyRegion::Forearm:
      return 0.023 * size;
    case BodyRegion::Hand:
      return 0.015 * size;
    case BodyRegion::Thigh:
      return 0.05 * size;
    case BodyRegion::Shin:
      return 0.033 * size;
    case BodyRegion::Foot:
      return 0.024 * size;
    case BodyRegion::Other:
      return 0.025 * size;
  }
  return 0.025 * size;
}

std::vector<BoneCapsule> all_bone_capsules(const Skeleton& skeleton) {
  const std::vector<JointPose> rest = rest_pose(skeleton);
  const double size = skeleton_size(skeleton);
  std::vector<BoneCapsule> result;
  for (int j = 0; j < skeleton.joint_count(); ++j) {
    const BodyRegion region = classify_bone(skeleton, j);
    const double radius = default_radius(region, size);
    std::vector<Eigen::Vector3d> ends;  // rest end points of this joint's segments so far
    auto add = [&](int child, const Eigen::Vector3d& end) {
      if ((end - rest[j].position).norm() < kMinSegment) return;
      // Children at the same offset (Boxing_Toes' Neck and both collars under Chest) stay at the
      // same point in every frame, since a child's position depends only on its parent's frame
      // and its offset: one capsule covers them all.
      for (const Eigen::Vector3d& e : ends)
        if ((e - end).norm() < kMinSegment) return;
      ends.push_back(end);
      result.push_back({j, child, region, radius});
    };
    for (int c : skeleton.children(j)) add(c, rest[c].position);
    if (skeleton.end_site[j]) add(-1, point_in_joint(rest[j], *skeleton.end_site[j]));
  }
  return result;
}

Body make_body(const Skeleton& skeleton, const BodySpec& spec) {
  for (const auto& [name, radius] : spec.radius) {
    skeleton.require(name);
    if (!(radius > 0) || !std::isfinite(radius))
      throw MotionError(skeleton.source + ": radius of bone '" + name +
                        "' must be a positive number of metres");
  }
  std::vector<BoneCapsule> all = all_bone_capsules(skeleton);
  for (BoneCapsule& c : all) {
    const auto it = spec.radius.find(skeleton.names[c.joint]);
    if (it != spec.radius.end()) c.radius = it->second;
  }
  Body body;
  if (spec.bones.empty()) {
    body.capsules = std::move(all);
    return body;
  }
  for (const std::string& name : spec.bones) {
    const int j = skeleton.require(name);
    bool found = false;
    for (const BoneCapsule& c : all) {
      if (c.joint != j) continue;
      const bool listed_twice =
          std::any_of(body.capsules.begin(), body.capsules.end(),
                      [&](const BoneCapsule& b) { return b.joint == j && b.child == c.child; });
      if (!listed_twice) body.capsules.push_back(c);
      found = true;
    }
    if (!found)
      throw MotionError(skeleton.source + ": bone '" + name +
                        "' has no segment to make a capsule of (its joint coincides with its "
                        "children); list its child bone instead");
  }
  return body;
}

Body make_body_near(const Skeleton& skeleton, const MotionClip& clip,
                    const Eigen::Matrix3Xd& garment_points, double distance, const BodySpec& spec,
                    int frame) {
  const Body candidates = make_body(skeleton, spec);
  if (frame < 0 || frame >= clip.frame_count)
    throw MotionError(clip.source + ": frame " + std::to_string(frame) + " is outside the clip's " +
                      std::to_string(clip.frame_count) + " frames");
  std::vector<JointPose> pose(clip.joint_count);
  for (int j = 0; j < clip.joint_count; ++j) {
    pose[j].position = clip.position(frame, j);
    pose[j].rotation = clip.rotation(frame, j);
  }
  Body body;
  for (const BoneCapsule& c : candidates.capsules) {
    const Eigen::Vector3d a = pose[c.joint].position;
    const Eigen::Vector3d b = segment_end(c, skeleton, pose);
    double nearest = std::numeric_limits<double>::infinity();
    for (Eigen::Index i = 0; i < garment_points.cols() && nearest > distance; ++i)
      nearest = std::min(nearest, point_segment_distance(garment_points.col(i), a, b) - c.radius);
    if (nearest <= distance) body.capsules.push_back(c);
  }
  return body;
}

std::vector<CapsuleCollider> body_capsules(const Body& body, const Skeleton& skeleton,
                                           const std::vector<JointPose>& start,
                                           const std::vector<JointPose>& end) {
  std::vector<CapsuleCollider> result;
  result.reserve(body.capsules.size());
  for (const BoneCapsule& c : body.capsules) {
    CapsuleCollider capsule;
    capsule.a = end[c.joint].position;
    capsule.b = segment_end(c, skeleton, end);
    capsule.a_start = start[c.joint].position;
    capsule.b_start = segment_end(c, skeleton, start);
    capsule.radius = c.radius;
    capsule.bone = c.joint;
    result.push_back(capsule);
  }
  return result;
}

std::vector<CapsuleCollider> body_capsules_at_frame(const Body& body, const Skeleton& skeleton,
                                                    const MotionClip& clip, int frame) {
  if (frame < 0 || frame >= clip.frame_count)
    throw MotionError(clip.source + ": frame " + std::to_string(frame) + " is outside the clip's " +
                      std::to_string(clip.frame_count) + " frames");
  auto pose_of = [&](int f) {
    std::vector<JointPose> pose(clip.joint_count);
    for (int j = 0; j < clip.joint_count; ++j) {
      pose[j].position = clip.position(f, j);
      pose[j].rotation = clip.rotation(f, j);
    }
    return pose;
  };
  return body_capsules(body, skeleton, pose_of(std::max(frame - 1, 0)), pose_of(frame));
}

std::vector<CapsuleCollider> body_capsules_between(const Body& body, const Skeleton& skeleton,
                                                   const MotionClip& clip, double t_start,
                                                   double t_end) {
  return body_capsules(body, skeleton, sample_pose(clip, t_start), sample_pose(clip, t_end));
}

}  // namespace clothdb
