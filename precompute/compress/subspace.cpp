#include "compress/subspace.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

namespace clothdb {
namespace {

// Orthonormal basis of the columns of y (thin Q of a Householder QR).
Eigen::MatrixXd orthonormalise(const Eigen::MatrixXd& y) {
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(y);
  return qr.householderQ() * Eigen::MatrixXd::Identity(y.rows(), y.cols());
}

// Standard normal numbers by Box-Muller from mt19937_64's raw output, so the sequence does not
// depend on the standard library's distribution implementation.
double normal(std::mt19937_64& rng) {
  const double u1 = (double(rng() >> 11) + 0.5) * 0x1.0p-53;
  const double u2 = double(rng() >> 11) * 0x1.0p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}

}  // namespace

Subspace build_subspace(const std::vector<float>& frames, uint32_t coordinates, uint32_t modes,
                        uint64_t seed) {
  if (coordinates == 0 || frames.empty() || frames.size() % coordinates != 0)
    throw std::invalid_argument("subspace: " + std::to_string(frames.size()) +
                                " values are not whole frames of " + std::to_string(coordinates));
  const size_t n = coordinates;
  const size_t N = frames.size() / n;
  for (float v : frames)
    if (!std::isfinite(v)) throw std::invalid_argument("subspace: non-finite frame value");
  Subspace s;
  s.coordinates = coordinates;
  // Centred sample A (n x N), in double: the range finder's products lose little in float, but
  // the sample is small enough (a few thousand frames) that double costs only memory.
  Eigen::Map<const Eigen::MatrixXf> x(frames.data(), Eigen::Index(n), Eigen::Index(N));
  const Eigen::VectorXd mean = x.cast<double>().rowwise().mean();
  Eigen::MatrixXd a = x.cast<double>().colwise() - mean;
  s.mean.resize(n);
  for (size_t i = 0; i < n; ++i) s.mean[i] = float(mean[Eigen::Index(i)]);
  const double total = a.squaredNorm();
  s.sample_rms = std::sqrt(total / double(n * N));
  const uint32_t rank = uint32_t(std::min<size_t>({n, N > 1 ? N - 1 : 0, size_t(modes)}));
  s.modes = rank;
  if (rank == 0) {
    s.residual_rms = s.sample_rms;
    return s;
  }
  // Range finder with oversampling and two power iterations (the singular values of cloth decay
  // slowly, and the power iterations sharpen the top of the spectrum).
  const Eigen::Index l = Eigen::Index(std::min<size_t>(std::min(n, N), size_t(rank) + 16));
  std::mt19937_64 rng(seed);
  Eigen::MatrixXd omega(Eigen::Index(N), l);
  for (Eigen::Index j = 0; j < l; ++j)
    for (Eigen::Index i = 0; i < Eigen::Index(N); ++i) omega(i, j) = normal(rng);
  Eigen::MatrixXd q = orthonormalise(a * omega);
  for (int it = 0; it < 2; ++it) {
    const Eigen::MatrixXd z = orthonormalise(a.transpose() * q);
    q = orthonormalise(a * z);
  }
  // A ~ Q B with B = Q^T A (l x N); the left singular vectors of B, through the eigenvectors of
  // B B^T (l x l), give A's: U = Q U_B.
  const Eigen::MatrixXd b = q.transpose() * a;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(b * b.transpose());
  const Eigen::VectorXd values = eig.eigenvalues();  // ascending
  const Eigen::MatrixXd u = q * eig.eigenvectors();
  s.basis.resize(size_t(rank) * n);
  s.singular.resize(rank);
  double captured = 0;
  for (uint32_t k = 0; k < rank; ++k) {
    const Eigen::Index col = l - 1 - Eigen::Index(k);
    const double value = std::max(0.0, values[col]);
    s.singular[k] = std::sqrt(value);
    captured += value;
    // Sign convention: the largest component positive, so the basis does not depend on the
    // eigen solver's arbitrary signs.
    Eigen::Index big = 0;
    u.col(col).cwiseAbs().maxCoeff(&big);
    const double sign = u(big, col) < 0 ? -1.0 : 1.0;
    for (size_t i = 0; i < n; ++i)
      s.basis[size_t(k) * n + i] = float(sign * u(Eigen::Index(i), col));
  }
  s.residual_rms = std::sqrt(std::max(0.0, total - captured) / double(n * N));
  return s;
}

}  // namespace clothdb
