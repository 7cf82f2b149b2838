// The forecast of the CPU time an exploration needs to converge (no dead end left), made from the
// curve of the run so far. This project's, not Kim et al.'s, who report the error against CPU time
// but no forecast.
//
// Model: the number of open ways out, y = dead ends + unexplored ways out (an unexplored one
// counts twice: it is a dead end, and its node has yet to gain the states that will resolve its
// neighbours), decays exponentially with CPU time, y = A exp(b t), fitted by least squares on
// ln y over the last half of the run's curve (by CPU time). Exponential because each batch closes
// a share of the open ways out that grows as the states fill each node's space: measured on the
// demo (docs/notebook/convergence.md), ln y falls close to linearly once y has peaked, while a
// power law (straight in ln t) bends away. The last half, because the first half holds the rise
// while new nodes are reached. Convergence is when the fit drops below half a way out.
#pragma once

#include <string>
#include <vector>

#include "explore/explorer.hpp"

namespace clothdb {

// cpu_before: CPU seconds of the file's earlier runs (the curve's cpu_seconds are this run's).
// None (converging false, with why) when the fitted trend does not fall, or (too_few) when fewer
// than 4 curve points lie in the last half.
Forecast forecast_convergence(const std::vector<CurvePoint>& curve, double cpu_before);

// What `precompute` prints and `db info` shows after "forecast  ": "N CPU-h to converge (model
// ..., made at X CPU-h)", "none: not converging (...)" or "none: too few batches to fit (...)".
std::string forecast_text(const Forecast& forecast);

}  // namespace clothdb
