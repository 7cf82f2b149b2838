// A garment subspace for codec version 2 (docs/DATABASE.md, "version 2"): principal components of a
// database's own frames, as Kim et al. 2013 store a garment's shapes in a few hundred modes. Eigen
// lives here, in the precompute; the codec in database/ takes the result as plain floats
// (codec::Basis).
#pragma once

#include <cstdint>
#include <vector>

namespace clothdb {

struct Subspace {
  uint32_t coordinates = 0;  // 3V
  uint32_t modes = 0;
  std::vector<float> mean;       // 3V
  std::vector<float> basis;      // modes x 3V, mode-major, orthonormal
  std::vector<double> singular;  // of the centred sample, largest first (one per mode)
  double sample_rms = 0;         // RMS over the sample's coordinates of x - mean
  double residual_rms = 0;       // RMS of what the modes leave of the sample
};

// frames: frame_count x coordinates floats. Randomised SVD (range finder with 2 power iterations,
// Halko et al. 2011) of the centred frames; deterministic for a given seed. modes is clamped to
// the rank available (frame_count - 1 and coordinates). Throws std::invalid_argument on empty or
// non-finite input.
Subspace build_subspace(const std::vector<float>& frames, uint32_t coordinates, uint32_t modes,
                        uint64_t seed = 1);

}  // namespace clothdb
