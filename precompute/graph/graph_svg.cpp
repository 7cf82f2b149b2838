#include "graph/graph_svg.hpp"

#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <utility>
#include <vector>

#include "report/svg_plot.hpp"

extern char** environ;

namespace clothdb {

namespace {


std::string fmt(double v, const char* format = "%.1f") {
  char buf[48];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

std::string counts_line(const MotionGraph& g) {
  return std::to_string(g.node_count()) + " nodes, " + std::to_string(g.edge_count()) + " edges (" +
         std::to_string(g.transition_count()) + " transitions, " +
         std::to_string(g.clip_edge_count()) + " clip segments), " +
         std::to_string(g.clips.size()) + " clips";
}

std::string settings_line(const MotionGraph& g) {
  const GraphSettings& s = g.settings;
  double lo = 0.0, hi = 0.0;
  for (size_t k = 0; k < g.thresholds.size(); ++k) {
    lo = k == 0 ? g.thresholds[k].rms : std::min(lo, g.thresholds[k].rms);
    hi = std::max(hi, g.thresholds[k].rms);
  }
  const std::string range =
      lo == hi ? fmt(hi * 100.0, "%.2f") : fmt(lo * 100.0, "%.2f") + "-" + fmt(hi * 100.0, "%.2f");
  return "threshold " + range + " cm RMS" +
         (s.threshold_mode == ThresholdMode::percentile
              ? " (" + fmt(s.threshold, "%g") + " percentile per clip pair)"
              : std::string()) +
         ", window " + std::to_string(s.window) + " frames, blend " + std::to_string(s.blend) +
         " frames; before pruning " + std::to_string(g.candidate_nodes) + " nodes, " +
         std::to_string(g.candidate_transitions) + " transitions";
}

}  // namespace

std::string motion_graph_svg(const MotionGraph& g) {
  const double width = 1200, left = 150, right = 40, top = 96, lane = 130;
  const int clip_count = static_cast<int>(g.clips.size());
  const double height = top + lane * std::max(1, clip_count) + 30;
  int max_frames = 2;
  for (const GraphClip& c : g.clips) max_frames = std::max(max_frames, c.frame_count);
  const auto x_of = [&](int frame) {
    return left + (width - left - right) * frame / static_cast<double>(max_frames - 1);
  };
  const auto y_of = [&](int clip) { return top + lane * (clip + 0.5); };

  std::ostringstream o;
  o << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << width << "\" height=\"" << height
    << "\" viewBox=\"0 0 " << width << ' ' << height << "\" font-family=\"sans-serif\">\n";
  o << "<defs>\n";
  for (const auto& [id, color] : {std::pair<const char*, std::string>{"clip", "#333333"},
                                  {"auto", "#e6550d"},
                                  {"manual", "#756bb1"}})
    o << "<marker id=\"arrow-" << id
      << "\" viewBox=\"0 0 10 10\" refX=\"10\" refY=\"5\" markerUnits=\"userSpaceOnUse\" "
         "markerWidth=\"9\" markerHeight=\"9\" orient=\"auto-start-reverse\"><path d=\"M0,0 L10,5 "
         "L0,10 z\" fill=\""
      << color << "\"/></marker>\n";
  o << "</defs>\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  o << "<text x=\"" << width / 2 << "\" y=\"28\" text-anchor=\"middle\" font-size=\"18\">"
    << svg_escape("Motion graph: " + counts_line(g)) << "</text>\n";
  o << "<text x=\"" << width / 2 << "\" y=\"50\" text-anchor=\"middle\" font-size=\"12\" "
    << "fill=\"#555\">" << svg_escape(settings_line(g)) << "</text>\n";
  // Legend.
  const double ly = 72;
  o << "<line x1=\"" << left << "\" y1=\"" << ly << "\" x2=\"" << left + 40 << "\" y2=\"" << ly
    << "\" stroke=\"#333\" stroke-width=\"2.5\" marker-end=\"url(#arrow-clip)\"/>"
    << "<text x=\"" << left + 48 << "\" y=\"" << ly + 4
    << "\" font-size=\"12\">clip segment</text>\n";
  o << "<path d=\"M" << left + 170 << ',' << ly << " q20,-14 40,0\" fill=\"none\" "
    << "stroke=\"#e6550d\" stroke-width=\"1.5\" marker-end=\"url(#arrow-auto)\"/>"
    << "<text x=\"" << left + 218 << "\" y=\"" << ly + 4
    << "\" font-size=\"12\">transition (found)</text>\n";
  o << "<path d=\"M" << left + 360 << ',' << ly << " q20,-14 40,0\" fill=\"none\" "
    << "stroke=\"#756bb1\" stroke-width=\"1.5\" stroke-dasharray=\"5,3\" "
    << "marker-end=\"url(#arrow-manual)\"/><text x=\"" << left + 408 << "\" y=\"" << ly + 4
    << "\" font-size=\"12\">transition (declared)</text>\n";
  o << "<text x=\"" << width - right << "\" y=\"" << ly + 4
    << "\" text-anchor=\"end\" font-size=\"12\" fill=\"#555\">x: frame</text>\n";

  // Lanes: the whole clip in grey, so that what pruning removed shows.
  for (int c = 0; c < clip_count; ++c) {
    const double y = y_of(c);
    const GraphClip& clip = g.clips[c];
    o << "<text x=\"" << left - 12 << "\" y=\"" << y + 4
      << "\" text-anchor=\"end\" font-size=\"13\">" << svg_escape(clip.name) << "</text>\n";
    o << "<line x1=\"" << x_of(0) << "\" y1=\"" << y << "\" x2=\"" << x_of(clip.frame_count - 1)
      << "\" y2=\"" << y << "\" stroke=\"#dddddd\" stroke-width=\"6\" stroke-linecap=\"round\"/>\n";
    for (int f : {0, clip.frame_count - 1})
      o << "<text x=\"" << x_of(f) << "\" y=\"" << y + 22
        << "\" text-anchor=\"middle\" font-size=\"10\" fill=\"#888\">" << f << "</text>\n";
  }

  // Clip edges first, transitions over them, nodes on top.
  for (int k = 0; k < g.edge_count(); ++k) {
    const GraphEdge& e = g.edges[k];
    if (e.kind != EdgeKind::clip) continue;
    const double y = y_of(e.clip);
    o << "<line x1=\"" << fmt(x_of(e.first_frame)) << "\" y1=\"" << y << "\" x2=\""
      << fmt(x_of(e.last_frame)) << "\" y2=\"" << y
      << "\" stroke=\"#333\" stroke-width=\"2.5\" marker-end=\"url(#arrow-clip)\"><title>"
      << svg_escape("edge " + std::to_string(k) + ": " + g.clips[e.clip].name + " frames " +
                std::to_string(e.first_frame) + ".." + std::to_string(e.last_frame))
      << "</title></line>\n";
  }
  for (int k = 0; k < g.edge_count(); ++k) {
    const GraphEdge& e = g.edges[k];
    if (e.kind != EdgeKind::transition) continue;
    const double x1 = x_of(e.first_frame), y1 = y_of(e.clip);
    const double x2 = x_of(e.target_frame), y2 = y_of(e.target_clip);
    // Control points: an arc above the lane going forward in the same clip and below going back
    // (higher for longer jumps); an S-curve between lanes.
    double yc1, yc2;
    if (e.clip == e.target_clip) {
      const double bulge = std::min(lane * 0.45, 14.0 + 0.25 * std::abs(x2 - x1));
      yc1 = yc2 = x2 >= x1 ? y1 - bulge : y1 + bulge;
    } else {
      yc1 = yc2 = 0.5 * (y1 + y2);
    }
    std::ostringstream d;
    d << 'M' << fmt(x1) << ',' << fmt(y1) << " C" << fmt(x1) << ',' << fmt(yc1) << ' ' << fmt(x2)
      << ',' << fmt(yc2) << ' ' << fmt(x2) << ',' << fmt(y2);
    const char* color = e.manual ? "#756bb1" : "#e6550d";
    o << "<path d=\"" << d.str() << "\" fill=\"none\" stroke=\"" << color
      << "\" stroke-width=\"1.5\" stroke-opacity=\"0.85\""
      << (e.manual ? " stroke-dasharray=\"5,3\"" : "") << " marker-end=\"url(#arrow-"
      << (e.manual ? "manual" : "auto") << ")\"><title>"
      << svg_escape("edge " + std::to_string(k) + ": " + g.clips[e.clip].name + " " +
                std::to_string(e.first_frame) + " -> " + g.clips[e.target_clip].name + " " +
                std::to_string(e.target_frame) + ", blend " + std::to_string(e.blend) +
                " frames, distance " + fmt(e.distance * 100.0, "%.2f") + " cm RMS")
      << "</title></path>\n";
  }
  for (int v = 0; v < g.node_count(); ++v) {
    const GraphNode& n = g.nodes[v];
    o << "<circle cx=\"" << fmt(x_of(n.frame)) << "\" cy=\"" << y_of(n.clip)
      << "\" r=\"4\" fill=\"#1f77b4\" stroke=\"white\" stroke-width=\"1\"><title>"
      << svg_escape("node " + std::to_string(v) + ": " + g.clips[n.clip].name + " frame " +
                std::to_string(n.frame))
      << "</title></circle>\n";
  }
  o << "</svg>\n";
  return o.str();
}

std::string motion_graph_dot(const MotionGraph& g) {
  const auto quote = [](const std::string& s) {
    std::string out = "\"";
    for (char c : s) {
      if (c == '\n') {
        out += "\\n";  // DOT's centred line break
        continue;
      }
      if (c == '"' || c == '\\') out += '\\';
      out += c;
    }
    return out + "\"";
  };
  std::ostringstream o;
  o << "digraph motion_graph {\n";
  o << "  label=" << quote("Motion graph: " + counts_line(g) + "\n" + settings_line(g))
    << ";\n  labelloc=t;\n  rankdir=LR;\n  node [shape=circle, fontsize=10];\n";
  for (int c = 0; c < static_cast<int>(g.clips.size()); ++c) {
    o << "  subgraph cluster_" << c << " {\n    label=" << quote(g.clips[c].name) << ";\n";
    for (int v = 0; v < g.node_count(); ++v)
      if (g.nodes[v].clip == c)
        o << "    n" << v << " [label=" << quote(std::to_string(g.nodes[v].frame)) << "];\n";
    o << "  }\n";
  }
  for (const GraphEdge& e : g.edges) {
    o << "  n" << e.from << " -> n" << e.to;
    if (e.kind == EdgeKind::clip)
      o << " [weight=10, label=" << quote(std::to_string(e.frame_count() - 1) + " fr") << "];\n";
    else
      o << " [style=dashed, color=" << (e.manual ? "purple" : "orangered")
        << ", constraint=false, label=" << quote(fmt(e.distance * 100.0, "%.1f") + " cm")
        << ", fontsize=8];\n";
  }
  o << "}\n";
  return o.str();
}

bool graphviz_available() {
  const char* path = std::getenv("PATH");
  if (!path) return false;
  std::stringstream dirs(path);
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    if (dir.empty()) continue;
    const std::string candidate = dir + "/dot";
    if (::access(candidate.c_str(), X_OK) == 0) return true;
  }
  return false;
}

void render_dot_svg(const std::string& dot, const std::string& svg_path) {
  if (!graphviz_available())
    throw GraphError(svg_path +
                     ": Graphviz's dot is not on PATH (apt-get install graphviz), or "
                     "use the built-in SVG drawing");
  const std::string suffix = ".tmp." + std::to_string(::getpid());
  const std::string dot_file = svg_path + ".dot" + suffix, svg_tmp = svg_path + suffix;
  {
    std::ofstream out(dot_file, std::ios::binary | std::ios::trunc);
    out << dot;
    if (!out) throw GraphError(dot_file + ": cannot write: " + std::strerror(errno));
  }
  // posix_spawnp with an argument vector: no shell, so paths need no quoting.
  std::vector<std::string> args = {"dot", "-Tsvg", "-o", svg_tmp, dot_file};
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = 0;
  int status = 0;
  const int spawned = ::posix_spawnp(&pid, "dot", nullptr, nullptr, argv.data(), environ);
  const bool ok = spawned == 0 && ::waitpid(pid, &status, 0) == pid && WIFEXITED(status) &&
                  WEXITSTATUS(status) == 0;
  std::remove(dot_file.c_str());
  if (!ok) {
    std::remove(svg_tmp.c_str());
    throw GraphError(svg_path + ": Graphviz's dot failed" +
                     (spawned != 0 ? std::string(": ") + std::strerror(spawned) : std::string()));
  }
  if (std::rename(svg_tmp.c_str(), svg_path.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    std::remove(svg_tmp.c_str());
    throw GraphError(svg_path + ": cannot move into place: " + why);
  }
}

}  // namespace clothdb
