#include "compress/predictability.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "compress/body_frame.hpp"
#include "compress/subspace.hpp"

namespace clothdb {

namespace {

constexpr double kPi = 3.14159265358979323846;

}  // namespace

PredictabilityReport analyse_predictability(const std::vector<float>& frames, uint32_t vertices,
                                            uint32_t frame_count,
                                            const std::vector<uint32_t>& clip_starts,
                                            const std::vector<uint32_t>& modes,
                                            const std::vector<double>& bounds,
                                            double anchor_fraction) {
  const std::size_t n = std::size_t(vertices) * 3;
  if (vertices == 0 || frame_count < 3 || frames.size() != n * frame_count)
    throw std::invalid_argument("analyse_predictability: need at least 3 frames of " +
                                std::to_string(vertices) + " vertices");
  if (modes.empty() || bounds.empty())
    throw std::invalid_argument("analyse_predictability: no mode counts or no bounds");
  for (float v : frames)
    if (!std::isfinite(v)) throw std::invalid_argument("analyse_predictability: non-finite frame");
  if (!(anchor_fraction > 0.0 && anchor_fraction <= 1.0))
    throw std::invalid_argument("analyse_predictability: anchor fraction must be in (0, 1]");

  const Eigen::Map<const Eigen::MatrixXf> xf(frames.data(), Eigen::Index(n), frame_count);
  const Eigen::MatrixXd x = xf.cast<double>();
  const Eigen::VectorXd mean = x.rowwise().mean();

  // Anchors: the vertices whose positions vary least (the pinned band and what moves with it).
  std::vector<double> variance(vertices, 0.0);
  for (uint32_t v = 0; v < vertices; ++v)
    variance[v] = (x.middleRows(3 * v, 3).colwise() - mean.segment<3>(3 * v)).squaredNorm();
  std::vector<uint32_t> order(vertices);
  std::iota(order.begin(), order.end(), 0u);
  const uint32_t anchor_count =
      std::max<uint32_t>(3, uint32_t(std::lround(anchor_fraction * vertices)));
  std::stable_sort(order.begin(), order.end(),
                   [&](uint32_t a, uint32_t b) { return variance[a] < variance[b]; });
  order.resize(std::min(anchor_count, vertices));

  PredictabilityReport report;
  report.bounds = bounds;
  report.anchors = uint32_t(order.size());
  Eigen::Matrix3Xd anchor_rest(3, order.size());
  for (std::size_t a = 0; a < order.size(); ++a)
    anchor_rest.col(Eigen::Index(a)) = mean.segment<3>(3 * order[a]);
  std::vector<RigidFrame> body(frame_count);
  Eigen::MatrixXd y(x.rows(), x.cols());  // body-relative frames: R^T (x - t)
  for (uint32_t f = 0; f < frame_count; ++f) {
    Eigen::Matrix3Xd anchor_now(3, order.size());
    for (std::size_t a = 0; a < order.size(); ++a)
      anchor_now.col(Eigen::Index(a)) = x.col(f).segment<3>(3 * order[a]);
    body[f] = fit_rigid(anchor_rest, anchor_now);
    const double c = std::clamp((body[f].rotation.trace() - 1.0) / 2.0, -1.0, 1.0);
    report.max_rotation_deg = std::max(report.max_rotation_deg, std::acos(c) * 180.0 / kPi);
    for (uint32_t v = 0; v < vertices; ++v)
      y.col(f).segment<3>(3 * v) =
          body[f].rotation.transpose() * (x.col(f).segment<3>(3 * v) - body[f].translation);
  }

  // A frame's temporal predictors may use frames f-1 and f-2 only within its own clip.
  std::vector<uint32_t> clip_offset(frame_count, 0);  // frames since the clip began
  {
    std::vector<char> starts(frame_count, 0);
    starts[0] = 1;
    for (uint32_t s : clip_starts)
      if (s < frame_count) starts[s] = 1;
    for (uint32_t f = 0; f < frame_count; ++f)
      clip_offset[f] = starts[f] ? 0 : clip_offset[f - 1] + 1;
  }

  const uint32_t largest = *std::max_element(modes.begin(), modes.end());
  for (const char* space : {"character", "body"}) {
    const bool is_body = std::string(space) == "body";
    const Eigen::MatrixXd& data = is_body ? y : x;
    std::vector<float> sample(data.size());
    Eigen::Map<Eigen::MatrixXf>(sample.data(), data.rows(), data.cols()) = data.cast<float>();
    const Subspace sub = build_subspace(sample, uint32_t(n), largest);
    const Eigen::Map<const Eigen::MatrixXf> basis_all(sub.basis.data(), Eigen::Index(n), sub.modes);
    const Eigen::Map<const Eigen::VectorXf> sub_mean(sub.mean.data(), Eigen::Index(n));
    const Eigen::MatrixXd centred = data.colwise() - sub_mean.cast<double>();
    for (uint32_t k : modes) {
      const uint32_t used = std::min(k, sub.modes);
      const Eigen::MatrixXd u = basis_all.leftCols(used).cast<double>();
      Eigen::MatrixXd residual = centred - u * (u.transpose() * centred);
      if (is_body)  // back to character space, where the bound applies
        for (uint32_t f = 0; f < frame_count; ++f)
          for (uint32_t v = 0; v < vertices; ++v)
            residual.col(f).segment<3>(3 * v) =
                body[f].rotation * residual.col(f).segment<3>(3 * v);
      PredictabilityRow row;
      row.space = space;
      row.modes = used;
      row.rms_left = std::sqrt(residual.squaredNorm() / double(residual.size()));
      for (double bound : bounds) {
        double as_is = 0, delta = 0, linear = 0, temporal = 0;
        for (uint32_t f = 0; f < frame_count; ++f) {
          as_is += double((residual.col(f).array().abs() <= bound).count());
          if (clip_offset[f] < 2) continue;
          temporal += double(n);
          delta += double(((residual.col(f) - residual.col(f - 1)).array().abs() <= bound).count());
          linear += double(
              ((residual.col(f) - 2.0 * residual.col(f - 1) + residual.col(f - 2)).array().abs() <=
               bound)
                  .count());
        }
        row.within_as_is.push_back(as_is / double(n * frame_count));
        row.within_delta.push_back(temporal > 0 ? delta / temporal : 0.0);
        row.within_linear.push_back(temporal > 0 ? linear / temporal : 0.0);
      }
      report.rows.push_back(std::move(row));
    }
  }
  return report;
}

}  // namespace clothdb
