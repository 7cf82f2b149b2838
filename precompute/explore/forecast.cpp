#include "explore/forecast.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace clothdb {

namespace {

// Fewest curve points in the last half that a fit of two parameters is made from.
constexpr size_t kFewestPoints = 4;

double open_ways_out(const CurvePoint& p) {
  return p.dead_ends + p.unexplored;
}

}  // namespace

Forecast forecast_convergence(const std::vector<CurvePoint>& curve, double cpu_before) {
  Forecast f;
  if (curve.empty()) {
    f.why = "no curve";
    return f;
  }
  const CurvePoint& last = curve.back();
  f.made_at = cpu_before + last.cpu_seconds;
  if (last.dead_ends == 0) {
    f.converging = f.converged = true;
    f.cpu_seconds = f.made_at;
    f.model = "converged: no dead end left";
    return f;
  }
  // Least squares of y = a + b t over the last half of this run's curve.
  double n = 0, st = 0, sy = 0, stt = 0, sty = 0;
  double first_y = -1, t0 = 0;
  for (const CurvePoint& p : curve) {
    if (p.cpu_seconds < last.cpu_seconds / 2) continue;
    const double t = cpu_before + p.cpu_seconds, y = open_ways_out(p);
    if (first_y < 0) first_y = y, t0 = t;
    n += 1;
    st += t;
    sy += y;
    stt += t * t;
    sty += t * y;
  }
  const double spread = n * stt - st * st;
  char text[256];
  if (n < kFewestPoints || !(spread > 0)) {
    std::snprintf(text, sizeof text, "%.0f batches in the last half of the run", n);
    f.why = text;
    f.too_few = true;
    return f;
  }
  const double b = (n * sty - st * sy) / spread, a = (sy - b * st) / n;
  if (!(b < 0)) {
    std::snprintf(text, sizeof text,
                  "dead ends + unexplored ways out went from %.0f to %.0f over the last half of "
                  "the run (%.2f to %.2f CPU-h); the fitted trend does not fall",
                  first_y, open_ways_out(last), t0 / 3600, f.made_at / 3600);
    f.why = text;
    return f;
  }
  f.converging = true;
  // y = 0: no way out left.
  f.cpu_seconds = std::max(f.made_at, -a / b);
  std::snprintf(text, sizeof text,
                "linear decline of dead ends + unexplored ways out fitted on the last half of the "
                "run, %.0f fewer per CPU-h",
                -b * 3600);
  f.model = text;
  return f;
}

std::string forecast_text(const Forecast& f) {
  char text[512];
  if (f.converging)
    std::snprintf(text, sizeof text, "%.3g CPU-h to converge (model %s, made at %.3g CPU-h)",
                  f.cpu_seconds / 3600, f.model.c_str(), f.made_at / 3600);
  else
    std::snprintf(text, sizeof text, "none: %s (%s)",
                  f.too_few ? "too few batches to fit" : "not converging", f.why.c_str());
  return text;
}

}  // namespace clothdb
