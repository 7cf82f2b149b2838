#include "bench/solver_bench.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <sstream>
#include <tuple>

namespace clothdb {

namespace {

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += (c == '"') ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

}  // namespace

ClothScene make_bench_scene(const std::string& name, const SolverBenchOptions& options) {
  if (name == "large-sheet") return make_large_sheet(options.large_vertices);
  if (name == "seed004-529") return make_seed004_grid();
  if (name == "seed004-fall") return make_seed004_fall();
  return make_hard_case(name, options.resolution);
}

bool resolve_config(BenchConfig& c, const ClothScene& scene, const SolverBenchOptions& options,
                    std::string& why) {
  if (c.kind != SolverKind::MassSpring || !(c.critical_multiple > 0)) return true;
  const double critical = mass_spring_critical_dt(scene.model);
  const double needed = std::isfinite(critical) ? std::ceil(scene.frame_dt / critical) : 1.0;
  const double substeps = std::ceil(c.critical_multiple * needed);
  char buf[160];
  std::snprintf(buf, sizeof buf, "substeps=%.0f (%gx critical)", substeps, c.critical_multiple);
  c.label = buf;
  if (substeps > options.max_mass_spring_substeps) {
    std::snprintf(buf, sizeof buf,
                  "needs %.0f sub-steps per frame for stability (critical dt %.3g s), over the "
                  "cap of %d",
                  substeps, critical, options.max_mass_spring_substeps);
    why = buf;
    return false;
  }
  c.settings.substeps = static_cast<int>(substeps);
  return true;
}

BenchRow measure_config(const ClothScene& scene, const BenchConfig& c, int frames,
                        const RunResult& reference, const RunResult* tight) {
  auto solver = make_solver(c.kind, scene.model, c.settings);
  const RunResult run = run_scene(scene, *solver, frames, true);
  BenchRow row;
  row.scene = scene.name;
  row.vertices = scene.model.vertex_count();
  row.solver = solver_name(c.kind);
  row.settings = c.label;
  row.threads = c.settings.threads;
  row.frames = static_cast<int>(run.metrics.size()) - 1;
  row.ms_per_frame = row.frames > 0 ? 1e3 * run.seconds / row.frames : NAN;
  row.cpu_ms_per_frame = row.frames > 0 ? 1e3 * run.cpu_seconds / row.frames : NAN;
  row.stable = run.stable;
  row.message = run.message;
  const FrameErrors errors = compare_frames(run.frames, reference.frames, 1);
  const bool comparable = reference.stable && run.stable && std::isfinite(errors.rms) &&
                          std::min(run.frames.size(), reference.frames.size()) > 1;
  row.rms_error_mm = comparable ? 1e3 * errors.rms : NAN;
  row.max_error_mm = comparable ? 1e3 * errors.max : NAN;
  if (tight && tight->stable && run.stable && !run.frames.empty() &&
      run.frames.size() == tight->frames.size())
    std::tie(row.end_vs_tight_rms_mm, row.end_vs_tight_max_mm) =
        end_state_distance_mm(run.frames.back(), tight->frames.back());
  long iterations = 0, factorizations = 0;
  for (const auto& m : run.metrics) {
    row.max_strain = std::max(row.max_strain, m.max_strain);
    row.max_penetration_mm = std::max(row.max_penetration_mm, 1e3 * m.max_penetration);
    row.step_halvings += m.step_halvings;
    iterations += m.iterations;
    factorizations += m.factorizations;
  }
  if (row.frames > 0) {
    row.iterations_per_frame = static_cast<double>(iterations) / row.frames;
    row.factorizations_per_frame = static_cast<double>(factorizations) / row.frames;
  }
  return row;
}

std::vector<BenchConfig> newton_study_configs() {
  using L = LinearSolverKind;
  using G = SolverSettings::Guess;
  auto variant = [](L linear, double tolerance, G guess, double contraction, bool exact = true,
                    int substeps = 1) {
    BenchConfig c = candidate(SolverKind::Newton, substeps, 0, tolerance, linear);
    c.settings.newton_guess = guess;
    c.settings.newton_reuse_contraction = contraction;
    c.settings.newton_exact_hessian = exact;
    // The loop as it was before today's stopping rule (docs/notebook/BENCHMARKS.md,
    // "Newton on seed 004's grids"): force tolerance only, halve at the cap, exact first.
    c.settings.newton_velocity_tolerance = 0.0;
    c.settings.newton_accept_decrease = false;
    c.settings.newton_projected_first = false;
    const char* guess_name = guess == G::Start ? "x_n" : guess == G::Inertial ? "x+hv" : "x+hv+h2a";
    char buf[160];
    std::snprintf(buf, sizeof buf, "%s tol=%.0e start=%s chord=%s hessian=%s%s",
                  linear_solver_name(linear), tolerance, guess_name, contraction > 0 ? "yes" : "no",
                  exact ? "exact" : "projected",
                  substeps > 1 ? (" substeps=" + std::to_string(substeps)).c_str() : "");
    c.label = buf;
    return c;
  };
  // Today's loop (docs/notebook/BENCHMARKS.md, "Newton on seed 004's grids"): stop on the update
  // (no velocity change above `vtol`), keep a non-converged iterate that lowered Phi, projected
  // Hessian first, Eisenstat-Walker PCG tolerance.
  auto update_stop = [](L linear, double vtol, bool exact, double contraction = 0.0,
                        G guess = G::Start) {
    BenchConfig c = candidate(SolverKind::Newton, 1, 0, 1e-6, linear);
    c.settings.newton_velocity_tolerance = vtol;
    c.settings.newton_exact_hessian = exact;
    c.settings.newton_reuse_contraction = contraction;
    c.settings.newton_guess = guess;
    char buf[200];
    std::snprintf(buf, sizeof buf, "%s tol=1e-06 vtol=%.0e keep-descent hessian=%s%s%s",
                  linear_solver_name(linear), vtol, exact ? "projected-then-exact" : "projected",
                  contraction > 0 ? " chord=yes" : "",
                  guess == G::Extrapolate ? " start=x+hv+h2a"
                  : guess == G::Inertial  ? " start=x+hv"
                                          : "");
    c.label = buf;
    return c;
  };
  return {
      update_stop(L::SimplicialLDLT, 1e-3, true),
      update_stop(L::SimplicialLDLT, 1e-3, false),
      update_stop(L::SimplicialLDLT, 1e-4, true),
      update_stop(L::SimplicialLDLT, 1e-3, true, 0.5),
      update_stop(L::SimplicialLDLT, 1e-3, true, 0.0, G::Extrapolate),
      update_stop(L::SimplicialLDLT, 1e-3, true, 0.5, G::Extrapolate),
      update_stop(L::SimplicialLDLT, 1e-3, false, 0.5, G::Extrapolate),
      update_stop(L::Cholmod, 1e-3, true),
      update_stop(L::CholmodSupernodal, 1e-3, true),
      update_stop(L::CholmodSupernodal, 1e-3, true, 0.0, G::Extrapolate),
      update_stop(L::CholmodSupernodal, 3e-3, true, 0.0, G::Extrapolate),
      update_stop(L::CholmodSupernodal, 1e-2, true, 0.0, G::Extrapolate),
      update_stop(L::CholmodSupernodal, 1e-3, false, 0.0, G::Extrapolate),
      update_stop(L::ConjugateGradient, 1e-3, true),
      update_stop(L::ConjugateGradientIC, 1e-3, true),
      variant(L::SimplicialLDLT, 1e-6, G::Start, 0),  // the loop before this study
      variant(L::SimplicialLDLT, 1e-6, G::Inertial, 0),
      variant(L::SimplicialLDLT, 1e-6, G::Extrapolate, 0),
      variant(L::SimplicialLDLT, 1e-6, G::Start, 0.5),
      variant(L::SimplicialLDLT, 1e-6, G::Extrapolate, 0.5),
      variant(L::SimplicialLDLT, 1e-4, G::Extrapolate, 0.5),
      variant(L::SimplicialLDLT, 1e-3, G::Extrapolate, 0.5),
      variant(L::SimplicialLDLT, 1e-2, G::Extrapolate, 0.5),
      variant(L::SimplicialLDLT, 1e-3, G::Extrapolate, 0.5, false),
      variant(L::SimplicialLDLT, 1e-3, G::Extrapolate, 0, false),
      variant(L::SimplicialLDLT, 1e-3, G::Extrapolate, 0.5, false, 2),
      variant(L::Cholmod, 1e-6, G::Start, 0),
      variant(L::Cholmod, 1e-3, G::Extrapolate, 0.5),
      variant(L::ConjugateGradient, 1e-6, G::Start, 0),
      variant(L::ConjugateGradient, 1e-3, G::Extrapolate, 0),
      variant(L::ConjugateGradient, 1e-3, G::Extrapolate, 0.5),
      variant(L::ConjugateGradientIC, 1e-6, G::Start, 0),
      variant(L::ConjugateGradientIC, 1e-3, G::Extrapolate, 0),
      variant(L::ConjugateGradientIC, 1e-3, G::Extrapolate, 0.5),
  };
}

BenchConfig newton_tight_config() {
  BenchConfig c = candidate(SolverKind::Newton, 1, 0, 1e-8, LinearSolverKind::SimplicialLDLT);
  c.settings.newton_velocity_tolerance = 1e-7;
  c.settings.newton_accept_decrease = true;
  c.settings.newton_max_iterations = 200;
  c.label = "tight: ldlt substeps=1 tol=1e-08 vtol=1e-07 max-iterations=200";
  return c;
}

std::pair<double, double> end_state_distance_mm(const Eigen::Matrix3Xd& a,
                                                const Eigen::Matrix3Xd& b) {
  if (a.cols() != b.cols() || a.cols() == 0) return {NAN, NAN};
  const Eigen::RowVectorXd d = (a - b).colwise().norm();
  return {1e3 * std::sqrt(d.squaredNorm() / static_cast<double>(d.size())), 1e3 * d.maxCoeff()};
}

std::vector<BenchRow> run_newton_study(const std::vector<std::string>& scenes, int frames,
                                       int repeat, const std::vector<std::string>& only,
                                       const std::function<void(const std::string&)>& progress) {
  std::vector<BenchRow> rows;
  SolverBenchOptions options;
  for (const auto& name : scenes) {
    const ClothScene scene = make_bench_scene(name, options);
    const int n = frames > 0 ? frames : scene.frames;
    const BenchConfig ref_config = reference_config();
    auto ref_solver = make_solver(ref_config.kind, scene.model, ref_config.settings);
    const RunResult reference = run_scene(scene, *ref_solver, n, true);
    if (progress) progress(name + ": reference " + ref_config.label);
    const BenchConfig tight_config = newton_tight_config();
    auto tight_solver = make_solver(tight_config.kind, scene.model, tight_config.settings);
    const RunResult tight = run_scene(scene, *tight_solver, n, true);
    if (progress) {
      int halvings = 0;
      for (const auto& m : tight.metrics) halvings += m.step_halvings;
      progress(name + ": " + tight_config.label + ", " + std::to_string(halvings) + " halvings" +
               (tight.stable ? "" : " UNSTABLE: " + tight.message));
    }
    for (const BenchConfig& c : newton_study_configs()) {
      if (!only.empty() && std::none_of(only.begin(), only.end(), [&](const std::string& o) {
            return c.label.find(o) != std::string::npos;
          }))
        continue;
      BenchRow best;
      for (int k = 0; k < std::max(1, repeat); ++k) {
        BenchRow row = measure_config(scene, c, n, reference, &tight);
        if (k == 0 || row.cpu_ms_per_frame < best.cpu_ms_per_frame) best = row;
      }
      rows.push_back(best);
      if (progress) {
        char buf[512];
        std::snprintf(buf, sizeof buf,
                      "%s: %-40s %8.2f ms/frame (cpu %8.2f)  %5.2f it  %5.2f fact  %d halvings  "
                      "rms %9.4f mm  end vs tight %.3g mm (max %.3g) %s",
                      name.c_str(), best.settings.c_str(), best.ms_per_frame, best.cpu_ms_per_frame,
                      best.iterations_per_frame, best.factorizations_per_frame, best.step_halvings,
                      best.rms_error_mm, best.end_vs_tight_rms_mm, best.end_vs_tight_max_mm,
                      best.stable ? "" : ("UNSTABLE: " + best.message).c_str());
        progress(buf);
      }
    }
  }
  return rows;
}

std::string newton_study_markdown(const std::vector<BenchRow>& rows) {
  std::ostringstream o;
  o << "| scene | variant | ms/frame | CPU ms/frame | Newton it./frame | factorisations/frame | "
       "RMS err mm | max err mm | end vs tight RMS mm | end vs tight max mm | halvings | stable "
       "|\n|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  char buf[512];
  for (const auto& r : rows) {
    std::snprintf(buf, sizeof buf,
                  "| %s | %s | %.2f | %.2f | %.2f | %.2f | %.3g | %.3g | %.3g | %.3g | %d | %s |\n",
                  r.scene.c_str(), r.settings.c_str(), r.ms_per_frame, r.cpu_ms_per_frame,
                  r.iterations_per_frame, r.factorizations_per_frame, r.rms_error_mm,
                  r.max_error_mm, r.end_vs_tight_rms_mm, r.end_vs_tight_max_mm, r.step_halvings,
                  r.stable ? "yes" : "no");
    o << buf;
  }
  return o.str();
}

std::string bench_rows_csv(const std::vector<BenchRow>& rows) {
  std::ostringstream o;
  o << "scene,vertices,solver,settings,threads,frames,ms_per_frame,cpu_ms_per_frame,rms_error_mm,"
       "max_error_mm,max_strain,max_penetration_mm,step_halvings,iterations_per_frame,"
       "factorizations_per_frame,stable,run,message\n";
  for (const auto& r : rows) {
    o << csv_field(r.scene) << ',' << r.vertices << ',' << r.solver << ',' << csv_field(r.settings)
      << ',' << r.threads << ',' << r.frames << ',' << r.ms_per_frame << ',' << r.cpu_ms_per_frame
      << ',' << r.rms_error_mm << ',' << r.max_error_mm << ',' << r.max_strain << ','
      << r.max_penetration_mm << ',' << r.step_halvings << ',' << r.iterations_per_frame << ','
      << r.factorizations_per_frame << ',' << (r.stable ? "yes" : "no") << ','
      << (r.run ? "yes" : "no") << ',' << csv_field(r.message) << '\n';
  }
  return o.str();
}

std::string bench_rows_json(const std::vector<BenchRow>& rows) {
  nlohmann::json j = nlohmann::json::array();
  auto num = [](double v) {
    return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
  };
  for (const auto& r : rows) {
    j.push_back({{"scene", r.scene},
                 {"vertices", r.vertices},
                 {"solver", r.solver},
                 {"settings", r.settings},
                 {"threads", r.threads},
                 {"frames", r.frames},
                 {"ms_per_frame", num(r.ms_per_frame)},
                 {"cpu_ms_per_frame", num(r.cpu_ms_per_frame)},
                 {"iterations_per_frame", r.iterations_per_frame},
                 {"factorizations_per_frame", r.factorizations_per_frame},
                 {"run", r.run},
                 {"rms_error_mm", num(r.rms_error_mm)},
                 {"max_error_mm", num(r.max_error_mm)},
                 {"end_vs_tight_rms_mm", num(r.end_vs_tight_rms_mm)},
                 {"end_vs_tight_max_mm", num(r.end_vs_tight_max_mm)},
                 {"max_strain", num(r.max_strain)},
                 {"max_penetration_mm", num(r.max_penetration_mm)},
                 {"step_halvings", r.step_halvings},
                 {"stable", r.stable},
                 {"message", r.message}});
  }
  return j.dump(1) + "\n";
}

}  // namespace clothdb
