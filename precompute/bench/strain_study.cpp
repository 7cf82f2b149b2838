#include "bench/strain_study.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <sstream>

#include "report/stats.hpp"
#include "solvers/solver.hpp"

namespace clothdb {

namespace {

std::string fixed(double v, int digits) {
  if (!std::isfinite(v)) return "-";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

nlohmann::json num(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

std::string label(const Solver& solver, const SolverSettings& s) {
  return solver.describe() + (s.tethers ? "" : " tethers=off");
}

// One continuous run from the scene's start, positions kept.
RunResult run(const ClothScene& scene, const SolverCandidate& c, int frames, std::string& name) {
  SolverSettings s = c.settings;
  s.threads = 1;
  auto solver = make_solver(c.kind, scene.model, s);
  name = label(*solver, s);
  return run_scene(scene, *solver, frames, true);
}

}  // namespace

bool meets_strain_target(double max_strain, double target) {
  return std::isfinite(max_strain) && max_strain <= target + 5e-6;
}

StrainStudy run_strain_study(const ClothScene& scene, const StrainStudyOptions& options,
                             const std::function<void(const std::string&)>& progress) {
  StrainStudy out;
  out.scene = scene.name;
  out.description = scene.description;
  out.vertices = static_cast<int>(scene.model.vertex_count());
  out.frames = options.frames;
  out.targets = options.targets;
  const auto& edges = scene.model.mesh.edges;
  for (const SolverCandidate& c : options.settings) {
    StrainStudyRow row;
    const RunResult r = run(scene, c, options.frames, row.settings);
    row.stable = r.stable;
    row.message = r.message;
    row.frames = static_cast<int>(r.frames.size()) - 1;
    if (row.frames > 0) {
      row.cpu_ms_per_frame = 1e3 * r.cpu_seconds / row.frames;
      std::vector<double> strains;
      strains.reserve(edges.size() * static_cast<std::size_t>(row.frames));
      row.max_strain = 0.0;
      for (std::size_t f = 1; f < r.frames.size(); ++f) {
        const double frame_max =
            std::max(0.0, append_edge_strains(scene.model, r.frames[f], strains).strain);
        row.max_strain = std::max(row.max_strain, frame_max);
        row.last_strain = frame_max;
      }
      row.p99_strain = report::percentile(std::move(strains), 0.99);
    }
    if (options.references && r.stable) {
      const SolverCandidate ref = scene_reference(c.kind, c.settings);
      std::string ignored;
      const RunResult rr = run(scene, ref, options.frames, ignored);
      row.reference = ref.label;
      if (rr.stable && rr.frames.size() > 1) {
        const FrameErrors e = compare_frames(r.frames, rr.frames, 1);
        row.reference_rms_mm = 1e3 * e.rms;
        row.reference_max_mm = 1e3 * e.max;
        row.reference_cpu_ms_per_frame =
            1e3 * rr.cpu_seconds / static_cast<double>(rr.frames.size() - 1);
      } else {
        row.reference += " (unstable: " + rr.message + ")";
      }
    }
    if (progress)
      progress(scene.name + ": " + row.settings + ": CPU " + fixed(row.cpu_ms_per_frame, 1) +
               " ms/frame, strain p99 " + fixed(100 * row.p99_strain, 3) + " % max " +
               fixed(100 * row.max_strain, 3) + " %, " + fixed(row.reference_rms_mm, 2) +
               " mm RMS from 8x sub-steps" + (row.stable ? "" : " UNSTABLE: " + row.message));
    out.rows.push_back(row);
  }
  for (double target : out.targets) {
    StrainStudyRow* best = nullptr;
    for (StrainStudyRow& row : out.rows)
      if (row.stable && meets_strain_target(row.max_strain, target) &&
          (best == nullptr || row.cpu_ms_per_frame < best->cpu_ms_per_frame))
        best = &row;
    if (best != nullptr) best->cheapest_for.push_back(target);
  }
  return out;
}

std::string strain_study_markdown(const StrainStudy& study) {
  std::ostringstream o;
  o << "### " << study.scene << " (" << study.vertices << " vertices, " << study.frames
    << " frames, one thread)\n\n"
    << study.description << "\n\n"
    << "| setting | CPU ms/frame | p99 strain | max strain | at the last frame | RMS / max mm "
       "from 8x sub-steps | reference CPU ms/frame | cheapest within |\n"
    << "|---|---:|---:|---:|---:|---:|---:|---|\n";
  for (const StrainStudyRow& r : study.rows) {
    std::string cheapest;
    for (double t : r.cheapest_for)
      cheapest += (cheapest.empty() ? "**" : ", **") + fixed(100 * t, 2) + " %**";
    o << "| " << r.settings << (r.stable ? "" : " (UNSTABLE: " + r.message + ")") << " | "
      << fixed(r.cpu_ms_per_frame, 1) << " | " << fixed(100 * r.p99_strain, 3) << " % | "
      << fixed(100 * r.max_strain, 3) << " % | " << fixed(100 * r.last_strain, 3) << " % | "
      << fixed(r.reference_rms_mm, 2) << " / " << fixed(r.reference_max_mm, 2) << " | "
      << fixed(r.reference_cpu_ms_per_frame, 1) << " | " << cheapest << " |\n";
  }
  for (double t : study.targets)
    if (std::none_of(study.rows.begin(), study.rows.end(), [&](const StrainStudyRow& r) {
          return std::find(r.cheapest_for.begin(), r.cheapest_for.end(), t) != r.cheapest_for.end();
        }))
      o << "\nNo setting keeps the largest strain within " << fixed(100 * t, 2) << " %.\n";
  return o.str();
}

std::string strain_study_json(const std::vector<StrainStudy>& studies) {
  nlohmann::json j = nlohmann::json::array();
  for (const StrainStudy& s : studies) {
    nlohmann::json rows = nlohmann::json::array();
    for (const StrainStudyRow& r : s.rows)
      rows.push_back({{"settings", r.settings},
                      {"stable", r.stable},
                      {"message", r.message},
                      {"frames", r.frames},
                      {"cpu_ms_per_frame", num(r.cpu_ms_per_frame)},
                      {"p99_strain", num(r.p99_strain)},
                      {"max_strain", num(r.max_strain)},
                      {"last_strain", num(r.last_strain)},
                      {"reference", r.reference},
                      {"reference_rms_mm", num(r.reference_rms_mm)},
                      {"reference_max_mm", num(r.reference_max_mm)},
                      {"reference_cpu_ms_per_frame", num(r.reference_cpu_ms_per_frame)},
                      {"cheapest_for", r.cheapest_for}});
    j.push_back({{"scene", s.scene},
                 {"description", s.description},
                 {"vertices", s.vertices},
                 {"frames", s.frames},
                 {"targets", s.targets},
                 {"rows", rows}});
  }
  return j.dump(1) + "\n";
}

}  // namespace clothdb
