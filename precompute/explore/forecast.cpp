#include "explore/forecast.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

namespace clothdb {

namespace {

// Standard deviations of the prediction band (about 95 % for Gaussian residuals).
constexpr double kBandSigmas = 2;
// A band within this share of the forecast is printed as a figure with its band; a wider one as
// the band itself.
constexpr double kNarrowBand = 0.1;

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
    f.cpu_seconds = f.low_cpu_seconds = f.high_cpu_seconds = f.made_at;
    f.model = "converged: no dead end left";
    return f;
  }
  // Least squares of y = a + b t over the last half of this run's curve, centred on the means
  // (t in the whole exploration's CPU seconds).
  std::vector<std::pair<double, double>> window;
  for (const CurvePoint& p : curve)
    if (p.cpu_seconds >= last.cpu_seconds / 2)
      window.emplace_back(cpu_before + p.cpu_seconds, open_ways_out(p));
  const double n = static_cast<double>(window.size());
  double mean_t = 0, mean_y = 0;
  for (const auto& [t, y] : window) mean_t += t / n, mean_y += y / n;
  double stt = 0, sty = 0;
  for (const auto& [t, y] : window)
    stt += (t - mean_t) * (t - mean_t), sty += (t - mean_t) * (y - mean_y);
  char text[256];
  if (window.size() < kForecastFewestPoints || !(stt > 0)) {
    std::snprintf(text, sizeof text, "%zu batches in the last half of the run", window.size());
    f.why = text;
    f.too_few = true;
    return f;
  }
  const double b = sty / stt, a = mean_y - b * mean_t;
  if (!(b < 0)) {
    std::snprintf(text, sizeof text,
                  "dead ends + unexplored ways out went from %.0f to %.0f over the last half of "
                  "the run (%.2f to %.2f CPU-h); the fitted trend does not fall",
                  window.front().second, open_ways_out(last), window.front().first / 3600,
                  f.made_at / 3600);
    f.why = text;
    return f;
  }
  f.converging = true;
  // y = 0: no way out left.
  f.cpu_seconds = std::max(f.made_at, -a / b);
  // The band: t where (a + b t)^2 = k (1 + 1/n + (t - mean_t)^2 / stt), k = (z s)^2 with s^2 the
  // residual variance (n - 2 degrees of freedom): the ordinary least-squares prediction interval
  // of a new point at t, inverted for y = 0. A quadratic in t, A t^2 + B t + C = 0.
  double ssr = 0;
  for (const auto& [t, y] : window) ssr += (y - a - b * t) * (y - a - b * t);
  const double k = kBandSigmas * kBandSigmas * ssr / (n - 2);
  const double qa = b * b - k / stt, qb = 2 * a * b + 2 * k * mean_t / stt,
               qc = a * a - k * (1 + 1 / n) - k * mean_t * mean_t / stt;
  const double disc = qb * qb - 4 * qa * qc;
  if (qa > 0 && disc >= 0) {
    const double r1 = (-qb - std::sqrt(disc)) / (2 * qa), r2 = (-qb + std::sqrt(disc)) / (2 * qa);
    f.low_cpu_seconds = std::max(f.made_at, std::min(r1, r2));
    f.high_cpu_seconds = std::max(f.cpu_seconds, std::max(r1, r2));
  } else {
    // The slope is not clear of the scatter: the band's upper edge never reaches 0.
    f.low_cpu_seconds = f.made_at;
    if (qa < 0 && disc >= 0) {
      // The band clears 0 only between the roots: its lower edge reaches 0 at the later one.
      const double r =
          std::max((-qb - std::sqrt(disc)) / (2 * qa), (-qb + std::sqrt(disc)) / (2 * qa));
      if (std::isfinite(r)) f.low_cpu_seconds = std::clamp(r, f.made_at, f.cpu_seconds);
    }
    f.high_cpu_seconds = std::numeric_limits<double>::infinity();
  }
  f.low_cpu_seconds = std::min(f.low_cpu_seconds, f.cpu_seconds);
  std::snprintf(text, sizeof text,
                "linear decline of dead ends + unexplored ways out fitted on the last half of the "
                "run, %.0f fewer per CPU-h, band +-%.0f sigma of its %zu batches",
                -b * 3600, kBandSigmas, window.size());
  f.model = text;
  return f;
}

std::vector<ReplayedForecast> replay_forecasts(const std::vector<std::vector<CurvePoint>>& runs) {
  std::vector<ReplayedForecast> out;
  double before = 0;
  for (size_t r = 0; r < runs.size(); ++r) {
    const std::vector<CurvePoint>& curve = runs[r];
    if (curve.empty())
      throw std::runtime_error("run " + std::to_string(r + 1) + ": no curve points");
    if (r > 0 && curve.front().frames != runs[r - 1].back().frames)
      throw std::runtime_error("run " + std::to_string(r + 1) + " starts with " +
                               std::to_string(curve.front().frames) + " frames stored, but run " +
                               std::to_string(r) + " ended with " +
                               std::to_string(runs[r - 1].back().frames) +
                               ": not a resume of it (give the curves in the order they ran)");
    std::vector<CurvePoint> so_far;
    for (size_t k = 0; k < curve.size(); ++k) {
      so_far.push_back(curve[k]);
      ReplayedForecast f;
      f.run = r;
      f.point = k;
      f.cpu_seconds = before + curve[k].cpu_seconds;
      f.forecast = forecast_convergence(so_far, before);
      out.push_back(std::move(f));
    }
    before += curve.back().cpu_seconds;
  }
  return out;
}

std::string forecast_text(const Forecast& f) {
  char text[640];
  const double n = f.cpu_seconds / 3600, lo = f.low_cpu_seconds / 3600,
               hi = f.high_cpu_seconds / 3600, made = f.made_at / 3600;
  if (!f.converging)
    std::snprintf(text, sizeof text, "none: %s (%s)",
                  f.too_few ? "too few batches to fit" : "not converging", f.why.c_str());
  else if (f.converged)
    std::snprintf(text, sizeof text, "%.3g CPU-h to converge (model %s, made at %.3g CPU-h)", n,
                  f.model.c_str(), made);
  else if (!std::isfinite(hi))
    std::snprintf(text, sizeof text,
                  "at least %.3g CPU-h to converge (%.3g on the trend, no upper end: the fall is "
                  "not clear of the scatter; model %s, made at %.3g CPU-h)",
                  lo, n, f.model.c_str(), made);
  else if (hi - n <= kNarrowBand * n && n - lo <= kNarrowBand * n)
    std::snprintf(text, sizeof text,
                  "%.3g CPU-h to converge (band %.3g-%.3g CPU-h; model %s, made at %.3g CPU-h)", n,
                  lo, hi, f.model.c_str(), made);
  else
    std::snprintf(text, sizeof text,
                  "%.3g-%.3g CPU-h to converge (%.3g on the trend; model %s, made at %.3g CPU-h)",
                  lo, hi, n, f.model.c_str(), made);
  return text;
}

std::string forecast_short_text(const Forecast& f) {
  char text[96];
  if (!f.converging) return f.too_few ? "none yet" : "none (not falling)";
  if (f.converged) return "converged";
  if (!std::isfinite(f.high_cpu_seconds))
    std::snprintf(text, sizeof text, ">= %.3g CPU-h", f.low_cpu_seconds / 3600);
  else
    std::snprintf(text, sizeof text, "%.3g CPU-h (%.3g-%.3g)", f.cpu_seconds / 3600,
                  f.low_cpu_seconds / 3600, f.high_cpu_seconds / 3600);
  return text;
}

}  // namespace clothdb
