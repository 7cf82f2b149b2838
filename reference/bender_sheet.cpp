// Compiled twice (reference/CMakeLists.txt): BENDER_SHEET_FUNCTION names the copy, and Bender's
// Common.h makes Real float or (USE_DOUBLE) double. The loop is ours, written after Bender's
// Simulation/TimeStepController.cpp; the constraint kernels and the integrator are his.
#include "bender_sheet.hpp"

#include <PositionBasedDynamics/TimeIntegration.h>
#include <PositionBasedDynamics/XPBD.h>

#include <cmath>
#include <vector>

#include "report/cpu_time.hpp"
#include "solvers/coloring.hpp"
#include "solvers/shell_energy.hpp"

namespace clothdb {

namespace {

Vector3r to_real(const Eigen::Vector3d& v) {
  return v.cast<Real>();
}

}  // namespace

BenderSheetRun BENDER_SHEET_FUNCTION(const ClothScene& scene, int frames, int substeps) {
  const ClothModel& model = scene.model;
  const ClothMesh& mesh = model.mesh;
  const int n = model.vertex_count();
  const Eigen::Matrix3Xd& rest = mesh.rest;

  // Per-vertex data as Bender's ParticleData holds it: mass 0 marks a pinned particle.
  std::vector<Vector3r> x(static_cast<std::size_t>(n)), v(x.size()), old(x.size());
  std::vector<Real> mass(x.size()), inv_mass(x.size()), drag(x.size());
  for (int i = 0; i < n; ++i) {
    const std::size_t iu = static_cast<std::size_t>(i);
    x[iu] = to_real(scene.initial.x.col(i));
    v[iu] = to_real(scene.initial.v.col(i));
    inv_mass[iu] = static_cast<Real>(model.inv_mass[i]);
    mass[iu] = model.inv_mass[i] > 0.0 ? static_cast<Real>(model.mass[i]) : Real(0);
    // Linear air drag, force -c A v (collision.hpp's Environment::air_drag), as an acceleration.
    drag[iu] = static_cast<Real>(scene.env.air_drag * model.vertex_area[i] * model.inv_mass[i]);
  }

  // Stretch: one distance constraint per edge with our stiffness k = k_s / l0 (xpbd.cpp).
  struct Distance {
    int i, j;
    Real rest, stiffness, lambda;
  };
  std::vector<std::array<int, 2>> distance_vertices;
  std::vector<Distance> distance;
  const double et = model.material.stretch_stiffness();
  for (std::size_t e = 0; e < mesh.edges.size(); ++e) {
    const double l0 = model.edge_rest_length[e];
    const double k_s = stretch_coefficient(et, model.edge_area[e], l0);
    if (!(l0 > 0.0) || !(k_s > 0.0)) continue;
    distance.push_back({mesh.edges[e][0], mesh.edges[e][1], static_cast<Real>(l0),
                        static_cast<Real>(k_s / l0), Real(0)});
    distance_vertices.push_back(mesh.edges[e]);
  }
  // Bending: Bender's isometric bending (Bergou et al. 2006) per hinge, stiffness D.
  struct Bend {
    int p0, p1, p2, p3;  // Bender's order: wings p0, p1; shared edge p2, p3
    Matrix4r q;
    Real lambda;
  };
  std::vector<std::array<int, 4>> bend_vertices;
  std::vector<Bend> bend;
  const Real d = static_cast<Real>(model.material.bending_rigidity());
  for (const Hinge& h : mesh.hinges) {
    Bend b{h.a, h.b, h.v0, h.v1, Matrix4r::Zero(), Real(0)};
    if (!PBD::XPBD::init_IsometricBendingConstraint(
            to_real(rest.col(b.p0)), to_real(rest.col(b.p1)), to_real(rest.col(b.p2)),
            to_real(rest.col(b.p3)), b.q))
      continue;
    bend.push_back(b);
    bend_vertices.push_back({h.a, h.b, h.v0, h.v1});
  }
  // Constraint groups (Bender: SimulationModel::initConstraintGroups), here by our greedy
  // colouring; on one thread the groups only fix the order.
  const auto stretch_groups = greedy_coloring(distance_vertices);
  const auto bend_groups = greedy_coloring(bend_vertices);

  BenderSheetRun run;
  const Real h = static_cast<Real>(scene.frame_dt / substeps);
  const Vector3r gravity = to_real(scene.env.gravity);
  Eigen::Matrix3Xd frame_x(3, n);
  for (int frame = 0; frame < frames && run.finite; ++frame) {
    const double cpu_start = thread_cpu_seconds();
    for (int sub = 0; sub < substeps; ++sub) {
      for (std::size_t i = 0; i < x.size(); ++i) {
        old[i] = x[i];
        const Vector3r a = gravity - drag[i] * v[i];
        PBD::TimeIntegration::semiImplicitEuler(h, mass[i], x[i], v[i], a);
      }
      // Constraint::initConstraintBeforeProjection: the multipliers start at 0 every sub-step.
      for (Distance& c : distance) c.lambda = 0;
      for (Bend& c : bend) c.lambda = 0;
      Vector3r c0, c1, c2, c3;
      for (const auto& group : bend_groups)
        for (int k : group) {
          Bend& c = bend[static_cast<std::size_t>(k)];
          const std::size_t a = static_cast<std::size_t>(c.p0), b = static_cast<std::size_t>(c.p1),
                            e0 = static_cast<std::size_t>(c.p2),
                            e1 = static_cast<std::size_t>(c.p3);
          if (PBD::XPBD::solve_IsometricBendingConstraint(x[a], inv_mass[a], x[b], inv_mass[b],
                                                          x[e0], inv_mass[e0], x[e1], inv_mass[e1],
                                                          c.q, d, h, c.lambda, c0, c1, c2, c3)) {
            x[a] += c0;
            x[b] += c1;
            x[e0] += c2;
            x[e1] += c3;
          }
        }
      for (const auto& group : stretch_groups)
        for (int k : group) {
          Distance& c = distance[static_cast<std::size_t>(k)];
          const std::size_t i = static_cast<std::size_t>(c.i), j = static_cast<std::size_t>(c.j);
          if (PBD::XPBD::solve_DistanceConstraint(x[i], inv_mass[i], x[j], inv_mass[j], c.rest,
                                                  c.stiffness, h, c.lambda, c0, c1)) {
            x[i] += c0;
            x[j] += c1;
          }
        }
      for (std::size_t i = 0; i < x.size(); ++i)
        PBD::TimeIntegration::velocityUpdateFirstOrder(h, mass[i], x[i], old[i], v[i]);
    }
    run.cpu_seconds += thread_cpu_seconds() - cpu_start;
    for (int i = 0; i < n; ++i) {
      frame_x.col(i) = x[static_cast<std::size_t>(i)].template cast<double>();
      if (!frame_x.col(i).allFinite()) run.finite = false;
    }
    run.frames = frame + 1;
    if (!run.finite) break;
    run.last_strain = max_edge_strain(model, frame_x);
    run.max_strain = std::max(run.max_strain, run.last_strain);
  }
  return run;
}

}  // namespace clothdb
