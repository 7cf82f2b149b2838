// The hard cases of the core issue, built from procedural sheets. Every scene is small by default
// (a few hundred vertices) so tests run fast; benchmarks pass a larger resolution.
#include "hard_cases/hard_cases.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <stdexcept>

#include "cloth/self_intersection.hpp"
#include "report/cpu_time.hpp"

namespace clothdb {

namespace {

constexpr double kPi = 3.14159265358979323846;

// What every sheet scene shares: air drag at 2/s of the fabric's mass (c / density), so the
// swinging modes that stiffness-proportional damping barely touches settle within the scene; the
// collision margin at the fabric's thickness; and a start at rest.
void finish_scene(ClothScene& scene, const Material& m) {
  scene.env.air_drag = 2.0 * m.density;
  scene.env.collision_margin = m.thickness;
  scene.initial = rest_state(scene.model);
}

// A 1 m x 1 m sheet hanging in the XY plane, top edge at y = 1, pinned at its two top corners.
ClothScene hanging_sheet(const std::string& name, int resolution, const Material& material) {
  const int n = resolution > 0 ? resolution : 21;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  std::vector<int> pins{grid_index(mesh, 0, n - 1), grid_index(mesh, n - 1, n - 1)};
  ClothScene scene;
  scene.name = name;
  scene.model = make_model(std::move(mesh), material, pins);
  finish_scene(scene, material);
  scene.frames = 90;
  return scene;
}

ClothScene sphere_drape(int resolution) {
  const int n = resolution > 0 ? resolution : 21;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  // Lay the sheet horizontally (XY -> XZ), centred over a sphere of radius 0.3 at the origin.
  Eigen::Matrix3d lay;
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(-0.5, 0.35, 0.5));
  ClothScene scene;
  scene.name = "sphere-drape";
  scene.description = "free sheet falling onto a sphere: contact, friction, penetration";
  Material m;
  scene.model = make_model(std::move(mesh), m, {});
  SphereCollider sphere;
  sphere.radius = 0.3;
  scene.env.spheres.push_back(sphere);
  finish_scene(scene, m);
  scene.frames = 60;
  return scene;
}

ClothScene swung_sheet(int resolution) {
  const int n = resolution > 0 ? resolution : 21;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  std::vector<int> pins;
  for (int c = 0; c < n; ++c) pins.push_back(grid_index(mesh, c, n - 1));
  ClothScene scene;
  scene.name = "swung-sheet";
  scene.description = "sheet pinned along its top edge, swung sideways at up to 5 m/s";
  Material m;
  scene.model = make_model(std::move(mesh), m, pins);
  finish_scene(scene, m);
  scene.frames = 60;
  const Eigen::Matrix3Xd pin_rest = kinematic_positions(scene.model, scene.model.mesh.rest);
  // x(t) = A sin(w t) along z (out of the sheet's plane), peak speed A w = 5 m/s at 2 Hz.
  const double w = 2.0 * kPi * 2.0, amplitude = 5.0 / w;
  scene.kinematic_path = [pin_rest, w, amplitude](double t) {
    Eigen::Matrix3Xd p = pin_rest;
    p.row(2).array() += amplitude * std::sin(w * t);
    return p;
  };
  return scene;
}

ClothScene slivers(int resolution) {
  const int n = resolution > 0 ? resolution : 21;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  // Collapse one row onto the row below (1e-5 of the spacing apart) and squeeze one column onto
  // its neighbour: a band of near-zero-area triangles and a band of slivers.
  const double dy = 1.0 / (n - 1);
  for (int c = 0; c < n; ++c) {
    mesh.rest(1, grid_index(mesh, c, n / 2)) =
        mesh.rest(1, grid_index(mesh, c, n / 2 - 1)) + 1e-5 * dy;
  }
  for (int r = 0; r < n; ++r) {
    mesh.rest(0, grid_index(mesh, n / 3, r)) =
        mesh.rest(0, grid_index(mesh, n / 3 - 1, r)) + 0.02 * dy;
  }
  std::vector<int> pins{grid_index(mesh, 0, n - 1), grid_index(mesh, n - 1, n - 1)};
  ClothScene scene;
  scene.name = "slivers";
  scene.description = "hanging sheet with near-zero-area and sliver triangles";
  Material m;
  scene.model = make_model(std::move(mesh), m, pins);
  finish_scene(scene, m);
  scene.frames = 60;
  return scene;
}

ClothScene stretched_start(int resolution) {
  const int n = resolution > 0 ? resolution : 21;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  const int top_middle = grid_index(mesh, n / 2, n - 1);
  ClothScene scene;
  scene.name = "stretched-start";
  scene.description = "sheet hung from its top middle, starting stretched to 150 %";
  Material m;
  scene.model = make_model(std::move(mesh), m, {top_middle});
  finish_scene(scene, m);
  const Vec3 anchor = scene.model.mesh.rest.col(top_middle);
  scene.initial.x = ((scene.model.mesh.rest.colwise() - anchor) * 1.5).colwise() + anchor;
  scene.frames = 60;
  return scene;
}

ClothScene cantilever(int resolution) {
  // A plate 0.2 m long (x) and 0.04 m wide (z), clamped along x = 0 by two columns of nodes so the
  // clamp carries a moment, loaded by its own weight. Poisson 0 so the strip's rigidity per unit
  // width is exactly D = E t^3 / 12. Under full gravity the linear Euler-Bernoulli deflection
  // q L^4 / (8 D) would be 0.35 m, more than L: this is a large-deflection hard case, not the
  // small-load check. For that, the Newton test uses seed 004's equilateral plate: on this quad
  // grid the hinge model is about 20 % too soft even at small loads (docs/notebook/BENCHMARKS.md).
  const int columns = resolution > 0 ? resolution : 21;
  const int rows = std::max(3, columns / 5 + 1);
  ClothMesh mesh = make_quad_grid(columns, rows, 0.2, 0.04);
  Eigen::Matrix3d lay;
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(0, 0, 0.02));
  std::vector<int> clamp;
  for (int r = 0; r < rows; ++r) {
    clamp.push_back(grid_index(mesh, 0, r));
    clamp.push_back(grid_index(mesh, 1, r));
  }
  Material m;
  m.youngs_modulus = 1.0e7;
  m.thickness = 1.0e-3;
  m.poisson = 0.0;
  m.bending_stiffness = -1.0;  // plate value E t^3 / 12
  m.damping = 0.01;
  ClothScene scene;
  scene.name = "cantilever";
  scene.description = "plate clamped along one edge, bending under its own weight";
  scene.model = make_model(std::move(mesh), m, clamp);
  scene.env.air_drag = 20.0 * m.density;
  scene.env.collision_margin = m.thickness;
  scene.initial = rest_state(scene.model);
  scene.frames = 120;
  return scene;
}

// Self-collision (docs/notebook/self_collision.md): a 1 m x 0.5 m sheet laid flat and held along a
// line across it, 40 cm from one end, dropped with soft bending: both sides fall and fold down onto
// each other, the short side over the long one, and swing. Without self-collision they pass through
// each other; with it they meet and hang side by side.
ClothScene folding_sheet(int resolution) {
  const int n = resolution > 0 ? resolution : 21;
  const int rows = std::max(2, (n + 1) / 2);
  ClothMesh mesh = make_quad_grid(n, rows, 1.0, 0.5);
  // (x, y, 0) -> (x, 0, -y): flat at height 0.6, the held line along z at x = 0.
  Eigen::Matrix3d lay;
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(-0.4, 0.6, 0.25));
  // The grid column nearest x = 0 (40 % of the width) is held.
  const int held = static_cast<int>(std::lround(0.4 * (n - 1)));
  std::vector<int> pins;
  for (int r = 0; r < rows; ++r) pins.push_back(grid_index(mesh, held, r));
  Material m;
  m.bending_stiffness = 1e-6;
  ClothScene scene;
  scene.name = "folding-sheet";
  scene.description = "sheet held along a line 40/60 across it, dropped: its sides fold together";
  scene.model = make_model(std::move(mesh), m, pins);
  finish_scene(scene, m);
  scene.env.air_drag = 0.5 * m.density;  // little drag: the sides swing through, not creep in
  scene.frames = 45;
  scene.self_collision_mm = 5.0;
  return scene;
}

// Self-collision (docs/notebook/self_collision.md): a tube skirt (radius 0.16 m, 0.5 m long) round
// a body capsule of radius 0.1 m, held at its waist and its hem. The hem ring turns once about the
// body and rises 0.3 m in 1.5 s, then holds: the cloth between is wrung round the body in folds
// that press on each other (the rise leaves the slack to do so without stretching).
ClothScene twisted_skirt(int resolution) {
  const int around = resolution > 0 ? resolution : 24;
  const int rows = std::max(3, around * 5 / 8);
  const double radius = 0.16, length = 0.5;
  ClothMesh grid = make_quad_grid(around + 1, rows, 1.0, 1.0);
  Eigen::Matrix3Xd tube(3, grid.rest.cols());
  for (Eigen::Index i = 0; i < grid.rest.cols(); ++i) {
    const double angle = 2.0 * kPi * grid.rest(0, i);  // x in [0, 1] once around
    tube.col(i) = Vec3(radius * std::cos(angle), 1.0 + length * (grid.rest(1, i) - 1.0),
                       -radius * std::sin(angle));
  }
  // The last column lies on the first: weld it shut.
  ClothMesh mesh = weld_vertices(tube, grid.triangles, 1e-3 * radius);
  std::vector<int> held;
  int waist_count = 0;
  for (int i = 0; i < mesh.vertex_count(); ++i)
    if (mesh.rest(1, i) > 1.0 - 1e-9) held.push_back(i), ++waist_count;
  for (int i = 0; i < mesh.vertex_count(); ++i)
    if (mesh.rest(1, i) < 1.0 - length + 1e-9) held.push_back(i);
  Material m;
  m.bending_stiffness = 2e-6;
  ClothScene scene;
  scene.name = "twisted-skirt";
  scene.description = "tube skirt round a body, hem turned once and raised 0.3 m: wrung in folds";
  scene.model = make_model(std::move(mesh), m, held);
  CapsuleCollider body;
  body.a = body.a_start = Vec3(0, 0.2, 0);
  body.b = body.b_start = Vec3(0, 1.3, 0);
  body.radius = 0.1;
  scene.env.capsules.push_back(body);
  finish_scene(scene, m);
  scene.frames = 60;
  scene.self_collision_mm = 5.0;
  const Eigen::Matrix3Xd rest = kinematic_positions(scene.model, scene.model.mesh.rest);
  scene.kinematic_path = [rest, waist_count](double t) {
    const double s = std::min(t / 1.5, 1.0);
    const Eigen::Matrix3d r = Eigen::AngleAxisd(2.0 * kPi * s, Vec3::UnitY()).toRotationMatrix();
    Eigen::Matrix3Xd p = rest;
    for (Eigen::Index k = waist_count; k < p.cols(); ++k)
      p.col(k) = r * rest.col(k) + Vec3(0, 0.3 * s, 0);
    return p;
  };
  return scene;
}

}  // namespace

std::vector<std::string> hard_case_names() {
  return {"hanging-sheet", "sphere-drape",    "swung-sheet",        "stiff-large-step",
          "slivers",       "stretched-start", "light-stiff-fabric", "cantilever",
          "folding-sheet", "twisted-skirt"};
}

ClothScene make_hard_case(const std::string& name, int resolution) {
  if (name == "hanging-sheet") {
    ClothScene s = hanging_sheet(name, resolution, Material{});
    s.description = "1 m sheet hanging from two corners";
    return s;
  }
  if (name == "stiff-large-step") {
    Material m;
    m.youngs_modulus *= 10.0;
    ClothScene s = hanging_sheet(name, resolution, m);
    s.description = "hanging sheet with E x10, meant for one step per frame (1/30 s, no substeps)";
    return s;
  }
  if (name == "light-stiff-fabric") {
    Material m;
    m.density = 0.15;
    m.youngs_modulus = 4.0e8;  // E t = 2e5 N/m: a stiff, light fabric (high stiffness/mass ratio)
    ClothScene s = hanging_sheet(name, resolution, m);
    s.description = "light fabric (0.15 kg/m^2) with high stiffness (E t = 2e5 N/m)";
    return s;
  }
  if (name == "sphere-drape") return sphere_drape(resolution);
  if (name == "swung-sheet") return swung_sheet(resolution);
  if (name == "slivers") return slivers(resolution);
  if (name == "stretched-start") return stretched_start(resolution);
  if (name == "cantilever") return cantilever(resolution);
  if (name == "folding-sheet") return folding_sheet(resolution);
  if (name == "twisted-skirt") return twisted_skirt(resolution);
  std::string known;
  for (const auto& n : hard_case_names()) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown scene '" + name + "' (known: " + known + ")");
}

ClothScene make_large_sheet(int vertices) {
  const int side =
      std::max(2, static_cast<int>(std::lround(std::sqrt(static_cast<double>(vertices)))));
  ClothScene s = hanging_sheet("large-sheet", side, Material{});
  s.description = "hanging sheet of " + std::to_string(side * side) + " vertices";
  return s;
}

ClothScene make_seed004_grid() {
  ClothMesh mesh = make_equilateral_sheet(23, 23, 1.0 / 22.0);
  std::vector<int> pins{grid_index(mesh, 0, 22), grid_index(mesh, 22, 22)};
  Material m;
  ClothScene scene;
  scene.name = "seed004-529";
  scene.description = "seed 004's 529-node equilateral grid hanging from two corners";
  scene.model = make_model(std::move(mesh), m, pins);
  finish_scene(scene, m);
  scene.frames = 60;
  return scene;
}

ClothScene make_cantilever_plate(int rows) {
  if (rows < 3) throw std::invalid_argument("cantilever plate: at least 3 rows");
  const double width = 0.15;
  const double h = kCantileverLength / (rows - 1);
  const double edge = h / (std::sqrt(3.0) / 2);
  const int columns = static_cast<int>(std::lround(width / edge)) + 1;
  ClothMesh mesh = make_equilateral_sheet(columns, rows, edge);
  Eigen::Matrix3d lay;  // sheet rows run along x (the length), columns along z, normal along y
  lay << 0, 1, 0, 0, 0, 1, 1, 0, 0;
  transform_mesh(mesh, lay, Vec3(0, 0, 0));
  std::vector<int> clamp;
  for (int c = 0; c < columns; ++c) {
    clamp.push_back(grid_index(mesh, c, 0));
    clamp.push_back(grid_index(mesh, c, 1));
  }
  Material m;
  m.youngs_modulus = 1.0e7;
  m.thickness = 1.0e-3;
  m.poisson = 0.0;
  m.bending_stiffness = -1.0;  // plate value D = E t^3 / 12
  m.damping = 0.01;
  ClothScene scene;
  scene.name = "cantilever-plate";
  scene.description = "equilateral plate 0.1 m long clamped by two rows, 1 % gravity";
  scene.model = make_model(std::move(mesh), m, clamp);
  scene.env.gravity *= 0.01;
  scene.env.air_drag = 20.0 * m.density;
  scene.env.collision_margin = m.thickness;
  scene.initial = rest_state(scene.model);
  scene.frames = 150;
  return scene;
}

ClothScene make_seed004_fall(int nodes_per_side) {
  if (nodes_per_side < 2) throw std::invalid_argument("seed004-fall: at least 2 nodes per side");
  const int n = nodes_per_side;
  ClothMesh mesh = make_equilateral_sheet(n, n, 1.0 / (n - 1));
  // Lay the sheet flat: (x, y, 0) -> (x, 0, -y), rows running along -z from the free edge to the
  // pinned one; gravity (-y) then pulls it down and it swings through under its pinned corners.
  Eigen::Matrix3d lay;
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(0, 0, 0));
  std::vector<int> pins{grid_index(mesh, 0, n - 1), grid_index(mesh, n - 1, n - 1)};
  Material m;
  ClothScene scene;
  scene.name = "seed004-fall";
  scene.description = "seed 004's " + std::to_string(n * n) +
                      "-node grid laid flat, pinned at two corners, falling";
  scene.model = make_model(std::move(mesh), m, pins);
  finish_scene(scene, m);
  scene.frames = 60;
  return scene;
}

RunResult run_scene(const ClothScene& scene, Solver& solver, int frames, bool keep_frames) {
  if (frames <= 0) frames = scene.frames;
  RunResult result;
  ClothState state = scene.initial;
  Environment env = scene.env;
  StepInputs inputs;
  inputs.env = &env;
  const Vec3 g = env.gravity;
  const double energy0 =
      kinetic_energy(scene.model, state.v) + gravity_potential(scene.model, state.x, g);
  auto record = [&](const StepReport* report) {
    FrameMetrics m;
    m.max_strain = max_edge_strain(scene.model, state.x);
    m.max_penetration = max_penetration(state.x, scene.model.inv_mass, env);
    m.mean_penetration = mean_penetration(state.x, scene.model.inv_mass, env);
    m.kinetic_energy = kinetic_energy(scene.model, state.v);
    m.self_intersections = count_self_intersections(scene.model.mesh, state.x);
    m.total_energy = m.kinetic_energy + gravity_potential(scene.model, state.x, g) - energy0;
    if (report) {
      m.step_halvings = report->step_halvings;
      m.iterations = report->iterations;
      m.factorizations = report->factorizations;
      m.strain_limit_passes = report->strain_limit_passes;
      m.strain_limit_capped = report->strain_limit_capped;
      m.stable = report->stable;
    }
    result.metrics.push_back(m);
    if (keep_frames) result.frames.push_back(state.x);
  };
  record(nullptr);
  for (int f = 1; f <= frames; ++f) {
    const double t0 = (f - 1) * scene.frame_dt, t1 = f * scene.frame_dt;
    if (scene.collider_path) scene.collider_path(t0, t1, env);
    if (scene.kinematic_path) inputs.kinematic_targets = scene.kinematic_path(t1);
    const auto start = std::chrono::steady_clock::now();
    const double cpu_start = process_cpu_seconds();
    const StepReport report = solver.step(state, scene.frame_dt, inputs);
    result.cpu_seconds += process_cpu_seconds() - cpu_start;
    result.seconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (!report.stable) {
      result.stable = false;
      result.message = "frame " + std::to_string(f) + ": " + report.message;
      break;
    }
    record(&report);
  }
  return result;
}

}  // namespace clothdb
