#include "report/stats.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace clothdb::report {

double percentile(std::vector<double> values, double p) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  const double n = double(values.size());
  const double rank = std::ceil(std::clamp(p, 0.0, 1.0) * n);  // 1-based nearest rank
  const size_t k = size_t(std::clamp(rank, 1.0, n)) - 1;
  std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(k), values.end());
  return values[k];
}

}  // namespace clothdb::report
