// Progress: the curve of the run (one point per batch), the progress bar, and the run's notes.
// Kim et al. 2013 plot the unresolved error against CPU time; the rest is this project's.
#pragma once

#include <chrono>
#include <string>
#include <vector>

#include "explore/dead_ends.hpp"
#include "explore/explorer.hpp"
#include "explore/secondary_graph.hpp"

namespace clothdb {

// The curve's point after a batch (or at the start), with `queue` the dead ends left.
CurvePoint curve_point(const SecondaryGraph& sg, const ExploreGraph& graph,
                       const std::vector<Job>& queue, const ExploreReport& report);

// Appends a curve point with the forecast made from the curve so far (explore/forecast.hpp).
// Returns that forecast (the progress line prints it).
Forecast add_curve_point(ExploreReport& report, const CurvePoint& point);

// The progress bar on stderr (when options.progress): frames, states, dead ends, worst error, CPU
// time and the time left, from the budget or, without one, from the dead ends at the current pace.
class ProgressBar {
 public:
  explicit ProgressBar(const ExploreOptions& options) : options_(options) {}
  // `forecast`: the one add_curve_point made from the curve's last point.
  void update(const ExploreReport& report, const Forecast& forecast, size_t clips_done,
              size_t dead_ends) const;
  void end() const;

 private:
  const ExploreOptions& options_;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

// The run's notes in the run table: converged or dead ends left, the errors, the links.
std::string run_notes(const ExploreReport& report, size_t dead_ends_left);

}  // namespace clothdb
