// The forecast of the CPU time an exploration needs to converge (no dead end left), made from the
// curve of the run so far, with a band. This project's, not Kim et al.'s, who report the error
// against CPU time but no forecast. Every forecast the tool prints or stores (the progress line,
// `precompute`'s summary, meta forecast and `db info`, the curve's CSV, `clothdb forecast`) comes
// from forecast_convergence.
//
// Model: the number of open ways out, y = dead ends + unexplored ways out (an unexplored one
// counts twice: it is a dead end, and its node has yet to gain the states that will resolve its
// neighbours), falls linearly with CPU time, y = a + b t, fitted by least squares over the last
// half of the run's curve (by CPU time); convergence is where the line reaches 0. Linear because
// Kim et al.'s exploration is a branching process run at a fixed rate: a fixed batch of jobs per
// unit of CPU, each closing one way out and opening as many as its end node has when its end does
// not link, so y changes by about (share not linked x ways out per state - 1) per job, a constant
// while the share linked changes slowly. The last half, because the first half holds the rise
// while new nodes are reached.
//
// Band: the times where the fit's prediction band, the line +- 2 standard deviations of a new
// point (the residuals' spread, widened by the slope's and the level's uncertainty: the ordinary
// least-squares prediction interval), reaches 0. It is open above (no end) when the band's upper
// edge never falls to 0, i.e. when the fall is not clear of the batches' scatter. Measured on the
// committed curves in docs/notebook/convergence.md ("The forecast").
#pragma once

#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

// Fewest curve points in the last half of the run that a forecast is fitted on.
inline constexpr size_t kForecastFewestPoints = 4;

// cpu_before: CPU seconds of the file's earlier runs (the curve's cpu_seconds are this run's).
// None (converging false, with why) when the fitted trend does not fall, or (too_few) when fewer
// than kForecastFewestPoints curve points lie in the last half.
Forecast forecast_convergence(const std::vector<CurvePoint>& curve, double cpu_before);

// What `precompute` prints and `db info` shows after "forecast  ": "N CPU-h to converge (band
// L-H CPU-h; model ..., made at X CPU-h)" when the band is within 10 % of N, "L-H CPU-h to
// converge (N on the trend; model ...)" when it is wider, "at least L CPU-h to converge (...)"
// when it is open above, "none: not converging (...)" or "none: too few batches to fit (...)".
std::string forecast_text(const Forecast& forecast);

// The forecasts a run made, replayed from its curves (as `precompute --curve` wrote them, read by
// read_curve_csv): `runs` in the order they ran, each later one a resume of the file the earlier
// ones made (its first point's frames are the last point's of the run before; throws
// std::runtime_error naming the run otherwise). One entry per curve point: the forecast made from
// that run's curve up to the point, with the earlier runs' CPU before it. What `clothdb forecast`
// prints, and how a curve written by an older model is re-derived with this one.
struct ReplayedForecast {
  size_t run = 0, point = 0;  // which curve, which of its points
  double cpu_seconds = 0;     // the whole exploration's, at the point
  Forecast forecast;
};
std::vector<ReplayedForecast> replay_forecasts(const std::vector<std::vector<CurvePoint>>& runs);

// The forecast as the progress line shows it: "converges at N CPU-h", "L-H CPU-h", "none".
std::string forecast_short_text(const Forecast& forecast);

}  // namespace clothdb
