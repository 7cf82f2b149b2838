#include "explore/progress.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "explore/forecast.hpp"
#include "report/svg_plot.hpp"

namespace clothdb {

namespace {

// "12.3 mm", or "unknown" for NaN (every dead end unexplored).
std::string millimetres(double metres) {
  if (std::isnan(metres)) return "unknown";
  char text[32];
  std::snprintf(text, sizeof text, "%.1f mm", 1e3 * metres);
  return text;
}

// A CSV cell: empty for NaN (unknown), never 0.
std::string cell(double value) {
  if (std::isnan(value)) return "";
  std::ostringstream o;
  o << value;
  return o.str();
}

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
  int measured = 0;
  for (const Job& j : queue) {
    const double error = sg.states[static_cast<size_t>(j.state)].priority;  // metres
    if (error >= kNoNeighbour) {
      // Alone at its node: the error is unknown (not 0): counted as unexplored.
      ++p.unexplored;
      continue;
    }
    p.worst_error = std::max(p.worst_error, error);
    p.weighted_worst_error =
        std::max(p.weighted_worst_error, error * graph.edges[static_cast<size_t>(j.edge)].reach);
    sum += error;
    ++measured;
  }
  if (measured > 0) {
    p.mean_error = sum / measured;
  } else if (p.unexplored > 0) {
    const double unknown = std::numeric_limits<double>::quiet_NaN();
    p.worst_error = p.weighted_worst_error = p.mean_error = unknown;
  }
  p.linked_fraction = sg.clips ? static_cast<double>(sg.linked) / sg.clips : 0.0;
  return p;
}

void add_curve_point(ExploreReport& report, const CurvePoint& point) {
  report.curve.push_back(point);
  const Forecast f = forecast_convergence(report.curve, report.cpu_seconds_before);
  if (f.converging) report.curve.back().forecast_cpu_seconds = f.cpu_seconds;
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
  std::fprintf(stderr,
               "\r[%s] frames %ld  states %d  dead ends %d (%d unexplored)  worst %s  cpu %.0f s  "
               "ETA %s%.0f s   ",
               bar(fraction, 24).c_str(), report.frames, p.states, p.dead_ends, p.unexplored,
               millimetres(p.worst_error).c_str(), report.cpu_seconds,
               options_.max_frames > 0 || options_.cpu_hours > 0 ? "" : ">=", eta);
}

void ProgressBar::end() const {
  if (options_.progress) std::fprintf(stderr, "\n");
}

std::string run_notes(const ExploreReport& report, size_t dead_ends_left) {
  const CurvePoint& last = report.curve.back();
  char notes[384];
  std::snprintf(
      notes, sizeof notes,
      "%s; unresolved error worst %.2f mm, reach-weighted worst %.2f mm (%d unexplored ways out "
      "not counted); %.1f %% of "
      "clip ends linked within epsilon; %d dead ends linked to the nearest state (blend error "
      "mean %.2f mm, worst %.2f mm)",
      dead_ends_left == 0 ? "converged"
                          : (std::to_string(dead_ends_left) + " dead ends left").c_str(),
      1e3 * last.worst_error, 1e3 * last.weighted_worst_error, last.unexplored,
      100 * last.linked_fraction, report.links, 1e3 * report.mean_link_error,
      1e3 * report.worst_link_error);
  return notes;
}

std::string curve_csv(const std::vector<CurvePoint>& curve) {
  std::ostringstream o;
  // Empty error cells: every dead end unexplored (unknown). Empty forecast: none.
  o << "cpu_seconds,frames,states,dead_ends,unexplored,worst_error_mm,weighted_worst_error_mm,"
       "mean_error_mm,linked_percent,forecast_cpu_hours\n";
  for (const auto& p : curve)
    o << p.cpu_seconds << ',' << p.frames << ',' << p.states << ',' << p.dead_ends << ','
      << p.unexplored << ',' << cell(1e3 * p.worst_error) << ','
      << cell(1e3 * p.weighted_worst_error) << ',' << cell(1e3 * p.mean_error) << ','
      << 100 * p.linked_fraction << ',' << cell(p.forecast_cpu_seconds / 3600) << '\n';
  return o.str();
}

namespace {

PlotSeries line_series(const std::string& label, size_t color) {
  PlotSeries s;
  s.label = label;
  s.color = palette_color(color);
  s.line = true;
  return s;
}

// Adds (x, y) unless y is unknown (NaN).
void add_point(PlotSeries& s, double x, double y) {
  if (std::isnan(y)) return;
  s.x.push_back(x);
  s.y.push_back(y);
}

// Panels one above the other in one SVG.
std::string stack_svg(const std::vector<PlotSpec>& panels) {
  int width = 0, height = 0;
  for (const PlotSpec& p : panels) width = std::max(width, p.width), height += p.height;
  std::ostringstream o;
  o << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << width << "\" height=\"" << height
    << "\">\n";
  int y = 0;
  for (const PlotSpec& p : panels) {
    o << "<g transform=\"translate(0," << y << ")\">\n" << render_svg(p) << "</g>\n";
    y += p.height;
  }
  o << "</svg>\n";
  return o.str();
}

}  // namespace

std::string curve_svg(const std::vector<CurvePoint>& curve, double epsilon) {
  PlotSpec error;
  error.title = "Unresolved error against CPU time (dead ends with a neighbour state)";
  error.x_label = "CPU seconds (this run)";
  error.y_label = "unresolved error, mm";
  error.height = 400;
  PlotSeries worst = line_series("worst", 1),
             weighted = line_series("worst x reach (how often the game takes the edge)", 2),
             mean = line_series("mean", 0), eps = line_series("epsilon", 0);
  eps.color = "#333333";
  eps.markers = false;
  eps.dashed = true;
  PlotSpec open;
  open.title = "Dead ends and unexplored ways out (state alone at its node: error unknown)";
  open.x_label = error.x_label;
  open.y_label = "count";
  open.height = 400;
  PlotSeries dead = line_series("dead ends", 3), unexplored = line_series("unexplored ways out", 4);
  PlotSpec linked;
  linked.title = "Share of clip ends linked within epsilon";
  linked.x_label = error.x_label;
  linked.y_label = "linked, %";
  linked.height = 320;
  PlotSeries share = line_series("linked", 5);
  for (const auto& p : curve) {
    add_point(worst, p.cpu_seconds, 1e3 * p.worst_error);
    add_point(weighted, p.cpu_seconds, 1e3 * p.weighted_worst_error);
    add_point(mean, p.cpu_seconds, 1e3 * p.mean_error);
    add_point(dead, p.cpu_seconds, p.dead_ends);
    add_point(unexplored, p.cpu_seconds, p.unexplored);
    add_point(share, p.cpu_seconds, 100 * p.linked_fraction);
  }
  if (!curve.empty()) {
    eps.x = {curve.front().cpu_seconds, curve.back().cpu_seconds};
    eps.y = {1e3 * epsilon, 1e3 * epsilon};
  }
  error.series = {worst, weighted, mean, eps};
  open.series = {dead, unexplored};
  linked.series = {share};
  return stack_svg({error, open, linked});
}

}  // namespace clothdb
