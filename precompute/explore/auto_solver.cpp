#include "explore/auto_solver.hpp"

#include <time.h>

#include <algorithm>
#include <cmath>
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

// The chaos floor's perturbation of the start, m: ten times the float32 rounding of metre-scale
// coordinates (what a state stored in the database and resumed from carries).
constexpr double kPerturbation = 1e-6;
// The comparison window ends where the floor exceeds this share of the bound.
constexpr double kFloorShare = 0.25;

Trial simulate(const CharacterScene& scene, const SolverCandidate& c, const ClothState& start,
               const std::vector<std::vector<JointPose>>& poses, double rate) {
  Trial t;
  auto solver = make_scene_solver(scene, c.kind, c.settings);
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
  cal.bound = options.fraction * options.epsilon;
  const SolverKind own = scene.file.solver;
  std::vector<SolverKind> kinds = options.kinds;
  if (kinds.empty()) kinds.push_back(own);
  if (options.newton_reference)
    cal.reference = on_scene(reference_candidate(), scene.file.settings);
  else if (kinds.front() == own)
    cal.reference = scene_reference(own, scene.file.settings);
  else
    cal.reference = on_scene(calibration_reference(kinds.front(), false), scene.file.settings);
  cal.reference.settings.threads = 1;
  // Every run starts from the garment settled by the reference solver.
  auto settler = make_scene_solver(scene, cal.reference.kind, cal.reference.settings);
  const ClothState start = settle_garment(scene, *settler, poses.front());
  const Trial ref = simulate(scene, cal.reference, start, poses, rate);
  if (!ref.run.stable)
    throw std::runtime_error(scene.file.path.string() + ": --auto: the reference run (" +
                             cal.reference.label + ") is unstable: " + ref.run.message);
  cal.reference_cpu_ms_per_frame = 1e3 * ref.cpu / cal.frames;

  // The chaos floor: the reference again from a start moved by kPerturbation along a fixed
  // pattern (free vertices only), frame by frame against the reference.
  ClothState perturbed_start = start;
  for (int i = 0; i < scene.model.vertex_count(); ++i)
    if (scene.model.inv_mass[i] > 0.0)
      for (int c = 0; c < 3; ++c)
        perturbed_start.x(c, i) += ((3 * i + c) % 2 == 0 ? 1.0 : -1.0) * kPerturbation;
  const Trial perturbed = simulate(scene, cal.reference, perturbed_start, poses, rate);
  cal.window = 0;
  for (size_t f = 0; f < ref.run.frames.size(); ++f) {
    double d = NAN;
    if (perturbed.run.stable && f < perturbed.run.frames.size())
      d = std::sqrt((ref.run.frames[f] - perturbed.run.frames[f]).colwise().squaredNorm().sum() /
                    std::max<double>(1, scene.model.vertex_count()));
    cal.floor.push_back(d);
    if (cal.window == static_cast<int>(f) && d <= kFloorShare * cal.bound) ++cal.window;
  }
  cal.window = std::max(1, cal.window);

  // The reference's state at the window's end (its frames are the same whatever the clip's
  // length: one step per pose).
  const std::vector<std::vector<JointPose>> window_poses(poses.begin(),
                                                         poses.begin() + cal.window + 1);
  const Trial ref_window =
      cal.window == cal.frames ? ref : simulate(scene, cal.reference, start, window_poses, rate);
  const std::vector<float> ref_x = flat(ref_window.end.x), ref_v = flat(ref_window.end.v);
  for (SolverKind kind : kinds) {
    std::vector<SolverCandidate> table;
    if (kind == own) {
      table = scene_variations(own, scene.file.settings, options.quick);
      cal.scene = static_cast<int>(cal.candidates.size());  // the first variation is its own
    } else {
      for (const SolverCandidate& base : solver_candidates(kind, options.quick))
        table.push_back(on_scene(base, scene.file.settings));
    }
    for (SolverCandidate& config : table) {
      config.settings.threads = 1;
      AutoCandidate cand;
      cand.config = config;
      const Trial t = simulate(scene, cand.config, start, window_poses, rate);
      cand.cpu_ms_per_frame = 1e3 * t.cpu / cal.window;
      cand.stable = t.run.stable;
      cand.message = t.run.message;
      if (cand.stable) {
        const FrameErrors e = compare_frames(t.run.frames, ref_window.run.frames, 0);
        cand.position_error = e.worst_frame_rms;
        cand.state_error =
            db::state_distance(flat(t.end.x), flat(t.end.v), ref_x, ref_v, 1.0 / rate);
        cand.error = std::max(cand.position_error, cand.state_error);
      }
      cal.candidates.push_back(std::move(cand));
    }
  }
  return cal;
}

int scene_index(const AutoCalibration& cal) {
  return cal.scene;
}

namespace {

int cheapest_within(const AutoCalibration& cal, double bound) {
  int best = -1;
  for (size_t i = 0; i < cal.candidates.size(); ++i) {
    const AutoCandidate& c = cal.candidates[i];
    if (!c.stable || !(c.error <= bound)) continue;
    if (best < 0 || c.cpu_ms_per_frame < cal.candidates[best].cpu_ms_per_frame)
      best = static_cast<int>(i);
  }
  return best;
}

// The scene's own candidate when it decides the choice (nothing within the bound, it is stable).
const AutoCandidate* scene_rule(const AutoCalibration& cal, double epsilon, double fraction) {
  if (cheapest_within(cal, fraction * epsilon) >= 0 || cal.scene < 0) return nullptr;
  const AutoCandidate& own = cal.candidates[static_cast<size_t>(cal.scene)];
  return own.stable && std::isfinite(own.error) ? &own : nullptr;
}

}  // namespace

int pick_solver(const AutoCalibration& cal, double epsilon, double fraction) {
  const int within = cheapest_within(cal, fraction * epsilon);
  if (within >= 0) return within;
  const AutoCandidate* own = scene_rule(cal, epsilon, fraction);
  return own ? cheapest_within(cal, own->error) : -1;
}

std::string auto_table(const AutoCalibration& cal, int chosen, double epsilon, double fraction) {
  std::ostringstream o;
  char buf[512];
  std::snprintf(
      buf, sizeof buf,
      "--auto: %d vertices, %d frames against the reference %s %s (%.1f ms/frame); accept error <= "
      "%.2f mm (%.2f x epsilon %.2f mm)\n",
      cal.vertices, cal.frames, solver_name(cal.reference.kind), cal.reference.label.c_str(),
      cal.reference_cpu_ms_per_frame, 1e3 * fraction * epsilon, fraction, 1e3 * epsilon);
  o << buf;
  if (!cal.floor.empty()) {
    const double at_window = cal.floor[static_cast<size_t>(cal.window) - 1];
    const double at_end = cal.floor.back();
    std::snprintf(buf, sizeof buf,
                  "chaos floor (the reference from a start moved by %.0f um): %.3f mm after %d "
                  "frames, %.3f mm after %d; compared over the first %d frames (floor <= %.2f x "
                  "the bound)\n",
                  1e6 * kPerturbation, 1e3 * at_window, cal.window, 1e3 * at_end, cal.frames,
                  cal.window, kFloorShare);
    o << buf;
  }
  if (const AutoCandidate* own = scene_rule(cal, epsilon, fraction)) {
    std::snprintf(buf, sizeof buf,
                  "no candidate is within %.2f mm; the scene's own setting (%s) is %.3f mm from "
                  "the reference, so the choice is the cheapest at most that error: the accuracy "
                  "the scene's setting was made with, at no more CPU\n",
                  1e3 * fraction * epsilon, own->config.label.c_str(), 1e3 * own->error);
    o << buf;
  }
  o << "| solver | settings | CPU ms/frame | error mm | positions mm | state mm | within bound | "
       "verdict |\n|---|---|---|---|---|---|---|---|\n";
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
    if (static_cast<int>(i) != chosen && c.stable && !(c.error <= fraction * epsilon)) {
      if (const AutoCandidate* own = scene_rule(cal, epsilon, fraction))
        verdict = c.error <= own->error ? "at most the scene's error, costlier"
                                        : "error above the bound and the scene's";
    }
    std::snprintf(buf, sizeof buf, "| %s | %s | %.2f | %.3f | %.3f | %.3f | %s | %s |\n",
                  solver_name(c.config.kind), c.config.label.c_str(), c.cpu_ms_per_frame,
                  1e3 * c.error, 1e3 * c.position_error, 1e3 * c.state_error,
                  c.stable && c.error <= fraction * epsilon ? "yes" : "no", verdict.c_str());
    o << buf;
  }
  return o.str();
}

}  // namespace clothdb
