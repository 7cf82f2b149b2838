#include "database/codec/contract.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace clothdb::codec {

ContractFigures measure_contract(const float* decoded, const float* original, uint32_t frame_count,
                                 uint32_t vertex_count) {
  ContractFigures out;
  const size_t n = size_t(vertex_count) * 3;
  double max2 = 0, jitter2 = 0;
  for (uint32_t f = 0; f < frame_count; ++f) {
    const float* d = decoded + size_t(f) * n;
    const float* o = original + size_t(f) * n;
    double sum2 = 0;
    for (uint32_t v = 0; v < vertex_count; ++v) {
      double e2 = 0;
      for (int a = 0; a < 3; ++a) {
        const double e = double(d[3 * v + a]) - double(o[3 * v + a]);
        e2 += e * e;
      }
      sum2 += e2;
      max2 = std::max(max2, e2);
    }
    out.rms = std::max(out.rms, vertex_count ? std::sqrt(sum2 / vertex_count) : 0.0);
    if (f < 1 || f + 1 >= frame_count) continue;
    // Second difference of the error at frame f: (e[f+1] - 2 e[f] + e[f-1]).
    const float *dp = d - n, *dn = d + n, *op = o - n, *on = o + n;
    for (size_t i = 0; i < n; i += 3) {
      double j2 = 0;
      for (size_t a = 0; a < 3; ++a) {
        const double j = (double(dn[i + a]) - double(on[i + a])) -
                         2 * (double(d[i + a]) - double(o[i + a])) +
                         (double(dp[i + a]) - double(op[i + a]));
        j2 += j * j;
      }
      jitter2 = std::max(jitter2, j2);
    }
  }
  out.max = std::sqrt(max2);
  out.jitter = std::sqrt(jitter2);
  return out;
}

bool within(const ContractFigures& f, const Contract& c, double tolerance) {
  const double k = 1 + tolerance;
  return (c.rms <= 0 || f.rms <= c.rms * k) && (c.max <= 0 || f.max <= c.max * k) &&
         (c.jitter <= 0 || f.jitter <= c.jitter * k);
}

std::string describe(const ContractFigures& f) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "RMS %.3g / max %.3g / jitter %.3g mm", f.rms * 1e3, f.max * 1e3,
                f.jitter * 1e3);
  return buf;
}

}  // namespace clothdb::codec
