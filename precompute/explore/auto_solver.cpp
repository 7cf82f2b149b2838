#include "explore/auto_solver.hpp"

#include <time.h>

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "explore/explorer.hpp"
#include "report/cpu_time.hpp"

namespace clothdb {

namespace {

std::vector<float> flat(const Eigen::Matrix3Xd& m) {
  std::vector<float> out(static_cast<size_t>(m.size()));
  for (Eigen::Index i = 0; i < m.size(); ++i)
    out[static_cast<size_t>(i)] = static_cast<float>(m.data()[i]);
  return out;
}

// The scene's settings with what the sweep sets (sub-steps, iterations, tolerance, linear
// solver); one thread, so the CPU time is the cost of one explorer job.
SolverCandidate on_scene(const SolverCandidate& c, const SolverSettings& scene_settings) {
  SolverCandidate out = c;
  out.settings = scene_settings;
  out.settings.substeps = c.settings.substeps;
  out.settings.iterations = c.settings.iterations;
  out.settings.newton_tolerance = c.settings.newton_tolerance;
  out.settings.linear_solver = c.settings.linear_solver;
  out.settings.threads = 1;
  return out;
}

struct Trial {
  PoseRun run;
  ClothState end;
  double cpu = 0;
};

Trial simulate(const CharacterScene& scene, const SolverCandidate& c, const ClothState& start,
               const std::vector<std::vector<JointPose>>& poses, double rate) {
  Trial t;
  auto solver = make_solver(c.kind, scene.model, c.settings);
  t.end = start;
  const double t0 = thread_cpu_seconds();
  t.run = simulate_poses(scene, *solver, poses, rate, t.end);
  t.cpu = thread_cpu_seconds() - t0;
  return t;
}

}  // namespace

SolverCandidate calibration_reference(SolverKind kind, bool newton_reference) {
  if (newton_reference || kind == SolverKind::Newton) return reference_candidate();
  // The finest setting of the sweep (most sub-steps, then most iterations) with 4 times the
  // sub-steps: XPBD/PBD/mass-spring converge to their own model's motion as the step shrinks.
  SolverCandidate finest = solver_candidates(kind, false).front();
  for (const SolverCandidate& c : solver_candidates(kind, false))
    if (std::pair(c.settings.substeps, c.settings.iterations) >
        std::pair(finest.settings.substeps, finest.settings.iterations))
      finest = c;
  finest.settings.substeps *= 4;
  finest.label = "substeps=" + std::to_string(finest.settings.substeps) +
                 (kind == SolverKind::MassSpring
                      ? ""
                      : " iterations=" + std::to_string(finest.settings.iterations));
  return finest;
}

AutoCalibration calibrate_solvers(const CharacterScene& scene,
                                  const std::vector<std::vector<JointPose>>& edge_poses,
                                  double rate, const AutoSolverOptions& options) {
  if (edge_poses.size() < 2)
    throw std::runtime_error("--auto: the calibration edge has fewer than 2 poses");
  const size_t count =
      std::min(edge_poses.size(), static_cast<size_t>(std::max(1, options.frames)) + 1);
  const std::vector<std::vector<JointPose>> poses(edge_poses.begin(),
                                                  edge_poses.begin() + static_cast<long>(count));
  AutoCalibration cal;
  cal.frames = static_cast<int>(count) - 1;
  cal.vertices = scene.model.vertex_count();
  std::vector<SolverKind> kinds = options.kinds;
  if (kinds.empty()) kinds.push_back(scene.file.solver);
  cal.reference =
      on_scene(calibration_reference(kinds.front(), options.newton_reference), scene.file.settings);
  // Every run starts from the garment settled by the reference solver.
  auto settler = make_solver(cal.reference.kind, scene.model, cal.reference.settings);
  const ClothState start = settle_garment(scene, *settler, poses.front());
  const Trial ref = simulate(scene, cal.reference, start, poses, rate);
  if (!ref.run.stable)
    throw std::runtime_error(scene.file.path.string() + ": --auto: the reference run (" +
                             cal.reference.label + ") is unstable: " + ref.run.message);
  cal.reference_cpu_ms_per_frame = 1e3 * ref.cpu / cal.frames;
  const std::vector<float> ref_x = flat(ref.end.x), ref_v = flat(ref.end.v);
  for (SolverKind kind : kinds)
    for (const SolverCandidate& base : solver_candidates(kind, options.quick)) {
      AutoCandidate cand;
      cand.config = on_scene(base, scene.file.settings);
      const Trial t = simulate(scene, cand.config, start, poses, rate);
      cand.cpu_ms_per_frame = 1e3 * t.cpu / cal.frames;
      cand.stable = t.run.stable;
      cand.message = t.run.message;
      if (cand.stable) {
        const FrameErrors e = compare_frames(t.run.frames, ref.run.frames, 0);
        cand.error = std::max(e.worst_frame_rms, db::state_distance(flat(t.end.x), flat(t.end.v),
                                                                    ref_x, ref_v, 1.0 / rate));
      }
      cal.candidates.push_back(std::move(cand));
    }
  return cal;
}

int pick_solver(const AutoCalibration& cal, double epsilon, double fraction) {
  int best = -1;
  for (size_t i = 0; i < cal.candidates.size(); ++i) {
    const AutoCandidate& c = cal.candidates[i];
    if (!c.stable || !(c.error <= fraction * epsilon)) continue;
    if (best < 0 || c.cpu_ms_per_frame < cal.candidates[best].cpu_ms_per_frame)
      best = static_cast<int>(i);
  }
  return best;
}

std::string auto_table(const AutoCalibration& cal, int chosen, double epsilon, double fraction) {
  std::ostringstream o;
  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "--auto: %d vertices, %d frames against the reference %s %s (%.1f ms/frame); accept error <= "
      "%.2f mm (%.2f x epsilon)\n",
      cal.vertices, cal.frames, solver_name(cal.reference.kind), cal.reference.label.c_str(),
      cal.reference_cpu_ms_per_frame, 1e3 * fraction * epsilon, fraction);
  o << buf << "| solver | settings | CPU ms/frame | error mm | verdict |\n|---|---|---|---|---|\n";
  for (size_t i = 0; i < cal.candidates.size(); ++i) {
    const AutoCandidate& c = cal.candidates[i];
    std::string verdict;
    if (static_cast<int>(i) == chosen)
      verdict = "**chosen**";
    else if (!c.stable)
      verdict = "unstable (" + c.message + ")";
    else if (!(c.error <= fraction * epsilon))
      verdict = "error above the bound";
    else
      verdict = "within the bound, costlier";
    std::snprintf(buf, sizeof buf, "| %s | %s | %.2f | %.3f | %s |\n", solver_name(c.config.kind),
                  c.config.label.c_str(), c.cpu_ms_per_frame, 1e3 * c.error, verdict.c_str());
    o << buf;
  }
  return o.str();
}

}  // namespace clothdb
