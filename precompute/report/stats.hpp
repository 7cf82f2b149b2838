// The one percentile every benchmark and report uses (docs/RESULTS.md states it): the
// nearest-rank definition, pXX = the value at rank ceil(XX/100 * n) of the n values sorted
// ascending (rank 1 for p = 0). It is always one of the measured values, never an interpolation,
// so "p99 strain 2.5 %" names an edge-frame that was measured.
#pragma once

#include <cstddef>
#include <vector>

namespace clothdb::report {

// p in [0, 1]. NaN for no values. Takes the values by value (pass std::move(v) when they are no
// longer needed): O(n) by selection, not a full sort.
double percentile(std::vector<double> values, double p);

// percentile(values, 0.5).
inline double median(std::vector<double> values) {
  return percentile(std::move(values), 0.5);
}

}  // namespace clothdb::report
