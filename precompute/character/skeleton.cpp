#include "character/skeleton.hpp"

#include <algorithm>
#include <cmath>

namespace clothdb {

int Skeleton::find(const std::string& name) const {
  const auto it = std::find(names.begin(), names.end(), name);
  return it == names.end() ? -1 : static_cast<int>(it - names.begin());
}

int Skeleton::require(const std::string& name) const {
  const int j = find(name);
  if (j >= 0) return j;
  std::string list;
  for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
  throw MotionError(source + ": bone '" + name + "' not found; the skeleton has " +
                    std::to_string(names.size()) + " joints: " + list);
}

std::vector<int> Skeleton::children(int j) const {
  std::vector<int> result;
  for (int k = 0; k < joint_count(); ++k)
    if (parents[k] == j) result.push_back(k);
  return result;
}

JointPose pose_from_affine(const Eigen::Affine3d& t) {
  JointPose pose;
  pose.position = t.translation();
  Eigen::Matrix3d rotation, scaling;
  t.computeRotationScaling(&rotation, &scaling);
  pose.rotation = Eigen::Quaterniond(rotation).normalized();
  return pose;
}

std::vector<JointPose> rest_pose(const Skeleton& skeleton) {
  const int n = skeleton.joint_count();
  std::vector<Eigen::Affine3d> world(n);
  std::vector<JointPose> poses(n);
  for (int j = 0; j < n; ++j) {
    const int p = skeleton.parents[j];
    world[j] = p < 0 ? skeleton.rest_local[j] : world[p] * skeleton.rest_local[j];
    poses[j] = pose_from_affine(world[j]);
  }
  return poses;
}

Eigen::Isometry3d MotionClip::world(int frame, int joint) const {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = rotation(frame, joint).toRotationMatrix();
  t.translation() = position(frame, joint);
  return t;
}

std::vector<Eigen::Vector3d> MotionClip::root_trajectory() const {
  std::vector<Eigen::Vector3d> result;
  result.reserve(frame_count);
  for (int f = 0; f < frame_count; ++f) result.push_back(position(f, 0));
  return result;
}

std::vector<JointPose> sample_pose(const MotionClip& clip, double time) {
  std::vector<JointPose> pose(clip.joint_count);
  if (clip.frame_count == 0) return pose;
  const double u = std::clamp(time * clip.rate, 0.0, static_cast<double>(clip.frame_count - 1));
  const int f0 = static_cast<int>(std::floor(u));
  const int f1 = std::min(f0 + 1, clip.frame_count - 1);
  const double s = u - f0;
  for (int j = 0; j < clip.joint_count; ++j) {
    if (s == 0.0 || f1 == f0) {
      pose[j].position = clip.position(f0, j);
      pose[j].rotation = clip.rotation(f0, j);
    } else {
      pose[j].position = (1.0 - s) * clip.position(f0, j) + s * clip.position(f1, j);
      // Eigen's slerp takes the shorter arc (it flips the sign of q1 when q0.q1 < 0).
      pose[j].rotation = clip.rotation(f0, j).slerp(s, clip.rotation(f1, j)).normalized();
    }
  }
  return pose;
}

}  // namespace clothdb
