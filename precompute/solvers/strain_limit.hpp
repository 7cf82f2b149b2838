// The strain limit's rule for one over-long edge, shared by XPBD's passes (xpbd.cpp, shorten_edge)
// and the coarse-driven garment's projection of its fine edges (upsampled.cpp).
#pragma once

#include <algorithm>

namespace clothdb {

// The length an edge of length `len` > `limit` is projected to (Provot 1995 sec. 5, the
// "deformation rate" limit as a position projection). With relax > 1 it is shortened past the
// limit by (relax - 1) times its excess, never below its rest length `floor`: projected successive
// over-relaxation (Cryer 1971, "The solution of a quadratic programming problem using systematic
// overrelaxation") of the unilateral constraints, so a correction that must travel along many
// edges (a ring pushed out by a limb) takes fewer passes (docs/notebook/resolution.md).
inline double strain_limit_target(double len, double limit, double floor, double relax) {
  return std::max(limit - (relax - 1.0) * (len - limit), floor);
}

}  // namespace clothdb
