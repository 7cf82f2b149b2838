#include "bench/solver_accuracy.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <stdexcept>

#include "bench/solver_bench.hpp"
#include "cloth/self_intersection.hpp"
#include "report/cpu_time.hpp"
#include "report/stats.hpp"

namespace clothdb {

namespace {

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += (c == '"') ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

nlohmann::json num(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

std::string fmt(const char* format, double v) {
  if (!std::isfinite(v)) return "n/a";
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

// Sum of squared vertex distances and the largest one between two position sets.
void accumulate(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b, double& sum2, double& worst,
                long& count) {
  const Eigen::Matrix3Xd d = a - b;
  const Eigen::RowVectorXd n2 = d.colwise().squaredNorm();
  sum2 += n2.sum();
  worst = std::max(worst, std::sqrt(n2.maxCoeff()));
  count += d.cols();
}

ErrorMm to_mm(double sum2, double worst, long count) {
  if (count == 0) return {};
  return {1e3 * std::sqrt(sum2 / static_cast<double>(count)), 1e3 * worst};
}

SolverBenchOptions cap_options(const AccuracyOptions& options) {
  SolverBenchOptions o;
  o.max_mass_spring_substeps = options.max_mass_spring_substeps;
  return o;
}

nlohmann::json stats_json(const EnsembleStats& s) {
  return {{"sag_mm", num(s.sag_mm)},
          {"strain_p99", num(s.strain_p99)},
          {"kinetic_decay", num(s.kinetic_decay)},
          {"penetration_mm", num(s.penetration_mm)}};
}

}  // namespace

SolverCandidate accuracy_reference(int substeps, double tolerance) {
  SolverCandidate c =
      candidate(SolverKind::Newton, substeps, 0, tolerance, LinearSolverKind::SimplicialLDLT);
  // Converged on the force residual alone (the solver never asks for less than its rounding
  // floor, 16 eps * stiffness * |x|), never kept unconverged: a step that does not converge is
  // halved, which the benchmark counts and flags (a uniform reference has none).
  c.settings.newton_velocity_tolerance = 0.0;
  c.settings.newton_accept_decrease = false;
  c.settings.threads = 1;
  return c;
}

Trajectory simulate_from(const ClothScene& scene, const SolverCandidate& candidate,
                         const ClothState& start, int first, int frames) {
  Trajectory out;
  out.states.reserve(static_cast<size_t>(frames) + 1);
  out.states.push_back(start);
  SolverSettings settings = candidate.settings;
  if (candidate.kind == SolverKind::Xpbd)
    settings.self_collision_thickness_mm = scene.self_collision_mm;
  auto solver = make_solver(candidate.kind, scene.model, settings);
  ClothState state = start;
  Environment env = scene.env;
  StepInputs inputs;
  inputs.env = &env;
  for (int f = 1; f <= frames; ++f) {
    const double t0 = (first + f - 1) * scene.frame_dt, t1 = (first + f) * scene.frame_dt;
    if (scene.collider_path) scene.collider_path(t0, t1, env);
    if (scene.kinematic_path) inputs.kinematic_targets = scene.kinematic_path(t1);
    const double cpu0 = process_cpu_seconds();
    const StepReport report = solver->step(state, scene.frame_dt, inputs);
    out.cpu_seconds += process_cpu_seconds() - cpu0;
    out.step_halvings += report.step_halvings;
    if (!report.stable) {
      out.stable = false;
      out.message = "frame " + std::to_string(first + f) + ": " + report.message;
      break;
    }
    out.states.push_back(state);
  }
  return out;
}

ClothState perturbed_state(const ClothScene& scene, const ClothState& start, double distance,
                           uint64_t seed) {
  ClothState out = start;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int i = 0; i < scene.model.vertex_count(); ++i) {
    if (!(scene.model.inv_mass[i] > 0)) continue;  // pins stay where the scene puts them
    Vec3 d(normal(rng), normal(rng), normal(rng));
    while (d.norm() < 1e-12) d = Vec3(normal(rng), normal(rng), normal(rng));
    out.x.col(i) += distance * d.normalized();
  }
  return out;
}

std::vector<ErrorMm> frame_errors(const Trajectory& a, const Trajectory& b) {
  std::vector<ErrorMm> out;
  const size_t n = std::min(a.states.size(), b.states.size());
  for (size_t f = 0; f < n; ++f) {
    double sum2 = 0, worst = 0;
    long count = 0;
    accumulate(a.states[f].x, b.states[f].x, sum2, worst, count);
    out.push_back(to_mm(sum2, worst, count));
  }
  return out;
}

ErrorMm pooled_error(const Trajectory& a, const Trajectory& b, size_t first) {
  double sum2 = 0, worst = 0;
  long count = 0;
  const size_t n = std::min(a.states.size(), b.states.size());
  for (size_t f = first; f < n; ++f) accumulate(a.states[f].x, b.states[f].x, sum2, worst, count);
  return to_mm(sum2, worst, count);
}

std::vector<int> window_starts(int reference_frames, int restart_every, int horizon) {
  std::vector<int> out;
  for (int s = 0; s + horizon <= reference_frames; s += std::max(1, restart_every))
    out.push_back(s);
  return out;
}

Windows run_windows(const ClothScene& scene, const SolverCandidate& candidate,
                    const Trajectory& reference, int restart_every, int horizon) {
  Windows out;
  out.starts = window_starts(static_cast<int>(reference.states.size()) - 1, restart_every, horizon);
  for (int s : out.starts) {
    // A fresh solver per window: nothing a solver carries between steps (a previous acceleration,
    // warm starts) survives from a state it did not produce.
    const Trajectory t = simulate_from(scene, candidate, reference.states[s], s, horizon);
    out.cpu_seconds += t.cpu_seconds;
    out.step_halvings += t.step_halvings;
    if (!t.stable) {
      out.stable = false;
      out.message = t.message;
      break;
    }
    std::vector<Eigen::Matrix3Xd> frames;
    for (size_t f = 1; f < t.states.size(); ++f) frames.push_back(t.states[f].x);
    out.runs.push_back(std::move(frames));
  }
  return out;
}

Windows reference_windows(const Trajectory& reference, int restart_every, int horizon) {
  Windows out;
  out.starts = window_starts(static_cast<int>(reference.states.size()) - 1, restart_every, horizon);
  out.stable = reference.stable;
  for (int s : out.starts) {
    std::vector<Eigen::Matrix3Xd> frames;
    for (int f = 1; f <= horizon; ++f) frames.push_back(reference.states[s + f].x);
    out.runs.push_back(std::move(frames));
  }
  return out;
}

ErrorMm windows_error(const Windows& a, const Windows& b) {
  if (!a.stable || !b.stable || a.starts != b.starts || a.runs.size() != b.runs.size()) return {};
  double sum2 = 0, worst = 0;
  long count = 0;
  for (size_t w = 0; w < a.runs.size(); ++w) {
    const size_t n = std::min(a.runs[w].size(), b.runs[w].size());
    for (size_t f = 0; f < n; ++f) accumulate(a.runs[w][f], b.runs[w][f], sum2, worst, count);
  }
  return to_mm(sum2, worst, count);
}

EnsembleStats ensemble_stats(const ClothScene& scene, const Trajectory& run) {
  EnsembleStats s;
  const int n = static_cast<int>(run.states.size()) - 1;
  if (n < 1) return s;
  const ClothModel& model = scene.model;
  const Vec3 g =
      scene.env.gravity.norm() > 0 ? Vec3(scene.env.gravity.normalized()) : Vec3(0, -1, 0);
  const Eigen::Matrix3Xd& x0 = run.states[0].x;
  // Sag: mean over free vertices of the drop along gravity, (x - x0) . g_hat.
  double sag_sum = 0;
  long sag_count = 0;
  std::vector<double> strains;
  for (int f = n / 2; f <= n; ++f) {
    const Eigen::Matrix3Xd& x = run.states[f].x;
    for (int i = 0; i < model.vertex_count(); ++i) {
      if (!(model.inv_mass[i] > 0)) continue;
      sag_sum += (x.col(i) - x0.col(i)).dot(g);
      ++sag_count;
    }
    append_edge_strains(model, x, strains);
  }
  s.sag_mm = sag_count > 0 ? 1e3 * sag_sum / static_cast<double>(sag_count) : NAN;
  s.strain_p99 = report::percentile(std::move(strains), 0.99);
  // Kinetic-energy decay: mean over the last quarter of the frames / the run's peak.
  double peak = 0, tail = 0;
  int tail_count = 0;
  for (int f = 0; f <= n; ++f) {
    const double ke = kinetic_energy(model, run.states[f].v);
    peak = std::max(peak, ke);
    if (f >= (3 * n) / 4) {
      tail += ke;
      ++tail_count;
    }
  }
  s.kinetic_decay = peak > 0 ? tail / tail_count / peak : 0.0;
  // Penetration against the colliders where they are at each frame (runs from frame 0).
  Environment env = scene.env;
  double pen = 0;
  for (int f = 1; f <= n; ++f) {
    if (scene.collider_path) scene.collider_path((f - 1) * scene.frame_dt, f * scene.frame_dt, env);
    pen = std::max(pen, max_penetration(run.states[f].x, model.inv_mass, env));
  }
  s.penetration_mm = 1e3 * pen;
  return s;
}

EnsembleSpread ensemble_spread(const std::vector<EnsembleStats>& members) {
  EnsembleSpread out;
  out.members = static_cast<int>(members.size());
  if (members.empty()) return out;
  auto field = [&](double EnsembleStats::*m, double& mn, double& mx, double& mean, double& sd) {
    mn = INFINITY, mx = -INFINITY;
    double sum = 0, sum2 = 0;
    for (const auto& s : members) {
      mn = std::min(mn, s.*m);
      mx = std::max(mx, s.*m);
      sum += s.*m;
    }
    mean = sum / static_cast<double>(members.size());
    for (const auto& s : members) sum2 += (s.*m - mean) * (s.*m - mean);
    sd = members.size() > 1 ? std::sqrt(sum2 / static_cast<double>(members.size() - 1)) : 0.0;
  };
  for (double EnsembleStats::*m : {&EnsembleStats::sag_mm, &EnsembleStats::strain_p99,
                                   &EnsembleStats::kinetic_decay, &EnsembleStats::penetration_mm})
    field(m, out.min.*m, out.max.*m, out.mean.*m, out.sd.*m);
  return out;
}

int stats_within_spread(const EnsembleStats& s, const EnsembleSpread& spread) {
  int within = 0;
  for (double EnsembleStats::*m : {&EnsembleStats::sag_mm, &EnsembleStats::strain_p99,
                                   &EnsembleStats::kinetic_decay, &EnsembleStats::penetration_mm}) {
    // The band: [min, max] of the members, widened to mean +- 2 sd (four members sample the
    // spread coarsely).
    const double lo = std::min(spread.min.*m, spread.mean.*m - 2 * spread.sd.*m);
    const double hi = std::max(spread.max.*m, spread.mean.*m + 2 * spread.sd.*m);
    if (s.*m >= lo && s.*m <= hi) ++within;
  }
  return within;
}

CostAtError cost_at_error(const std::vector<AccuracyRow>& rows, const std::string& solver,
                          double target_mm) {
  CostAtError out;
  out.solver = solver;
  out.target_mm = target_mm;
  std::vector<const AccuracyRow*> usable;
  std::vector<double> cost, error;
  for (const auto& r : rows) {
    if (r.solver != solver || !r.run || !r.stable || !std::isfinite(r.short_rms_mm) ||
        !std::isfinite(r.cpu_s_per_sim_s))
      continue;
    usable.push_back(&r);
    cost.push_back(r.cpu_s_per_sim_s);
    error.push_back(std::max(r.short_rms_mm, 1e-9));
  }
  if (usable.empty()) {
    out.how = "no stable setting";
    return out;
  }
  const std::vector<size_t> front = pareto_front(cost, error);  // cost up, error down
  for (size_t k = 0; k < front.size(); ++k) {
    const size_t i = front[k];
    if (error[i] > target_mm) continue;
    char buf[512];
    if (k == 0) {
      out.cpu_s_per_sim_s = cost[i];
      std::snprintf(buf, sizeof buf, "at most: the cheapest setting (%s) is at %.3g mm",
                    usable[i]->settings.c_str(), error[i]);
    } else {
      // Straight line in log cost against log error between the neighbours on the front.
      const size_t j = front[k - 1];
      const double t =
          (std::log(target_mm) - std::log(error[j])) / (std::log(error[i]) - std::log(error[j]));
      out.cpu_s_per_sim_s =
          std::exp(std::log(cost[j]) + t * (std::log(cost[i]) - std::log(cost[j])));
      std::snprintf(buf, sizeof buf, "interpolated between %s (%.3g mm) and %s (%.3g mm)",
                    usable[j]->settings.c_str(), error[j], usable[i]->settings.c_str(), error[i]);
    }
    out.how = buf;
    return out;
  }
  const size_t best =
      static_cast<size_t>(std::min_element(error.begin(), error.end()) - error.begin());
  char buf[512];
  std::snprintf(buf, sizeof buf, "not reached: best %.3g mm (%s)", error[best],
                usable[best]->settings.c_str());
  out.how = buf;
  return out;
}

// ---- static cases ----

double catenary_parameter(double length, double span) {
  if (!(length > span && span > 0))
    throw std::invalid_argument("catenary: the chain must be longer than the span");
  // l = 2 a sinh(S / 2a) falls monotonically from infinity (a -> 0) to S (a -> infinity):
  // bisection on log a.
  double lo = 1e-6 * span, hi = 1e6 * span;
  for (int k = 0; k < 200; ++k) {
    const double a = std::sqrt(lo * hi);
    if (2 * a * std::sinh(span / (2 * a)) > length)
      lo = a;
    else
      hi = a;
  }
  return std::sqrt(lo * hi);
}

StaticCase membrane_strip_case(bool quad_grid) {
  // About 0.1 m x 0.3 m: a quad grid at 20 mm, or equilateral triangles of 20 mm edges (rows
  // 17.3 mm apart, alternate rows shifted by half an edge).
  const double edge = 0.02;
  const int columns = 6, rows = quad_grid ? 16 : 18;
  ClothMesh mesh = quad_grid
                       ? make_quad_grid(columns, rows, edge * (columns - 1), edge * (rows - 1))
                       : make_equilateral_sheet(columns, rows, edge);
  const double width = edge * (columns - 1);
  const double length = mesh.rest(1, grid_index(mesh, 0, rows - 1)) - mesh.rest(1, 0);
  std::vector<int> top;
  for (int c = 0; c < columns; ++c) top.push_back(grid_index(mesh, c, rows - 1));
  Material m;
  m.poisson = 0.0;  // the material's; the edge-spring membranes have their lattice's own
  StaticCase out;
  out.name = quad_grid ? "membrane-strip-quad" : "membrane-strip";
  out.quantity = "elongation";
  out.formula = "(F + W/2) L / (E t w)";
  ClothScene& scene = out.scene;
  scene.name = out.name;
  scene.description = std::string(quad_grid ? "quad-grid" : "equilateral") +
                      " strip 0.1 m wide pinned along its top, 1 % strain worth of weight at its "
                      "bottom row";
  scene.model = make_model(std::move(mesh), m, top);
  scene.env.air_drag = 2.0 * m.density;
  scene.env.collision_margin = m.thickness;
  const double g = scene.env.gravity.norm();
  const double stiffness = m.stretch_stiffness();  // E t, N/m
  const double load = 0.01 * stiffness * width;    // F = 1 % of E t w, N
  // The weight hung on the bottom row in tributary shares (half a spacing at the two ends), so the
  // stress across the strip is uniform.
  std::vector<int> bottom;
  for (int c = 0; c < columns; ++c) bottom.push_back(grid_index(scene.model.mesh, c, 0));
  for (int c = 0; c < columns; ++c) {
    const double share = (c == 0 || c == columns - 1 ? 0.5 : 1.0) / (columns - 1);
    const int i = bottom[static_cast<size_t>(c)];
    scene.model.mass[i] += share * load / g;
    scene.model.inv_mass[i] = 1.0 / scene.model.mass[i];
  }
  scene.initial = rest_state(scene.model);
  scene.frames = 150;
  // The strip's own weight W stretches it as if W/2 hung at its end: int_0^L W (L - y) / L dy.
  const double own_weight = m.density * width * length * g;
  // elongation = F L / (E t w), plus the own weight's share.
  out.analytic_mm = 1e3 * (load + 0.5 * own_weight) * length / (stiffness * width);
  const Eigen::Matrix3Xd rest = scene.model.mesh.rest;
  out.measure_mm = [bottom, rest](const Eigen::Matrix3Xd& x) {
    double drop = 0;
    for (int i : bottom) drop += rest(1, i) - x(1, i);
    return 1e3 * drop / static_cast<double>(bottom.size());
  };
  return out;
}

StaticCase cantilever_plate_case(int rows) {
  StaticCase out;
  out.name = "cantilever-plate";
  out.quantity = "tip deflection";
  out.formula = "q L^4 / (8 D), L = length - h/2";
  out.scene = make_cantilever_plate(rows);
  const ClothScene& scene = out.scene;
  const ClothMesh& mesh = scene.model.mesh;
  const int columns = mesh.grid_columns;
  const std::vector<int> tip{grid_index(mesh, columns / 2, rows - 1),
                             grid_index(mesh, columns / 2 - 1, rows - 1)};
  // Euler-Bernoulli: tip = q L^4 / (8 D), q = rho g per unit area, L measured from half a row
  // spacing behind the last clamped row (the discrete clamp's effective root, as the Newton
  // test finds).
  const double h = kCantileverLength / (rows - 1);
  const double free_length = kCantileverLength - 0.5 * h;
  const Material& m = scene.model.material;
  const double q = m.density * scene.env.gravity.norm();
  out.analytic_mm = 1e3 * q * std::pow(free_length, 4) / (8 * m.bending_rigidity());
  out.measure_mm = [tip](const Eigen::Matrix3Xd& x) {
    return -1e3 * 0.5 * (x(1, tip[0]) + x(1, tip[1]));
  };
  return out;
}

StaticCase catenary_strip_case() {
  const double length = 1.0, width = 0.05, span = 0.8;
  const int columns = 41, rows = 3;
  ClothMesh mesh = make_quad_grid(columns, rows, length, width);
  Eigen::Matrix3d lay;  // horizontal: length along x, width along z
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(0, 0, 0));
  std::vector<int> ends, middle;
  for (int r = 0; r < rows; ++r) {
    ends.push_back(grid_index(mesh, 0, r));
    ends.push_back(grid_index(mesh, columns - 1, r));
    middle.push_back(grid_index(mesh, columns / 2, r));
  }
  Material m;
  StaticCase out;
  out.name = "catenary-strip";
  out.quantity = "mid-span sag";
  out.formula = "a (cosh(S/2a) - 1), l = 2 a sinh(S/2a)";
  ClothScene& scene = out.scene;
  scene.name = out.name;
  scene.description = "1 m strip hung from its two end columns 0.8 m apart";
  scene.model = make_model(std::move(mesh), m, ends);
  // About critical damping of the strip's slowest swing (omega ~ sqrt(g / sag) ~ 5 /s).
  scene.env.air_drag = 10.0 * m.density;
  scene.env.collision_margin = m.thickness;
  scene.initial = rest_state(scene.model);
  // Start flat with the strip pushed together to the span; the pins stay where the start puts
  // them and gravity pulls the strip into its catenary.
  scene.initial.x.row(0) = (scene.initial.x.row(0).array() * (span / length)).matrix();
  scene.frames = 150;
  const double a = catenary_parameter(length, span);
  out.analytic_mm = 1e3 * a * (std::cosh(span / (2 * a)) - 1);
  out.measure_mm = [middle](const Eigen::Matrix3Xd& x) {
    double y = 0;
    for (int i : middle) y += x(1, i);
    return -1e3 * y / static_cast<double>(middle.size());
  };
  return out;
}

std::vector<std::string> static_case_names() {
  return {"membrane-strip", "membrane-strip-quad", "cantilever-plate", "catenary-strip"};
}

StaticCase make_static_case(const std::string& name) {
  if (name == "membrane-strip") return membrane_strip_case(false);
  if (name == "membrane-strip-quad") return membrane_strip_case(true);
  if (name == "cantilever-plate") return cantilever_plate_case();
  if (name == "catenary-strip") return catenary_strip_case();
  throw std::invalid_argument("unknown static case '" + name + "'");
}

StaticRow measure_static(const StaticCase& c, const SolverCandidate& candidate, int frames) {
  StaticRow row;
  row.name = c.name;
  row.quantity = c.quantity;
  row.formula = c.formula;
  row.solver = solver_name(candidate.kind);
  row.settings = candidate.label;
  row.analytic_mm = c.analytic_mm;
  const Trajectory t = simulate_from(c.scene, candidate, c.scene.initial, 0, frames);
  row.stable = t.stable;
  row.message = t.message;
  if (!t.stable) return row;
  const ClothState& last = t.states.back();
  row.measured_mm = c.measure_mm(last.x);
  row.relative_error = row.measured_mm / row.analytic_mm - 1.0;
  row.final_kinetic_energy = kinetic_energy(c.scene.model, last.v);
  row.max_strain = max_edge_strain(c.scene.model, last.x);
  return row;
}

// ---- the benchmark ----

std::vector<SolverCandidate> accuracy_candidates(const AccuracyOptions& options) {
  std::vector<SolverKind> kinds;
  if (options.solvers.empty()) {
    kinds = {SolverKind::MassSpring, SolverKind::Pbd, SolverKind::Xpbd, SolverKind::Newton};
  } else {
    for (const auto& s : options.solvers) kinds.push_back(parse_solver_kind(s));
  }
  std::vector<SolverCandidate> out;
  for (SolverKind kind : kinds)
    for (SolverCandidate c : solver_candidates(kind, options.quick)) {
      c.settings.threads = 1;
      out.push_back(c);
    }
  for (SolverCandidate c : options.extra) {
    c.settings.threads = 1;
    out.push_back(c);
  }
  return out;
}

SolverCandidate refined_candidate(const SolverCandidate& c, int factor) {
  SolverCandidate out = c;
  out.settings.substeps = c.settings.substeps * factor;
  out.critical_multiple = 0;  // already resolved
  out.label = c.label + " x" + std::to_string(factor) + " sub-steps";
  return out;
}

namespace {

using Progress = std::function<void(const std::string&)>;

void say(const Progress& progress, const std::string& line) {
  if (progress) progress(line);
}

// A row for a setting that is not simulated.
AccuracyRow not_run_row(const ClothScene& scene, const SolverCandidate& c, const std::string& why) {
  AccuracyRow row;
  row.scene = scene.name;
  row.solver = solver_name(c.kind);
  row.settings = c.label;
  row.vertices = scene.model.vertex_count();
  row.run = row.stable = false;
  row.message = why;
  return row;
}

}  // namespace

SceneAccuracy measure_scene_accuracy(const ClothScene& scene, const AccuracyOptions& options,
                                     const Progress& progress) {
  if (options.horizon < 1 || options.restart_every < 1 || options.refine < 2 ||
      options.ensemble < 2 || options.reference_substeps < 1 || options.frames < 1)
    throw std::invalid_argument(
        "bench solvers: horizon, restart-every, frames and reference sub-steps must be >= 1, "
        "refine and ensemble >= 2");
  SceneAccuracy out;
  out.name = scene.name;
  out.description = scene.description;
  out.vertices = scene.model.vertex_count();
  out.frames = options.frames;
  const int k = options.restart_every, h = options.horizon;
  const double simulated = options.frames * scene.frame_dt;

  // 1. The reference, and the chaos floor: the reference from a start moved 1 um.
  const SolverCandidate ref =
      accuracy_reference(options.reference_substeps, options.reference_tolerance);
  out.reference = "newton " + ref.label + " vtol=0";
  const Trajectory reference = simulate_from(scene, ref, scene.initial, 0, options.frames);
  out.reference_halvings = reference.step_halvings;
  out.reference_stable = reference.stable;
  out.reference_message = reference.message;
  out.reference_cpu_s_per_sim_s = reference.cpu_seconds / simulated;
  say(progress, scene.name + ": reference " + ref.label + ", " +
                    std::to_string(reference.step_halvings) + " step halvings" +
                    (reference.stable ? "" : " UNSTABLE: " + reference.message));
  if (!reference.stable) return out;
  const Trajectory perturbed = simulate_from(
      scene, ref, perturbed_state(scene, scene.initial, options.perturbation, options.seed), 0,
      options.frames);
  out.chaos_floor = frame_errors(reference, perturbed);
  out.chaos_floor_peak_rms_mm = out.chaos_floor_peak_max_mm = 0;
  for (const ErrorMm& e : out.chaos_floor) {
    out.chaos_floor_peak_rms_mm = std::max(out.chaos_floor_peak_rms_mm, e.rms);
    out.chaos_floor_peak_max_mm = std::max(out.chaos_floor_peak_max_mm, e.max);
  }
  out.chaos_floor_final_rms_mm = out.chaos_floor.empty() ? NAN : out.chaos_floor.back().rms;
  out.chaotic = out.chaos_floor_peak_rms_mm >= options.chaotic_floor_mm;
  if (!perturbed.stable) out.chaos_floor_message = "perturbed run stopped: " + perturbed.message;
  say(progress, scene.name + ": chaos floor " + fmt("%.3g", out.chaos_floor_final_rms_mm) +
                    " mm RMS at the last frame, peak " + fmt("%.3g", out.chaos_floor_peak_rms_mm) +
                    " mm" + (out.chaotic ? " (chaotic)" : "") +
                    (perturbed.stable ? "" : " (" + out.chaos_floor_message + ")"));

  // 2. The reference's own time error: its windows at twice the sub-steps.
  const Windows ref_windows = reference_windows(reference, k, h);
  const Windows ref_fine = run_windows(
      scene, accuracy_reference(2 * options.reference_substeps, options.reference_tolerance),
      reference, k, h);
  out.reference_time_error_rms_mm = windows_error(ref_fine, ref_windows).rms;
  out.reference_halvings += ref_fine.step_halvings;
  say(progress, scene.name + ": reference time error (against 2x sub-steps) " +
                    fmt("%.3g", out.reference_time_error_rms_mm) + " mm RMS");

  // 3. The ensemble of perturbed references, for chaotic scenes.
  if (out.chaotic) {
    out.ensemble.push_back(ensemble_stats(scene, reference));
    out.ensemble.push_back(ensemble_stats(scene, perturbed));
    for (int m = 2; m < options.ensemble; ++m) {
      const Trajectory member =
          simulate_from(scene, ref,
                        perturbed_state(scene, scene.initial, options.perturbation,
                                        options.seed + static_cast<uint64_t>(m)),
                        0, options.frames);
      if (member.stable) out.ensemble.push_back(ensemble_stats(scene, member));
      say(progress, scene.name + ": ensemble member " + std::to_string(m + 1));
    }
    out.spread = ensemble_spread(out.ensemble);
  }

  // 4. Every setting: continuous run, short-horizon windows, refined windows.
  const SolverBenchOptions caps = cap_options(options);
  for (SolverCandidate c : accuracy_candidates(options)) {
    std::string why;
    if (!resolve_config(c, scene, caps, why)) {
      out.rows.push_back(not_run_row(scene, c, why));
      say(progress, scene.name + ": " + solver_name(c.kind) + " " + c.label + " not run: " + why);
      continue;
    }
    AccuracyRow row;
    row.scene = scene.name;
    row.solver = solver_name(c.kind);
    row.settings = c.label;
    row.vertices = out.vertices;
    const Trajectory run = simulate_from(scene, c, scene.initial, 0, options.frames);
    row.stable = run.stable;
    row.message = run.message;
    row.step_halvings = run.step_halvings;
    const int done_frames = static_cast<int>(run.states.size()) - 1;
    if (done_frames > 0) row.cpu_s_per_sim_s = run.cpu_seconds / (done_frames * scene.frame_dt);
    row.self_intersections = 0;
    for (const ClothState& st : run.states)
      row.self_intersections =
          std::max(row.self_intersections, count_self_intersections(scene.model.mesh, st.x));
    if (run.stable) {
      row.long_run_rms_mm = pooled_error(run, reference).rms;
      row.long_run_final_rms_mm = frame_errors(run, reference).back().rms;
      row.long_run_within_floor = row.long_run_final_rms_mm <= out.chaos_floor_final_rms_mm;
      if (out.chaotic) {
        row.stats = ensemble_stats(scene, run);
        row.stats_within = stats_within_spread(row.stats, out.spread);
      }
    }
    const Windows windows = run_windows(scene, c, reference, k, h);
    if (!windows.stable) {
      row.stable = false;
      if (row.message.empty()) row.message = "window: " + windows.message;
    }
    const ErrorMm short_error = windows_error(windows, ref_windows);
    row.short_rms_mm = short_error.rms;
    row.short_max_mm = short_error.max;
    row.refine = options.refine;
    const SolverCandidate fine = refined_candidate(c, options.refine);
    if (c.kind == SolverKind::MassSpring &&
        fine.settings.substeps > options.max_mass_spring_substeps) {
      row.message += (row.message.empty() ? "" : "; ") + std::string("refined run not made: ") +
                     std::to_string(fine.settings.substeps) + " sub-steps over the cap";
    } else if (windows.stable) {
      const Windows fine_windows = run_windows(scene, fine, reference, k, h);
      row.self_convergence_rms_mm = windows_error(windows, fine_windows).rms;
      row.model_mismatch_rms_mm = windows_error(fine_windows, ref_windows).rms;
    }
    out.rows.push_back(row);
    char buf[640];
    std::snprintf(buf, sizeof buf,
                  "%s: %-11s %-34s %8.3g CPU s/sim s  short %8.3g mm  self-conv %8.3g mm  "
                  "mismatch %8.3g mm  long-run %8.3g mm%s",
                  scene.name.c_str(), row.solver.c_str(), row.settings.c_str(), row.cpu_s_per_sim_s,
                  row.short_rms_mm, row.self_convergence_rms_mm, row.model_mismatch_rms_mm,
                  row.long_run_rms_mm, row.stable ? "" : (" UNSTABLE: " + row.message).c_str());
    say(progress, buf);
  }
  for (const char* solver : {"mass-spring", "pbd", "xpbd", "newton"}) {
    if (std::none_of(out.rows.begin(), out.rows.end(),
                     [&](const AccuracyRow& r) { return r.solver == solver; }))
      continue;
    for (double target : options.target_errors_mm)
      out.cost.push_back(cost_at_error(out.rows, solver, target));
  }
  return out;
}

AccuracyReport run_accuracy_bench(
    const AccuracyOptions& options,
    const std::function<void(const std::string&, int, int)>& progress) {
  AccuracyReport report;
  report.options = options;
  std::vector<std::string> scenes = options.scenes;
  if (scenes.empty())
    scenes = {"hanging-sheet", "swung-sheet", "sphere-drape", "stretched-start", "seed004-fall"};
  SolverBenchOptions scene_options;
  scene_options.resolution = options.resolution;
  std::vector<ClothScene> built;
  for (const auto& s : scenes) built.push_back(make_bench_scene(s, scene_options));
  const std::vector<SolverCandidate> candidates = accuracy_candidates(options);
  const std::vector<std::string> statics =
      options.statics ? static_case_names() : std::vector<std::string>{};
  // In the static cases XPBD is also run without its long-range attachments (tethers), which
  // otherwise hold every vertex within its rest distance of the pins and so hide the strain its
  // compliance gives.
  std::vector<SolverCandidate> static_candidates;
  for (const SolverCandidate& c : candidates) {
    static_candidates.push_back(c);
    if (c.kind != SolverKind::Xpbd) continue;
    SolverCandidate loose = c;
    loose.settings.tethers = false;
    loose.label += " tethers=off";
    static_candidates.push_back(loose);
  }
  // Units of work: per scene the reference, its perturbed twin, its time check, the ensemble's
  // further members and one per setting; per static case one per setting.
  const int per_scene = 3 + (options.ensemble - 2) + static_cast<int>(candidates.size());
  const int total = per_scene * static_cast<int>(built.size()) +
                    static_cast<int>(statics.size() * static_candidates.size());
  int done = 0;
  for (const ClothScene& scene : built) {
    const int scene_start = done;
    report.scenes.push_back(measure_scene_accuracy(scene, options, [&](const std::string& line) {
      done = std::min(done + 1, scene_start + per_scene);
      if (progress) progress(line, done, total);
    }));
    done = scene_start + per_scene;  // skipped ensemble members count as done
  }
  const SolverBenchOptions caps = cap_options(options);
  for (const auto& name : statics) {
    const StaticCase c = make_static_case(name);
    for (SolverCandidate candidate : static_candidates) {
      std::string why;
      StaticRow row;
      if (!resolve_config(candidate, c.scene, caps, why)) {
        row.name = c.name;
        row.quantity = c.quantity;
        row.formula = c.formula;
        row.solver = solver_name(candidate.kind);
        row.settings = candidate.label;
        row.analytic_mm = c.analytic_mm;
        row.run = row.stable = false;
        row.message = why;
      } else {
        row = measure_static(c, candidate, options.static_frames);
      }
      report.statics.push_back(row);
      ++done;
      if (progress) {
        char buf[512];
        std::snprintf(buf, sizeof buf, "%s: %-11s %-34s %s %.4g mm, analytic %.4g mm (%+.2f %%)%s",
                      row.name.c_str(), row.solver.c_str(), row.settings.c_str(),
                      row.quantity.c_str(), row.measured_mm, row.analytic_mm,
                      100 * row.relative_error,
                      row.run ? (row.stable ? "" : " UNSTABLE") : (" not run: " + why).c_str());
        progress(buf, done, total);
      }
    }
  }
  return report;
}

// ---- output ----

std::string accuracy_json(const AccuracyReport& report) {
  const AccuracyOptions& o = report.options;
  nlohmann::json j;
  j["options"] = {{"frames", o.frames},
                  {"restart_every", o.restart_every},
                  {"horizon", o.horizon},
                  {"refine", o.refine},
                  {"reference_substeps", o.reference_substeps},
                  {"reference_tolerance", o.reference_tolerance},
                  {"perturbation_m", o.perturbation},
                  {"ensemble", o.ensemble},
                  {"chaotic_floor_mm", o.chaotic_floor_mm},
                  {"target_errors_mm", o.target_errors_mm},
                  {"static_frames", o.static_frames},
                  {"quick", o.quick},
                  {"seed", o.seed}};
  nlohmann::json scenes = nlohmann::json::array();
  for (const SceneAccuracy& s : report.scenes) {
    nlohmann::json floor_rms = nlohmann::json::array(), floor_max = nlohmann::json::array();
    for (const ErrorMm& e : s.chaos_floor) {
      floor_rms.push_back(num(e.rms));
      floor_max.push_back(num(e.max));
    }
    nlohmann::json rows = nlohmann::json::array();
    for (const AccuracyRow& r : s.rows) {
      rows.push_back({{"solver", r.solver},
                      {"settings", r.settings},
                      {"run", r.run},
                      {"stable", r.stable},
                      {"message", r.message},
                      {"cpu_s_per_sim_s", num(r.cpu_s_per_sim_s)},
                      {"short_horizon_rms_mm", num(r.short_rms_mm)},
                      {"short_horizon_max_mm", num(r.short_max_mm)},
                      {"self_convergence_rms_mm", num(r.self_convergence_rms_mm)},
                      {"model_mismatch_rms_mm", num(r.model_mismatch_rms_mm)},
                      {"refine", r.refine},
                      {"long_run_rms_mm", num(r.long_run_rms_mm)},
                      {"long_run_final_rms_mm", num(r.long_run_final_rms_mm)},
                      {"long_run_within_chaos_floor", r.long_run_within_floor},
                      {"step_halvings", r.step_halvings},
                      {"self_intersections", r.self_intersections},
                      {"ensemble_stats", stats_json(r.stats)},
                      {"ensemble_stats_within_spread", r.stats_within}});
    }
    nlohmann::json members = nlohmann::json::array();
    for (const auto& m : s.ensemble) members.push_back(stats_json(m));
    nlohmann::json cost = nlohmann::json::array();
    for (const auto& c : s.cost)
      cost.push_back({{"solver", c.solver},
                      {"target_mm", num(c.target_mm)},
                      {"cpu_s_per_sim_s", num(c.cpu_s_per_sim_s)},
                      {"how", c.how}});
    scenes.push_back({{"scene", s.name},
                      {"description", s.description},
                      {"vertices", s.vertices},
                      {"frames", s.frames},
                      {"reference", s.reference},
                      {"reference_step_halvings", s.reference_halvings},
                      {"reference_uniform", s.reference_halvings == 0},
                      {"reference_stable", s.reference_stable},
                      {"reference_message", s.reference_message},
                      {"reference_cpu_s_per_sim_s", num(s.reference_cpu_s_per_sim_s)},
                      {"reference_time_error_rms_mm", num(s.reference_time_error_rms_mm)},
                      {"chaos_floor_rms_mm", floor_rms},
                      {"chaos_floor_max_mm", floor_max},
                      {"chaos_floor_final_rms_mm", num(s.chaos_floor_final_rms_mm)},
                      {"chaos_floor_peak_rms_mm", num(s.chaos_floor_peak_rms_mm)},
                      {"chaos_floor_peak_max_mm", num(s.chaos_floor_peak_max_mm)},
                      {"chaotic", s.chaotic},
                      {"chaos_floor_message", s.chaos_floor_message},
                      {"ensemble", members},
                      {"ensemble_min", stats_json(s.spread.min)},
                      {"ensemble_max", stats_json(s.spread.max)},
                      {"ensemble_mean", stats_json(s.spread.mean)},
                      {"ensemble_sd", stats_json(s.spread.sd)},
                      {"rows", rows},
                      {"cost_at_target", cost}});
  }
  j["scenes"] = scenes;
  nlohmann::json statics = nlohmann::json::array();
  for (const StaticRow& r : report.statics)
    statics.push_back({{"case", r.name},
                       {"quantity", r.quantity},
                       {"formula", r.formula},
                       {"solver", r.solver},
                       {"settings", r.settings},
                       {"analytic_mm", num(r.analytic_mm)},
                       {"measured_mm", num(r.measured_mm)},
                       {"relative_error", num(r.relative_error)},
                       {"final_kinetic_energy_j", num(r.final_kinetic_energy)},
                       {"max_strain", num(r.max_strain)},
                       {"run", r.run},
                       {"stable", r.stable},
                       {"message", r.message}});
  j["statics"] = statics;
  return j.dump(1) + "\n";
}

std::string accuracy_rows_csv(const AccuracyReport& report) {
  std::ostringstream o;
  o << "scene,vertices,solver,settings,run,stable,cpu_s_per_sim_s,short_horizon_rms_mm,"
       "short_horizon_max_mm,self_convergence_rms_mm,model_mismatch_rms_mm,refine,"
       "long_run_rms_mm,long_run_final_rms_mm,chaos_floor_final_rms_mm,"
       "long_run_within_chaos_floor,reference_time_error_rms_mm,step_halvings,sag_mm,strain_p99,"
       "kinetic_decay,penetration_mm,stats_within_spread,message\n";
  for (const SceneAccuracy& s : report.scenes)
    for (const AccuracyRow& r : s.rows) {
      o << csv_field(r.scene) << ',' << r.vertices << ',' << r.solver << ','
        << csv_field(r.settings) << ',' << (r.run ? "yes" : "no") << ','
        << (r.stable ? "yes" : "no") << ',' << r.cpu_s_per_sim_s << ',' << r.short_rms_mm << ','
        << r.short_max_mm << ',' << r.self_convergence_rms_mm << ',' << r.model_mismatch_rms_mm
        << ',' << r.refine << ',' << r.long_run_rms_mm << ',' << r.long_run_final_rms_mm << ','
        << s.chaos_floor_final_rms_mm << ',' << (r.long_run_within_floor ? "yes" : "no") << ','
        << s.reference_time_error_rms_mm << ',' << r.step_halvings << ',' << r.stats.sag_mm << ','
        << r.stats.strain_p99 << ',' << r.stats.kinetic_decay << ',' << r.stats.penetration_mm
        << ',' << r.stats_within << ',' << csv_field(r.message) << '\n';
    }
  return o.str();
}

std::string accuracy_statics_csv(const AccuracyReport& report) {
  std::ostringstream o;
  o << "case,quantity,formula,solver,settings,analytic_mm,measured_mm,relative_error,"
       "final_kinetic_energy_j,max_strain,run,stable,message\n";
  for (const StaticRow& r : report.statics)
    o << r.name << ',' << csv_field(r.quantity) << ',' << csv_field(r.formula) << ',' << r.solver
      << ',' << csv_field(r.settings) << ',' << r.analytic_mm << ',' << r.measured_mm << ','
      << r.relative_error << ',' << r.final_kinetic_energy << ',' << r.max_strain << ','
      << (r.run ? "yes" : "no") << ',' << (r.stable ? "yes" : "no") << ',' << csv_field(r.message)
      << '\n';
  return o.str();
}

std::string accuracy_markdown(const AccuracyReport& report) {
  std::ostringstream o;
  o << "| scene | verts | chaos floor RMS mm (last / peak) | reference halvings | reference time "
       "error mm |\n|---|---|---|---|---|\n";
  for (const SceneAccuracy& s : report.scenes)
    o << "| " << s.name << " | " << s.vertices << " | " << fmt("%.3g", s.chaos_floor_final_rms_mm)
      << " / " << fmt("%.3g", s.chaos_floor_peak_rms_mm) << (s.chaotic ? " (chaotic)" : "") << " | "
      << s.reference_halvings << (s.reference_halvings > 0 ? " (NOT uniform)" : "") << " | "
      << fmt("%.2g", s.reference_time_error_rms_mm) << " |\n";
  o << "\n| scene | solver | settings | CPU s / sim s | short-horizon RMS mm | max mm | "
       "self-conv. mm (1x vs x"
    << report.options.refine
    << ") | mismatch mm (refined vs ref.) | long-run RMS mm | chaos floor mm | crossings max | "
       "stable |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const SceneAccuracy& s : report.scenes)
    for (const AccuracyRow& r : s.rows) {
      if (!r.run) {
        o << "| " << s.name << " | " << r.solver << " | " << r.settings
          << " | not run: " << r.message << " | | | | | | | | |\n";
        continue;
      }
      o << "| " << s.name << " | " << r.solver << " | " << r.settings << " | "
        << fmt("%.3g", r.cpu_s_per_sim_s) << " | " << fmt("%.3g", r.short_rms_mm) << " | "
        << fmt("%.3g", r.short_max_mm) << " | " << fmt("%.3g", r.self_convergence_rms_mm) << " | "
        << fmt("%.3g", r.model_mismatch_rms_mm) << " | " << fmt("%.3g", r.long_run_rms_mm)
        << (r.long_run_within_floor ? " (within floor)" : "") << " | "
        << fmt("%.3g", s.chaos_floor_final_rms_mm) << " | " << r.self_intersections << " | "
        << (r.stable ? "yes" : "no: " + r.message) << " |\n";
    }
  o << "\n| scene | solver | target short-horizon RMS mm | CPU s / sim s | how "
       "|\n|---|---|---|---|---|\n";
  for (const SceneAccuracy& s : report.scenes)
    for (const CostAtError& c : s.cost)
      o << "| " << s.name << " | " << c.solver << " | " << fmt("%g", c.target_mm) << " | "
        << fmt("%.3g", c.cpu_s_per_sim_s) << " | " << c.how << " |\n";
  bool any_chaotic = false;
  for (const SceneAccuracy& s : report.scenes) any_chaotic = any_chaotic || s.chaotic;
  if (any_chaotic) {
    o << "\n| scene | run | sag mm | p99 strain % | KE decay | penetration mm | within "
         "spread |\n|---|---|---|---|---|---|---|\n";
    for (const SceneAccuracy& s : report.scenes) {
      if (!s.chaotic) continue;
      o << "| " << s.name << " | reference ensemble (" << s.spread.members << ", min..max) | "
        << fmt("%.1f", s.spread.min.sag_mm) << ".." << fmt("%.1f", s.spread.max.sag_mm) << " | "
        << fmt("%.2f", 100 * s.spread.min.strain_p99) << ".."
        << fmt("%.2f", 100 * s.spread.max.strain_p99) << " | "
        << fmt("%.3f", s.spread.min.kinetic_decay) << ".."
        << fmt("%.3f", s.spread.max.kinetic_decay) << " | "
        << fmt("%.2f", s.spread.min.penetration_mm) << ".."
        << fmt("%.2f", s.spread.max.penetration_mm) << " | |\n";
      for (const AccuracyRow& r : s.rows) {
        if (!r.run || !r.stable) continue;
        o << "| " << s.name << " | " << r.solver << " " << r.settings << " | "
          << fmt("%.1f", r.stats.sag_mm) << " | " << fmt("%.2f", 100 * r.stats.strain_p99) << " | "
          << fmt("%.3f", r.stats.kinetic_decay) << " | " << fmt("%.2f", r.stats.penetration_mm)
          << " | " << r.stats_within << "/4 |\n";
      }
    }
  }
  if (!report.statics.empty()) {
    o << "\n| case | quantity | formula | solver | settings | analytic mm | measured mm | rel. "
         "error | final KE J |\n|---|---|---|---|---|---|---|---|---|\n";
    for (const StaticRow& r : report.statics) {
      o << "| " << r.name << " | " << r.quantity << " | " << r.formula << " | " << r.solver << " | "
        << r.settings << " | " << fmt("%.4g", r.analytic_mm) << " | ";
      if (!r.run)
        o << "not run: " << r.message << " | | |\n";
      else if (!r.stable)
        o << "unstable: " << r.message << " | | |\n";
      else
        o << fmt("%.4g", r.measured_mm) << " | " << fmt("%+.1f %%", 100 * r.relative_error) << " | "
          << fmt("%.2g", r.final_kinetic_energy) << " |\n";
    }
  }
  return o.str();
}

PlotSpec accuracy_plot(const SceneAccuracy& scene) {
  PlotSpec spec;
  spec.title = "Cost against short-horizon error: " + scene.name;
  spec.x_label = "CPU seconds per simulated second";
  spec.y_label = "short-horizon RMS error against the reference, mm";
  spec.log_x = spec.log_y = true;
  std::vector<double> all_x, all_y;
  size_t color = 0;
  for (const char* solver : {"mass-spring", "pbd", "xpbd", "newton"}) {
    PlotSeries s;
    s.label = solver;
    s.color = palette_color(color++);
    for (const auto& r : scene.rows) {
      if (r.solver != solver || !r.stable || !std::isfinite(r.short_rms_mm) ||
          !std::isfinite(r.cpu_s_per_sim_s))
        continue;
      s.x.push_back(r.cpu_s_per_sim_s);
      s.y.push_back(std::max(r.short_rms_mm, 1e-6));
      s.point_labels.push_back(r.settings);
      all_x.push_back(s.x.back());
      all_y.push_back(s.y.back());
    }
    if (!s.x.empty()) spec.series.push_back(std::move(s));
  }
  PlotSeries front;
  front.label = "Pareto front";
  front.color = "#333333";
  front.markers = false;
  front.line = true;
  front.dashed = true;
  for (size_t i : pareto_front(all_x, all_y)) {
    front.x.push_back(all_x[i]);
    front.y.push_back(all_y[i]);
  }
  if (!front.x.empty()) spec.series.push_back(std::move(front));
  // The reference's own time error: short-horizon errors below it are not resolved.
  if (!all_x.empty() && std::isfinite(scene.reference_time_error_rms_mm)) {
    const double lo = *std::min_element(all_x.begin(), all_x.end());
    const double hi = *std::max_element(all_x.begin(), all_x.end());
    PlotSeries floor;
    floor.label = "reference time error";
    floor.color = "#999999";
    floor.markers = false;
    floor.line = true;
    floor.dashed = true;
    floor.x = {lo, hi};
    floor.y = {std::max(scene.reference_time_error_rms_mm, 1e-6),
               std::max(scene.reference_time_error_rms_mm, 1e-6)};
    spec.series.push_back(std::move(floor));
  }
  return spec;
}

}  // namespace clothdb
