// Conversions between world space and character space (docs/SECONDARY_GRAPH.md: the frame
// character_frame() gives), as a clothdb file stores cloth: 3 floats per vertex. Positions move
// with the whole transform, velocities (vectors = true) with its rotation only.
#pragma once

#include <Eigen/Geometry>
#include <vector>

#include "character/skeleton.hpp"

namespace clothdb {

inline std::vector<float> to_character_space(const Eigen::Matrix3Xd& x,
                                             const Eigen::Isometry3d& frame, bool vectors) {
  std::vector<float> out(static_cast<size_t>(x.cols()) * 3);
  const Eigen::Isometry3d inv = frame.inverse();
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    const Eigen::Vector3d p = vectors ? Eigen::Vector3d(inv.linear() * x.col(i))
                                      : Eigen::Vector3d(inv * Eigen::Vector3d(x.col(i)));
    for (int k = 0; k < 3; ++k) out[3 * i + k] = static_cast<float>(p[k]);
  }
  return out;
}

inline Eigen::Matrix3Xd from_character_space(const std::vector<float>& local,
                                             const Eigen::Isometry3d& frame, bool vectors) {
  Eigen::Matrix3Xd x(3, static_cast<Eigen::Index>(local.size() / 3));
  for (Eigen::Index i = 0; i < x.cols(); ++i) {
    const Eigen::Vector3d p(local[3 * i], local[3 * i + 1], local[3 * i + 2]);
    x.col(i) = vectors ? Eigen::Vector3d(frame.linear() * p) : Eigen::Vector3d(frame * p);
  }
  return x;
}

// A pose moved rigidly by `t` (every joint's position and rotation): how a walk carries an edge's
// poses so that its first pose's character frame is where the walk has got to.
inline std::vector<JointPose> carried(const std::vector<JointPose>& pose,
                                      const Eigen::Isometry3d& t) {
  std::vector<JointPose> out = pose;
  const Eigen::Quaterniond q(t.linear());
  for (JointPose& j : out) {
    j.position = t * j.position;
    j.rotation = q * j.rotation;
  }
  return out;
}

}  // namespace clothdb
