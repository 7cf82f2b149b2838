#include "explore/progress.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <istream>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>

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
  p.clips = sg.clips;
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

Forecast add_curve_point(ExploreReport& report, const CurvePoint& point) {
  report.curve.push_back(point);
  const Forecast f = forecast_convergence(report.curve, report.cpu_seconds_before);
  if (!f.converging) return f;
  CurvePoint& p = report.curve.back();
  p.forecast_cpu_seconds = f.cpu_seconds;
  p.forecast_low_cpu_seconds = f.low_cpu_seconds;
  p.forecast_high_cpu_seconds = f.high_cpu_seconds;
  return f;
}

void ProgressBar::update(const ExploreReport& report, const Forecast& f, size_t done,
                         size_t dead_ends) const {
  if (!options_.progress) return;
  const CurvePoint& p = report.curve.back();
  double fraction = 0;
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  if (options_.max_frames > 0)
    fraction = static_cast<double>(report.frames_this_run) / options_.max_frames;
  if (options_.cpu_hours > 0)
    fraction = std::max(fraction, report.cpu_seconds / (options_.cpu_hours * 3600));
  // The time to convergence is the forecast's (explore/forecast.hpp), the one model every printed
  // forecast comes from; the time left is the budget's when there is one.
  std::string left;
  char text[64];
  if (fraction >= 1) {
    // The last batch ran past the budget (it is checked before each batch): no time is left,
    // and a negative one would read as a bug.
    left = "budget reached";
  } else if (fraction > 0) {
    std::snprintf(text, sizeof text, "budget ends in %.0f s", wall / fraction * (1 - fraction));
    left = text;
  } else {
    fraction = static_cast<double>(done) / (done + dead_ends);
  }
  std::fprintf(stderr,
               "\r[%s] frames %ld  states %d  dead ends %d (%d unexplored)  worst %s  cpu %.0f s  "
               "converges %s%s%s   ",
               bar(fraction, 24).c_str(), report.frames, p.states, p.dead_ends, p.unexplored,
               millimetres(p.worst_error).c_str(), report.cpu_seconds,
               forecast_short_text(f).c_str(), left.empty() ? "" : "  ", left.c_str());
}

void ProgressBar::end() const {
  if (options_.progress) std::fprintf(stderr, "\n");
}

std::string run_notes(const ExploreReport& report, size_t dead_ends_left) {
  const CurvePoint& last = report.curve.back();
  // The errors are NaN when every dead end is unexplored (CurvePoint): "unknown", never "nan mm".
  auto mm = [](double metres) -> std::string {
    if (std::isnan(metres)) return "unknown";
    char text[32];
    std::snprintf(text, sizeof text, "%.2f mm", 1e3 * metres);
    return text;
  };
  char notes[384];
  std::snprintf(
      notes, sizeof notes,
      "%s; unresolved error worst %s, reach-weighted worst %s (%d unexplored ways out "
      "not counted); %.1f %% of "
      "clip ends linked within epsilon; %d dead ends linked to the nearest state (blend error "
      "mean %.2f mm, worst %.2f mm)",
      dead_ends_left == 0 ? "converged"
                          : (std::to_string(dead_ends_left) + " dead ends left").c_str(),
      mm(last.worst_error).c_str(), mm(last.weighted_worst_error).c_str(), last.unexplored,
      100 * last.linked_fraction, report.links, 1e3 * report.mean_link_error,
      1e3 * report.worst_link_error);
  return notes;
}

std::string curve_csv(const std::vector<CurvePoint>& curve) {
  std::ostringstream o;
  // Empty error cells: every dead end unexplored (unknown). Empty forecast: none.
  // The band's upper end is "inf" when it is open above.
  o << "cpu_seconds,frames,states,dead_ends,unexplored,worst_error_mm,weighted_worst_error_mm,"
       "mean_error_mm,linked_percent,forecast_cpu_hours,forecast_low_cpu_hours,"
       "forecast_high_cpu_hours,clips\n";
  for (const auto& p : curve)
    o << p.cpu_seconds << ',' << p.frames << ',' << p.states << ',' << p.dead_ends << ','
      << p.unexplored << ',' << cell(1e3 * p.worst_error) << ','
      << cell(1e3 * p.weighted_worst_error) << ',' << cell(1e3 * p.mean_error) << ','
      << 100 * p.linked_fraction << ',' << cell(p.forecast_cpu_seconds / 3600) << ','
      << cell(p.forecast_low_cpu_seconds / 3600) << ','
      << (std::isinf(p.forecast_high_cpu_seconds) ? "inf"
                                                  : cell(p.forecast_high_cpu_seconds / 3600))
      << ',' << p.clips << '\n';
  return o.str();
}

std::vector<CurvePoint> read_curve_csv(std::istream& in, const std::string& path) {
  std::string line;
  if (!std::getline(in, line)) throw std::runtime_error(path + ": empty, no header line");
  // Columns by name: older curves lack the band's columns, and only the counts are needed.
  std::map<std::string, size_t> column;
  {
    std::istringstream header(line);
    std::string name;
    for (size_t k = 0; std::getline(header, name, ','); ++k) column[name] = k;
  }
  for (const char* needed : {"cpu_seconds", "frames", "states", "dead_ends", "unexplored"})
    if (!column.count(needed))
      throw std::runtime_error(path + ": no column '" + needed +
                               "' in the header (a curve written by precompute --curve)");
  std::vector<CurvePoint> curve;
  for (long row = 2; std::getline(in, line); ++row) {
    if (line.empty()) continue;
    std::vector<std::string> cells;
    std::istringstream fields(line);
    std::string c;
    while (std::getline(fields, c, ',')) cells.push_back(c);
    auto number = [&](const char* name) {
      const size_t k = column.at(name);
      char* end = nullptr;
      const double v = k < cells.size() ? std::strtod(cells[k].c_str(), &end) : 0;
      if (k >= cells.size() || cells[k].empty() || end != cells[k].c_str() + cells[k].size() ||
          !std::isfinite(v) || v < 0)
        throw std::runtime_error(path + ": line " + std::to_string(row) + ", column '" + name +
                                 "': not a number at least 0");
      return v;
    };
    CurvePoint p;
    p.cpu_seconds = number("cpu_seconds");
    p.frames = static_cast<long>(number("frames"));
    p.states = static_cast<int>(number("states"));
    p.dead_ends = static_cast<int>(number("dead_ends"));
    p.unexplored = static_cast<int>(number("unexplored"));
    if (column.count("linked_percent")) p.linked_fraction = number("linked_percent") / 100;
    if (column.count("clips"))
      p.clips = static_cast<long>(number("clips"));
    else if (p.states > 0 && p.linked_fraction < 1)
      // An older curve: every clip that did not link made a state (the first state is the start).
      p.clips = std::lround((p.states - 1) / (1 - p.linked_fraction));
    if (!curve.empty() && p.cpu_seconds < curve.back().cpu_seconds)
      throw std::runtime_error(path + ": line " + std::to_string(row) +
                               ": cpu_seconds goes back in time");
    curve.push_back(p);
  }
  if (curve.empty()) throw std::runtime_error(path + ": no rows after the header");
  return curve;
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
