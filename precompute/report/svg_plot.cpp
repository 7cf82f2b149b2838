#include "report/svg_plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <sstream>

namespace clothdb {

namespace {


std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

struct Axis {
  double lo, hi;
  bool log;
  double map(double v, double a, double b) const {  // value -> pixel between a and b
    const double t = log ? (std::log10(v) - std::log10(lo)) / (std::log10(hi) - std::log10(lo))
                         : (v - lo) / (hi - lo);
    return a + t * (b - a);
  }
  std::vector<double> ticks() const {
    std::vector<double> t;
    if (log) {
      for (double d = std::floor(std::log10(lo)); d <= std::ceil(std::log10(hi)); d += 1.0) {
        const double v = std::pow(10.0, d);
        if (v >= lo * 0.999 && v <= hi * 1.001) t.push_back(v);
      }
      if (t.size() < 2) t = {lo, hi};
    } else {
      const double span = hi - lo;
      const double step0 = std::pow(10.0, std::floor(std::log10(span / 5)));
      double step = step0;
      for (double m : {1.0, 2.0, 5.0, 10.0})
        if (span / (step0 * m) <= 8) {
          step = step0 * m;
          break;
        }
      for (double v = std::ceil(lo / step) * step; v <= hi + 1e-12 * span; v += step)
        t.push_back(v);
    }
    return t;
  }
};

Axis make_axis(const std::vector<const std::vector<double>*>& values, bool log) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto* vs : values)
    for (double v : *vs) {
      if (!std::isfinite(v) || (log && v <= 0)) continue;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  if (!std::isfinite(lo)) lo = log ? 1 : 0, hi = log ? 10 : 1;
  if (log) {
    lo = std::pow(10.0, std::floor(std::log10(lo)));
    hi = std::pow(10.0, std::ceil(std::log10(hi)));
    if (hi <= lo) hi = lo * 10;
  } else {
    const double pad = (hi - lo) * 0.05 + (hi == lo ? 1.0 : 0.0);
    lo -= pad;
    hi += pad;
  }
  return {lo, hi, log};
}

}  // namespace

std::string palette_color(size_t i) {
  static const char* colors[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e",
                                 "#9467bd", "#8c564b", "#e377c2", "#17becf"};
  return colors[i % 8];
}

std::vector<size_t> pareto_front(const std::vector<double>& x, const std::vector<double>& y) {
  std::vector<size_t> order(x.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b) { return x[a] != x[b] ? x[a] < x[b] : y[a] < y[b]; });
  std::vector<size_t> front;
  double best = std::numeric_limits<double>::infinity();
  for (size_t i : order) {
    if (!std::isfinite(x[i]) || !std::isfinite(y[i])) continue;
    if (y[i] < best) {
      front.push_back(i);
      best = y[i];
    }
  }
  return front;
}

std::string svg_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '&':
        out += "&amp;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string render_svg(const PlotSpec& spec) {
  std::vector<const std::vector<double>*> xs, ys;
  for (const auto& s : spec.series) {
    xs.push_back(&s.x);
    ys.push_back(&s.y);
  }
  const Axis ax = make_axis(xs, spec.log_x), ay = make_axis(ys, spec.log_y);
  const double left = 80, right = spec.width - 190, top = 40, bottom = spec.height - 60;
  std::ostringstream o;
  o << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << spec.width << "\" height=\""
    << spec.height << "\" font-family=\"sans-serif\" font-size=\"12\">\n"
    << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
    << "<text x=\"" << spec.width / 2 << "\" y=\"22\" text-anchor=\"middle\" font-size=\"15\">"
    << svg_escape(spec.title) << "</text>\n";
  for (double t : ax.ticks()) {
    const double px = ax.map(t, left, right);
    o << "<line x1=\"" << px << "\" y1=\"" << top << "\" x2=\"" << px << "\" y2=\"" << bottom
      << "\" stroke=\"#e5e5e5\"/><text x=\"" << px << "\" y=\"" << bottom + 16
      << "\" text-anchor=\"middle\">" << fmt(t) << "</text>\n";
  }
  for (double t : ay.ticks()) {
    const double py = ay.map(t, bottom, top);
    o << "<line x1=\"" << left << "\" y1=\"" << py << "\" x2=\"" << right << "\" y2=\"" << py
      << "\" stroke=\"#e5e5e5\"/><text x=\"" << left - 6 << "\" y=\"" << py + 4
      << "\" text-anchor=\"end\">" << fmt(t) << "</text>\n";
  }
  o << "<rect x=\"" << left << "\" y=\"" << top << "\" width=\"" << right - left << "\" height=\""
    << bottom - top << "\" fill=\"none\" stroke=\"black\"/>\n"
    << "<text x=\"" << (left + right) / 2 << "\" y=\"" << spec.height - 18
    << "\" text-anchor=\"middle\">" << svg_escape(spec.x_label) << (spec.log_x ? " (log)" : "")
    << "</text>\n<text transform=\"translate(20," << (top + bottom) / 2
    << ") rotate(-90)\" text-anchor=\"middle\">" << svg_escape(spec.y_label)
    << (spec.log_y ? " (log)" : "") << "</text>\n";
  auto usable = [&](double x, double y) {
    return std::isfinite(x) && std::isfinite(y) && (!spec.log_x || x > 0) && (!spec.log_y || y > 0);
  };
  double legend_y = top + 10;
  for (const auto& s : spec.series) {
    if (s.line) {
      o << "<polyline fill=\"none\" stroke=\"" << s.color << "\" stroke-width=\"1.8\""
        << (s.dashed ? " stroke-dasharray=\"6,4\"" : "") << " points=\"";
      for (size_t i = 0; i < s.x.size(); ++i)
        if (usable(s.x[i], s.y[i]))
          o << ax.map(s.x[i], left, right) << "," << ay.map(s.y[i], bottom, top) << " ";
      o << "\"/>\n";
    }
    if (s.markers) {
      for (size_t i = 0; i < s.x.size(); ++i) {
        if (!usable(s.x[i], s.y[i])) continue;
        const double px = ax.map(s.x[i], left, right), py = ay.map(s.y[i], bottom, top);
        o << "<circle cx=\"" << px << "\" cy=\"" << py << "\" r=\"4\" fill=\"" << s.color
          << "\" fill-opacity=\"0.8\"/>\n";
        if (i < s.point_labels.size() && !s.point_labels[i].empty())
          o << "<text x=\"" << px + 6 << "\" y=\"" << py - 5 << "\" font-size=\"9\" fill=\"#444\">"
            << svg_escape(s.point_labels[i]) << "</text>\n";
      }
    }
    o << "<line x1=\"" << right + 15 << "\" y1=\"" << legend_y << "\" x2=\"" << right + 35
      << "\" y2=\"" << legend_y << "\" stroke=\"" << s.color << "\" stroke-width=\"3\""
      << (s.dashed ? " stroke-dasharray=\"6,4\"" : "") << "/><text x=\"" << right + 40 << "\" y=\""
      << legend_y + 4 << "\">" << svg_escape(s.label) << "</text>\n";
    legend_y += 18;
  }
  o << "</svg>\n";
  return o.str();
}

}  // namespace clothdb
