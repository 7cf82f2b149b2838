// Cloth relative to the body for codec version 2 (docs/DATABASE.md, "version 2": the offset from
// the rest cloth carried by the pinned bones): a rigid frame per cloth frame, fitted (Kabsch) to
// the garment's anchor vertices, so the subspace describes the garment in that frame and the codec
// stores only the 12 floats of the transform for what the body carries.
//
// The anchors are the 5 % of vertices highest in the garment's rest shape, where garments hang
// from their pins (the skirt's waistband, the cape's collar, a sheet's pinned edge), and their
// reference pose is their rest positions. Both come from the file's garment row, so `db recode`,
// the explorer and a resumed run fit the same frames without storing anything more.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace clothdb {

struct RigidFrame {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

// Kabsch (1976): the rotation R and translation t with R p + t closest to q in least squares,
// reflections excluded. p and q: 3 x N, N >= 1.
RigidFrame fit_rigid(const Eigen::Matrix3Xd& p, const Eigen::Matrix3Xd& q);

struct BodyAnchors {
  std::vector<uint32_t> vertices;  // anchor vertex indices, ascending
  Eigen::Matrix3Xd reference;      // their rest positions (the body frame)
};

// The fraction (at least 3 vertices) highest in rest_positions (3 floats per vertex, y up), ties
// by index. Throws std::invalid_argument on fewer than 3 vertices or a fraction outside (0, 1].
BodyAnchors body_anchors(const std::vector<float>& rest_positions, double fraction = 0.05);

// Per frame (frames: frame_count x 3V floats) the transform from the body frame to the frame's
// space as codec::SubspaceSettings::body_frames stores it: 12 floats, R row by row, then t.
std::vector<float> fit_body_frames(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                                   const BodyAnchors& anchors);

// In place: x <- R^T (x - t) for each frame, with its transform as fit_body_frames gives it
// (transforms: 12 floats per frame), by codec::to_body_frame in double, rounded once to float:
// the frames a body-frame basis is built from.
void to_body_frame(float* frames, uint32_t frame_count, uint32_t vertex_count,
                   const float* transforms);

}  // namespace clothdb
