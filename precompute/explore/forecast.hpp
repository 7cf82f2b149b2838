// The forecast of the CPU time an exploration needs to converge (no dead end left), made from the
// curve of the run so far, with a band. This project's, not Kim et al.'s, who report the error
// against CPU time but no forecast. Every forecast the tool prints or stores (the progress line,
// `precompute`'s summary, meta forecast and `db info`, the curve's CSV, `clothdb forecast`) comes
// from forecast_convergence.
//
// Model: the number of open ways out, y = dead ends + unexplored ways out (an unexplored one
// counts twice: it is a dead end, and its node has yet to gain the states that will resolve its
// neighbours), against the clips made, C. Kim et al.'s exploration is a branching process: each
// clip closes one way out and, when its end does not link to a state within epsilon, makes a
// state that opens w ways out (w: ways out of its node), so y changes by w (1 - p) - 1 per clip,
// p the share of clip ends that link. p does not fall as the run goes on (each node gains states
// to link to), so this change per clip does not grow: y against C bends down or runs straight.
// The model lets it change linearly with C: y = a + b C + c C^2 with c < 0 when the fitted bend is
// at least 2 standard errors clear of zero, else a line (a bend up is scatter; a free bend on a
// straight decline only widens the band), fitted by least squares over the last half of the
// run's clips;
// convergence is where it reaches 0, turned into CPU time by the CPU per clip over that window.
// The last half, because the first half holds the rise while new nodes are reached. No forecast
// when the fitted trend does not fall at the last point (y still rising or flat: the process is
// not yet subcritical). Against clips rather than CPU time, because a batch's CPU time varies
// with its clips' lengths while the branching rule is per clip; and bending, because on a small
// run (the demo) the share linked climbs from about 10 % to 40 % within the run, so a line
// through the last half sees no fall at half the run. Measured on the committed curves and
// further runs in docs/notebook/convergence.md ("The forecast").
//
// Band: the clips (then CPU times) where the fit's 95 % prediction band, the trend +- t standard
// deviations of a new point (Student's t for the fit's degrees of freedom; the residuals' spread,
// at least the rounding of whole ways out, widened by the coefficients' uncertainty: the ordinary
// least-squares prediction interval), first reaches 0. It is open above (no end) when the band's
// upper edge does not reach 0 within 50 window spans, i.e. when the fall is not clear of the
// batches' scatter (as on the demo's 4-batch windows).
#pragma once

#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

// Fewest curve points in the last half of the run's clips that a forecast is fitted on.
inline constexpr size_t kForecastFewestPoints = 4;

// cpu_before: CPU seconds of the file's earlier runs (the curve's cpu_seconds are this run's).
// None (converging false, with why) when the fitted trend does not fall at the last point, or
// (too_few) when fewer than kForecastFewestPoints curve points lie in the last half of the run's
// clips.
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
