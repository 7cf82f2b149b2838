// A small SVG chart writer (scatter and line series, linear or log axes) for the benchmark plots
// and error curves: a person would rather look at these than read the CSV.
#pragma once

#include <string>
#include <vector>

namespace clothdb {

struct PlotSeries {
  std::string label;
  std::string color = "#1f77b4";
  std::vector<double> x, y;
  bool markers = true;
  bool line = false;
  bool dashed = false;
  std::vector<std::string> point_labels;  // optional, drawn small beside each marker
};

struct PlotSpec {
  std::string title;
  std::string x_label, y_label;
  bool log_x = false, log_y = false;
  std::vector<PlotSeries> series;
  int width = 900, height = 560;
};

std::string render_svg(const PlotSpec& spec);

// Text for an SVG element or attribute: <, >, & and " as entities.
std::string svg_escape(const std::string& s);

// Indices of the Pareto-optimal points when both x (cost) and y (error) are to be minimised:
// a point is kept if no other point is at least as good in both and better in one. Sorted by x.
std::vector<size_t> pareto_front(const std::vector<double>& x, const std::vector<double>& y);

// A colour from a fixed palette, by index.
std::string palette_color(size_t i);

}  // namespace clothdb
