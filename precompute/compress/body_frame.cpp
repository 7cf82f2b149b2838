#include "compress/body_frame.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

#include "database/codec/codec.hpp"

namespace clothdb {

RigidFrame fit_rigid(const Eigen::Matrix3Xd& p, const Eigen::Matrix3Xd& q) {
  const Eigen::Vector3d pc = p.rowwise().mean(), qc = q.rowwise().mean();
  const Eigen::Matrix3d h = (p.colwise() - pc) * (q.colwise() - qc).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0) d(2, 2) = -1;
  RigidFrame f;
  f.rotation = svd.matrixV() * d * svd.matrixU().transpose();
  f.translation = qc - f.rotation * pc;
  return f;
}

BodyAnchors body_anchors(const std::vector<float>& rest_positions, double fraction) {
  const size_t vertices = rest_positions.size() / 3;
  if (vertices < 3 || rest_positions.size() % 3 != 0)
    throw std::invalid_argument("body_anchors: need at least 3 vertices, got " +
                                std::to_string(rest_positions.size()) + " floats");
  if (!(fraction > 0.0 && fraction <= 1.0))
    throw std::invalid_argument("body_anchors: fraction must be in (0, 1]");
  std::vector<uint32_t> order(vertices);
  std::iota(order.begin(), order.end(), 0u);
  std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
    return rest_positions[3 * size_t(a) + 1] > rest_positions[3 * size_t(b) + 1];
  });
  const size_t count =
      std::min(vertices, std::max<size_t>(3, size_t(std::lround(fraction * double(vertices)))));
  order.resize(count);
  std::sort(order.begin(), order.end());
  BodyAnchors a;
  a.vertices = order;
  a.reference.resize(3, Eigen::Index(count));
  for (size_t k = 0; k < count; ++k)
    for (int c = 0; c < 3; ++c)
      a.reference(c, Eigen::Index(k)) = rest_positions[3 * size_t(order[k]) + size_t(c)];
  return a;
}

std::vector<float> fit_body_frames(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                                   const BodyAnchors& anchors) {
  const size_t n = size_t(vertex_count) * 3;
  for (uint32_t v : anchors.vertices)
    if (v >= vertex_count)
      throw std::invalid_argument("fit_body_frames: anchor " + std::to_string(v) +
                                  " beyond the frames' " + std::to_string(vertex_count) +
                                  " vertices");
  std::vector<float> out(size_t(frame_count) * 12);
  Eigen::Matrix3Xd now(3, Eigen::Index(anchors.vertices.size()));
  for (uint32_t f = 0; f < frame_count; ++f) {
    const float* x = frames + size_t(f) * n;
    for (size_t k = 0; k < anchors.vertices.size(); ++k)
      for (int c = 0; c < 3; ++c)
        now(c, Eigen::Index(k)) = x[3 * size_t(anchors.vertices[k]) + size_t(c)];
    const RigidFrame r = fit_rigid(anchors.reference, now);
    float* t = out.data() + size_t(f) * 12;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) t[3 * i + j] = float(r.rotation(i, j));
    for (int i = 0; i < 3; ++i) t[9 + i] = float(r.translation(i));
  }
  return out;
}

void to_body_frame(float* frames, uint32_t frame_count, uint32_t vertex_count,
                   const float* transforms) {
  const size_t n = size_t(vertex_count) * 3;
  std::vector<double> body(n);
  for (uint32_t f = 0; f < frame_count; ++f) {
    float* x = frames + size_t(f) * n;
    codec::to_body_frame(transforms + size_t(f) * 12, x, n, body.data());
    for (size_t i = 0; i < n; ++i) x[i] = float(body[i]);
  }
}

}  // namespace clothdb
