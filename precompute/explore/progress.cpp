#include "explore/progress.hpp"

#include <algorithm>
#include <cstdio>
#include <sstream>

#include "report/svg_plot.hpp"

namespace clothdb {

namespace {

std::string bar(double fraction, int width) {
  fraction = std::clamp(fraction, 0.0, 1.0);
  const int full = static_cast<int>(fraction * width);
  return std::string(full, '#') + std::string(width - full, '.');
}

}  // namespace

CurvePoint curve_point(const SecondaryGraph& sg, const ExploreGraph& graph,
                       const std::vector<Job>& queue, const ExploreReport& report) {
  CurvePoint p;
  p.cpu_seconds = report.cpu_seconds;
  p.frames = report.frames;
  p.states = static_cast<int>(sg.states.size());
  p.dead_ends = static_cast<int>(queue.size());
  double sum = 0;
  int counted = 0;
  for (const Job& j : queue) {
    // The very first state at a node has no neighbour: its error is the whole unknown; it is
    // explored first and counted as 0 here (nothing to compare it with yet).
    const double error = sg.states[static_cast<size_t>(j.state)].priority;  // metres
    const double e = error >= kNoNeighbour ? 0.0 : error;
    p.worst_error = std::max(p.worst_error, e);
    p.weighted_worst_error =
        std::max(p.weighted_worst_error, e * graph.edges[static_cast<size_t>(j.edge)].reach);
    sum += e;
    ++counted;
  }
  p.mean_error = counted ? sum / counted : 0.0;
  p.linked_fraction = sg.clips ? static_cast<double>(sg.linked) / sg.clips : 0.0;
  return p;
}

void ProgressBar::update(const ExploreReport& report, size_t done, size_t dead_ends) const {
  if (!options_.progress) return;
  const CurvePoint& p = report.curve.back();
  double fraction = 0, eta = 0;
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  if (options_.max_frames > 0)
    fraction = static_cast<double>(report.frames_this_run) / options_.max_frames;
  if (options_.cpu_hours > 0)
    fraction = std::max(fraction, report.cpu_seconds / (options_.cpu_hours * 3600));
  if (fraction > 0) {
    eta = wall / fraction * (1 - fraction);
  } else {
    // No budget: at least the dead ends left at the current pace (new ones may appear).
    const double per_job = wall / std::max<size_t>(1, done);
    fraction = static_cast<double>(done) / (done + dead_ends);
    eta = per_job * dead_ends;
  }
  std::fprintf(
      stderr,
      "\r[%s] frames %ld  states %d  dead ends %d  worst %.1f mm  cpu %.0f s  ETA %s%.0f s   ",
      bar(fraction, 24).c_str(), report.frames, p.states, p.dead_ends, 1e3 * p.worst_error,
      report.cpu_seconds, options_.max_frames > 0 || options_.cpu_hours > 0 ? "" : ">=", eta);
}

void ProgressBar::end() const {
  if (options_.progress) std::fprintf(stderr, "\n");
}

std::string run_notes(const ExploreReport& report, size_t dead_ends_left) {
  const CurvePoint& last = report.curve.back();
  char notes[384];
  std::snprintf(
      notes, sizeof notes,
      "%s; unresolved error worst %.2f mm, reach-weighted worst %.2f mm; %.1f %% of "
      "clip ends linked within epsilon; %d dead ends linked to the nearest state (blend error "
      "mean %.2f mm, worst %.2f mm)",
      dead_ends_left == 0 ? "converged"
                          : (std::to_string(dead_ends_left) + " dead ends left").c_str(),
      1e3 * last.worst_error, 1e3 * last.weighted_worst_error, 100 * last.linked_fraction,
      report.links, 1e3 * report.mean_link_error, 1e3 * report.worst_link_error);
  return notes;
}

std::string curve_csv(const std::vector<CurvePoint>& curve) {
  std::ostringstream o;
  o << "cpu_seconds,frames,states,dead_ends,worst_error_mm,weighted_worst_error_mm,mean_error_mm,"
       "linked_percent\n";
  for (const auto& p : curve)
    o << p.cpu_seconds << ',' << p.frames << ',' << p.states << ',' << p.dead_ends << ','
      << 1e3 * p.worst_error << ',' << 1e3 * p.weighted_worst_error << ',' << 1e3 * p.mean_error
      << ',' << 100 * p.linked_fraction << '\n';
  return o.str();
}

std::string curve_svg(const std::vector<CurvePoint>& curve, double epsilon) {
  PlotSpec spec;
  spec.title = "Unresolved error against CPU time";
  spec.x_label = "CPU seconds";
  spec.y_label = "unresolved error, mm";
  PlotSeries worst, weighted, mean, eps;
  weighted.label = "worst x reach (how often the game takes the edge)";
  weighted.color = palette_color(2);
  weighted.line = true;
  worst.label = "worst";
  worst.color = palette_color(1);
  worst.line = true;
  mean.label = "mean";
  mean.color = palette_color(0);
  mean.line = true;
  eps.label = "epsilon";
  eps.color = "#333333";
  eps.line = true;
  eps.markers = false;
  eps.dashed = true;
  for (const auto& p : curve) {
    worst.x.push_back(p.cpu_seconds);
    worst.y.push_back(1e3 * p.worst_error);
    weighted.x.push_back(p.cpu_seconds);
    weighted.y.push_back(1e3 * p.weighted_worst_error);
    mean.x.push_back(p.cpu_seconds);
    mean.y.push_back(1e3 * p.mean_error);
  }
  if (!curve.empty()) {
    eps.x = {curve.front().cpu_seconds, curve.back().cpu_seconds};
    eps.y = {1e3 * epsilon, 1e3 * epsilon};
  }
  spec.series = {worst, weighted, mean, eps};
  return render_svg(spec);
}

}  // namespace clothdb
