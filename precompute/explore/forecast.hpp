// The forecast of the CPU time an exploration needs to converge (no dead end left), made from the
// curve of the run so far. This project's, not Kim et al.'s, who report the error against CPU time
// but no forecast.
//
// Model: the number of open ways out, y = dead ends + unexplored ways out (an unexplored one
// counts twice: it is a dead end, and its node has yet to gain the states that will resolve its
// neighbours), falls linearly with CPU time, y = a + b t, fitted by least squares over the last
// half of the run's curve (by CPU time); convergence is where the line reaches 0. Linear because
// Kim et al.'s exploration is a branching process run at a fixed rate: a fixed batch of jobs per
// unit of CPU, each closing one way out and opening as many as its end node has when its end does
// not link, so y changes by about (share not linked x ways out per state - 1) per job, a constant
// while the share linked changes slowly. Measured on the whole-motion run
// (docs/notebook/convergence.md): made at half the run, the line was within 14 % of the CPU time
// the run took, an exponential fit of the same points 4.8x over it. The last half, because the
// first half holds the rise while new nodes are reached.
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
