#include "explore/forecast.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

namespace clothdb {

namespace {

// Half-width of the prediction band in standard deviations: the two-sided 95 % quantile of
// Student's t with `dof` degrees of freedom (residuals less the fitted coefficients), so that a fit
// through 4 or 5 batches (the demo's) does not claim a band it cannot know; about 2 from 30 on.
double band_sigmas(size_t dof) {
  static constexpr double kT975[] = {12.71, 4.30, 3.18, 2.78, 2.57, 2.45, 2.36, 2.31, 2.26, 2.23};
  if (dof == 0) return std::numeric_limits<double>::infinity();
  return dof <= 10 ? kT975[dof - 1] : 1.96 + 2.4 / static_cast<double>(dof);
}
// The curve counts whole ways out: a fit cannot know them better than their rounding, whose
// variance is 1/12 (uniform over one), however well it passes through a few points.
constexpr double kRoundingVariance = 1.0 / 12;
// The fit bends (a parabola) only when its bend is at least this many standard errors clear of
// zero: on a straight decline a free bend would only widen the band.
constexpr double kBendStandardErrors = 2;
// A band within this share of the forecast is printed as a figure with its band; a wider one as
// the band itself.
constexpr double kNarrowBand = 0.1;
// How far past the last point the band's edges are looked for, in window spans (clips of the
// fitted window): an edge not reached by then leaves the band open above.
constexpr double kBandReachSpans = 50;
constexpr int kBandStepsPerSpan = 200;

double open_ways_out(const CurvePoint& p) {
  return p.dead_ends + p.unexplored;
}

// A least-squares fit of y = sum_j beta_j v^j (j < terms, terms 2 or 3) with the inverse of its
// normal matrix, for the prediction band.
struct Fit {
  int terms = 0;
  Eigen::VectorXd beta;
  Eigen::MatrixXd inverse;  // (X^T X)^-1
  double residual_variance = 0;
  static Eigen::VectorXd powers(double v, int terms) {
    Eigen::VectorXd g(terms);
    for (int j = 0; j < terms; ++j) g[j] = j == 0 ? 1.0 : g[j - 1] * v;
    return g;
  }
  double at(double v) const { return powers(v, terms).dot(beta); }
  double slope(double v) const { return beta[1] + (terms == 3 ? 2 * beta[2] * v : 0); }
  // Standard deviation of a new point at v (ordinary least-squares prediction interval).
  double sigma(double v) const {
    const Eigen::VectorXd g = powers(v, terms);
    return std::sqrt(residual_variance * (1 + g.dot(inverse * g)));
  }
};

// False when the normal matrix is singular (every point at one v).
bool fit(const std::vector<std::pair<double, double>>& points, int terms, Fit& f) {
  Eigen::MatrixXd X(static_cast<Eigen::Index>(points.size()), terms);
  Eigen::VectorXd y(X.rows());
  for (Eigen::Index i = 0; i < X.rows(); ++i) {
    X.row(i) = Fit::powers(points[static_cast<size_t>(i)].first, terms).transpose();
    y[i] = points[static_cast<size_t>(i)].second;
  }
  const Eigen::FullPivLU<Eigen::MatrixXd> normal(X.transpose() * X);
  if (!normal.isInvertible()) return false;
  f.terms = terms;
  f.inverse = normal.inverse();
  f.beta = f.inverse * (X.transpose() * y);
  f.residual_variance = std::max(
      kRoundingVariance, (y - X * f.beta).squaredNorm() /
                             static_cast<double>(points.size() - static_cast<size_t>(terms)));
  return true;
}

// The first v in [from, to] where edge(v) <= 0 (to the step, then bisected), or NaN.
template <typename Edge>
double first_zero(Edge edge, double from, double to, double step) {
  if (edge(from) <= 0) return from;
  for (double lo = from; lo < to; lo += step) {
    double hi = std::min(lo + step, to);
    if (edge(hi) > 0) continue;
    double a = lo;
    for (int k = 0; k < 40; ++k) {
      const double mid = (a + hi) / 2;
      (edge(mid) > 0 ? a : hi) = mid;
    }
    return hi;
  }
  return std::numeric_limits<double>::quiet_NaN();
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
  // The window: the points of the last half of this run's clips. v: clips made, relative to the
  // window's mean, in window spans (so that the normal matrix stays well conditioned).
  const double first_clips = static_cast<double>(curve.front().clips),
               half = (static_cast<double>(last.clips) - first_clips) / 2;
  std::vector<const CurvePoint*> window;
  for (const CurvePoint& p : curve)
    if (static_cast<double>(p.clips) - first_clips >= half) window.push_back(&p);
  const double span = static_cast<double>(last.clips - window.front()->clips);
  char text[320];
  if (window.size() < kForecastFewestPoints || !(span > 0)) {
    std::snprintf(text, sizeof text, "%zu batches in the last half of the run's clips",
                  window.size());
    f.why = text;
    f.too_few = true;
    return f;
  }
  double mean_clips = 0;
  for (const CurvePoint* p : window)
    mean_clips += static_cast<double>(p->clips) / static_cast<double>(window.size());
  std::vector<std::pair<double, double>> points;
  for (const CurvePoint* p : window)
    points.emplace_back((static_cast<double>(p->clips) - mean_clips) / span, open_ways_out(*p));
  const double v_last = (static_cast<double>(last.clips) - mean_clips) / span;
  // The parabola when it bends down clearly (kBendStandardErrors); else the line (a bend up is
  // scatter: the change per clip does not grow, see the header).
  Fit trend;
  if (!fit(points, 3, trend) ||
      !(trend.beta[2] < 0 &&
        -trend.beta[2] >=
            kBendStandardErrors * std::sqrt(trend.residual_variance * trend.inverse(2, 2))))
    fit(points, 2, trend);
  // The trend's zero past the last point: no way out left.
  double v_end = v_last;
  if (trend.slope(v_last) < 0 && trend.at(v_last) > 0) {
    const double a = trend.beta[0], b = trend.beta[1];
    if (trend.terms == 2) {
      v_end = -a / b;
    } else {
      const double c = trend.beta[2];  // < 0, with a falling slope and a positive value at v_last
      v_end = (-b - std::sqrt(b * b - 4 * a * c)) / (2 * c);
    }
  }
  if (!(trend.slope(v_last) < 0) || !(v_end <= v_last + kBandReachSpans)) {
    std::snprintf(text, sizeof text,
                  "dead ends + unexplored ways out went from %.0f to %.0f over the last half of "
                  "the run's clips (%ld to %ld clips); %s",
                  points.front().second, open_ways_out(last), window.front()->clips, last.clips,
                  trend.slope(v_last) < 0
                      ? "the fitted trend falls too slowly to reach 0 within 50 times that window"
                      : "the fitted trend does not fall at the last batch");
    f.why = text;
    return f;
  }
  f.converging = true;
  // CPU seconds per window span of clips, measured over the window.
  const double cpu_per_span = last.cpu_seconds - window.front()->cpu_seconds;
  auto cpu_at = [&](double v) { return f.made_at + (v - v_last) * cpu_per_span; };
  f.cpu_seconds = cpu_at(std::max(v_end, v_last));
  // The band: where the prediction band's lower edge, and its upper edge, first reach 0.
  const double sigmas = band_sigmas(window.size() - static_cast<size_t>(trend.terms));
  const double reach = v_last + kBandReachSpans, step = 1.0 / kBandStepsPerSpan;
  const double low = first_zero([&](double v) { return trend.at(v) - sigmas * trend.sigma(v); },
                                v_last, reach, step);
  const double high = first_zero([&](double v) { return trend.at(v) + sigmas * trend.sigma(v); },
                                 v_last, reach, step);
  f.low_cpu_seconds = std::isnan(low) ? f.made_at : std::min(cpu_at(low), f.cpu_seconds);
  f.high_cpu_seconds = std::isnan(high) ? std::numeric_limits<double>::infinity()
                                        : std::max(cpu_at(high), f.cpu_seconds);
  std::snprintf(
      text, sizeof text,
      "dead ends + unexplored ways out against clips made, a %s fitted on the last half "
      "of the run's clips, %.0f fewer per CPU-h at the last batch, band +-%.2g sigma (95 %%) "
      "of its %zu batches",
      trend.terms == 3 ? "parabola bending down" : "line",
      -trend.slope(v_last) / cpu_per_span * 3600, sigmas, window.size());
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
