// The implicit Newton solver on discrete elastic plates / shells energies: energy derivatives
// against finite differences, the material mapping, convergence on a hanging sheet, a cantilever
// against Euler-Bernoulli, agreement of the three linear solvers, and honest degeneracy reports.
#include <gtest/gtest.h>
#include <omp.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <map>
#include <random>
#include <string>
#include <vector>

#include "cloth/mesh.hpp"
#include "cloth/model.hpp"
#include "hard_cases/hard_cases.hpp"
#include "solvers/shell_energy.hpp"
#include "solvers/solver.hpp"

using namespace clothdb;

namespace {

constexpr double kPi = 3.14159265358979323846;

using Vec12 = Eigen::Matrix<double, 12, 1>;
using Mat12 = Eigen::Matrix<double, 12, 12>;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

double rel_error(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).norm() / std::max(b.norm(), 1e-300);
}

// A random, well-conditioned hinge: unit-ish shared edge along x, wings at heights in [0.5, 1.5]
// folded by up to +-2 rad, everything rotated and translated at random.
Vec12 random_hinge(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double len = 1.0 + 0.3 * u(rng);
  const double h2 = 1.0 + 0.5 * u(rng), h3 = 1.0 + 0.5 * u(rng);
  const double fold2 = 1.0 * u(rng), fold3 = 1.0 * u(rng);
  Vec12 x;
  x.segment<3>(0) = Vec3(0, 0, 0);
  x.segment<3>(3) = Vec3(len, 0, 0);
  x.segment<3>(6) = Vec3(0.5 * len + 0.4 * u(rng), h2 * std::cos(fold2), h2 * std::sin(fold2));
  x.segment<3>(9) = Vec3(0.5 * len + 0.4 * u(rng), -h3 * std::cos(fold3), h3 * std::sin(fold3));
  const Eigen::Matrix3d r =
      Eigen::Quaterniond(Eigen::Vector4d(u(rng), u(rng), u(rng), u(rng)).normalized())
          .toRotationMatrix();
  const Vec3 t(u(rng), u(rng), u(rng));
  for (int k = 0; k < 4; ++k) x.segment<3>(3 * k) = r * x.segment<3>(3 * k) + t;
  return x;
}

Vec12 bend_grad(const Vec12& x, double theta0, double kb) {
  Vec12 g;
  bend_gradient(&x[0], &x[3], &x[6], &x[9], theta0, kb, g.data());
  return g;
}

Vec6 stretch_grad(const Vec6& x, double l0, double ks) {
  Vec6 g;
  stretch_gradient(&x[0], &x[3], l0, ks, g.data());
  return g;
}

}  // namespace

// ---- Energies
// ------------------------------------------------------------------------------------

TEST(ShellEnergy, StretchGradientMatchesFiniteDifferences) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 50; ++trial) {
    Vec6 x = Vec6::NullaryExpr([&](Eigen::Index) { return u(rng); });
    const double l = (x.segment<3>(3) - x.segment<3>(0)).norm();
    const double l0 = l * (1.0 + 0.4 * u(rng));  // compressed and stretched
    const double ks = 10.0 + 5.0 * u(rng);
    const Vec6 g = stretch_grad(x, l0, ks);
    Vec6 fd;
    const double step = 1e-6;
    for (int k = 0; k < 6; ++k) {
      Vec6 p = x, m = x;
      p[k] += step;
      m[k] -= step;
      fd[k] = (stretch_energy(&p[0], &p[3], l0, ks) - stretch_energy(&m[0], &m[3], l0, ks)) /
              (2 * step);
    }
    EXPECT_LT(rel_error(g, fd), 1e-6) << "trial " << trial;
  }
}

TEST(ShellEnergy, StretchHessianMatchesFiniteDifferences) {
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 50; ++trial) {
    Vec6 x = Vec6::NullaryExpr([&](Eigen::Index) { return u(rng); });
    const double l = (x.segment<3>(3) - x.segment<3>(0)).norm();
    const double l0 = l * (1.0 + 0.4 * u(rng));
    const double ks = 10.0 + 5.0 * u(rng);
    Vec6 g;
    Mat6 h;
    stretch_hessian(&x[0], &x[3], l0, ks, g.data(), h.data(), false);
    Mat6 fd;
    const double step = 1e-6;
    for (int k = 0; k < 6; ++k) {
      Vec6 p = x, m = x;
      p[k] += step;
      m[k] -= step;
      fd.col(k) = (stretch_grad(p, l0, ks) - stretch_grad(m, l0, ks)) / (2 * step);
    }
    EXPECT_LT(rel_error(h, fd), 1e-6) << "trial " << trial;
  }
}

TEST(ShellEnergy, ProjectedStretchHessianIsPsdAndExactWhenStretched) {
  const Vec6 x = (Vec6() << 0, 0, 0, 0.3, 0.4, 0.0).finished();  // l = 0.5
  Vec6 g;
  Mat6 exact, projected;
  // Compressed (l0 = 0.8): the exact Hessian has negative transverse eigenvalues.
  stretch_hessian(&x[0], &x[3], 0.8, 7.0, g.data(), exact.data(), false);
  stretch_hessian(&x[0], &x[3], 0.8, 7.0, g.data(), projected.data(), true);
  EXPECT_LT(Eigen::SelfAdjointEigenSolver<Mat6>(exact).eigenvalues().minCoeff(), -1.0);
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Mat6>(projected).eigenvalues().minCoeff(), -1e-12);
  // Along the edge the projected Hessian keeps the axial stiffness 2 k_s / l0.
  EXPECT_NEAR(Eigen::SelfAdjointEigenSolver<Mat6>(projected).eigenvalues().maxCoeff(),
              2 * 7.0 / 0.8, 1e-9);
  // Stretched (l0 = 0.4): nothing to project.
  stretch_hessian(&x[0], &x[3], 0.4, 7.0, g.data(), exact.data(), false);
  stretch_hessian(&x[0], &x[3], 0.4, 7.0, g.data(), projected.data(), true);
  EXPECT_LT((exact - projected).norm(), 1e-12);
}

TEST(ShellEnergy, HingeAngleIsTheSignedFoldAngle) {
  // Flat hinge in the XY plane, then the wing x2 rotated about the shared edge (the x axis).
  for (double fold : {-2.5, -1.0, -0.1, 0.0, 0.3, 1.2, 2.9}) {
    const Vec3 x0(0, 0, 0), x1(1, 0, 0), x3(0.5, -1, 0);
    const Vec3 x2(0.4, std::cos(fold), std::sin(fold));
    const double theta = hinge_angle(x0.data(), x1.data(), x2.data(), x3.data());
    // Lifting x2 along its normal (+z at fold 0) decreases theta.
    EXPECT_NEAR(theta, -fold, 1e-12) << "fold " << fold;
  }
}

TEST(ShellEnergy, BendGradientMatchesFiniteDifferences) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 100; ++trial) {
    const Vec12 x = random_hinge(rng);
    const double theta0 = 0.5 * u(rng), kb = 2.0 + u(rng);
    const Vec12 g = bend_grad(x, theta0, kb);
    Vec12 fd;
    const double step = 1e-6;
    for (int k = 0; k < 12; ++k) {
      Vec12 p = x, m = x;
      p[k] += step;
      m[k] -= step;
      fd[k] = (bend_energy(&p[0], &p[3], &p[6], &p[9], theta0, kb) -
               bend_energy(&m[0], &m[3], &m[6], &m[9], theta0, kb)) /
              (2 * step);
    }
    EXPECT_LT(rel_error(g, fd), 1e-6) << "trial " << trial;
  }
}

TEST(ShellEnergy, BendHessianMatchesFiniteDifferences) {
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 100; ++trial) {
    const Vec12 x = random_hinge(rng);
    const double theta0 = 0.5 * u(rng), kb = 2.0 + u(rng);
    Vec12 g;
    Mat12 h;
    bend_hessian(&x[0], &x[3], &x[6], &x[9], theta0, kb, g.data(), h.data(), false);
    EXPECT_LT(rel_error(g, bend_grad(x, theta0, kb)), 1e-14);
    Mat12 fd;
    const double step = 1e-6;
    for (int k = 0; k < 12; ++k) {
      Vec12 p = x, m = x;
      p[k] += step;
      m[k] -= step;
      fd.col(k) = (bend_grad(p, theta0, kb) - bend_grad(m, theta0, kb)) / (2 * step);
    }
    EXPECT_LT(rel_error(h, fd), 1e-6) << "trial " << trial;
  }
}

TEST(ShellEnergy, ProjectedBendHessianIsPsdAndRigidMotionsAreFree) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 20; ++trial) {
    const Vec12 x = random_hinge(rng);
    Vec12 g;
    Mat12 exact, projected;
    bend_hessian(&x[0], &x[3], &x[6], &x[9], 0.7, 1.0, g.data(), exact.data(), false);
    bend_hessian(&x[0], &x[3], &x[6], &x[9], 0.7, 1.0, g.data(), projected.data(), true);
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<Mat12>(projected).eigenvalues().minCoeff(), -1e-10);
    // Translations and infinitesimal rotations are in the null space of the exact Hessian and
    // orthogonal to the gradient.
    for (int axis = 0; axis < 3; ++axis) {
      Vec12 t = Vec12::Zero(), w = Vec12::Zero();
      Vec3 dir = Vec3::Zero();
      dir[axis] = 1.0;
      for (int k = 0; k < 4; ++k) {
        t.segment<3>(3 * k) = dir;
        w.segment<3>(3 * k) = dir.cross(Vec3(x.segment<3>(3 * k)));
      }
      EXPECT_NEAR(g.dot(t), 0.0, 1e-10);
      EXPECT_NEAR(g.dot(w), 0.0, 1e-10);
      EXPECT_LT((exact * t).norm(), 1e-9 * exact.norm());
    }
  }
}

TEST(ShellEnergy, DegenerateHingeGivesZeroNotNaN) {
  // Wing x2 on the shared edge's line: zero-area triangle.
  const Vec3 x0(0, 0, 0), x1(1, 0, 0), x2(0.5, 0, 0), x3(0.5, -1, 0.2);
  Vec12 g;
  Mat12 h;
  const double e =
      bend_hessian(x0.data(), x1.data(), x2.data(), x3.data(), 0.0, 1.0, g.data(), h.data(), false);
  EXPECT_EQ(e, 0.0);
  EXPECT_TRUE(g.allFinite());
  EXPECT_TRUE(h.allFinite());
}

TEST(ShellEnergy, StretchMappingMatchesTheTriangularLattice) {
  // An interior edge of an equilateral mesh: k_s / l0 = sqrt(3)/2 Y, the spring constant of a
  // triangular lattice whose 2D Young's modulus is Y.
  const double y = 5e4, l0 = 0.05;
  const double area = 2 * std::sqrt(3.0) / 4 * l0 * l0;
  EXPECT_NEAR(stretch_coefficient(y, area, l0) / l0, std::sqrt(3.0) / 2 * y, 1e-9 * y);
}

TEST(ShellEnergy, CylinderBendingEnergyMatchesThePlate) {
  // A quad grid bent about a grid axis into a cylinder of curvature kappa stores D/2 kappa^2 per
  // unit area (exact for the right-triangle grid), and an equilateral sheet within a few percent
  // (its hinges are not aligned with the bending direction).
  const double d = 2e-3, kappa = 0.5;
  auto bent_energy = [&](const ClothMesh& mesh) {
    Material m;
    m.bending_stiffness = d;
    const ClothModel model = make_model(mesh, m, {});
    // Rest: flat; deformed: z = kappa x^2 / 2 mapped isometrically onto the cylinder.
    Eigen::Matrix3Xd x = mesh.rest;
    for (Eigen::Index i = 0; i < x.cols(); ++i) {
      const double s = mesh.rest(0, i);
      x(0, i) = std::sin(kappa * s) / kappa;
      x(2, i) = (1 - std::cos(kappa * s)) / kappa;
    }
    double area = 0.0;
    for (const auto& t : mesh.triangles) area += triangle_area(mesh.rest, t);
    double energy = 0.0;
    for (const auto& h : mesh.hinges) {
      double a = 0.0;
      for (const auto& t : mesh.triangles) {
        int shared = 0;
        for (int v : t) shared += (v == h.v0 || v == h.v1);
        if (shared == 2) a += triangle_area(mesh.rest, t);
      }
      const double le = (mesh.rest.col(h.v1) - mesh.rest.col(h.v0)).norm();
      energy +=
          bend_energy(x.col(h.v0).data(), x.col(h.v1).data(), x.col(h.a).data(), x.col(h.b).data(),
                      0.0, bend_coefficient(model.material.bending_rigidity(), le, a));
    }
    // Hinges on the boundary lines are missing: compare per unit area of the interior strip the
    // hinges cover, which is the whole sheet for the cells between the first and last column.
    return energy / area;
  };
  const double expected = 0.5 * d * kappa * kappa;
  const double quad = bent_energy(make_quad_grid(41, 11, 1.0, 0.25));
  EXPECT_NEAR(quad / expected, 1.0, 0.03);
  const double equilateral = bent_energy(make_equilateral_sheet(41, 15, 0.025));
  EXPECT_NEAR(equilateral / expected, 1.0, 0.1);
}

// ---- The solver ---------------------------------------------------------------------------------

namespace {

// The force-residual loop most tests here check (every step ends below the tolerance, or fails
// and halves): without the stop on the update and without keeping a non-converged descent
// iterate, which StopOnTheUpdateReachesTheTightEndState tests.
SolverSettings newton_settings(LinearSolverKind linear = LinearSolverKind::SimplicialLDLT) {
  SolverSettings s;
  s.linear_solver = linear;
  s.newton_velocity_tolerance = 0.0;
  s.newton_accept_decrease = false;
  return s;
}

double tolerance_for(const ClothModel& model, const SolverSettings& s, const Vec3& g) {
  double m = 0;
  for (int i = 0; i < model.vertex_count(); ++i)
    if (model.inv_mass[i] > 0) m = std::max(m, model.mass[i]);
  return s.newton_tolerance * m * g.norm();
}

}  // namespace

TEST(NewtonSolver, DescribeNamesSolverAndSettings) {
  const ClothScene scene = make_hard_case("hanging-sheet", 5);
  EXPECT_EQ(make_newton_solver(scene.model, newton_settings())->describe(),
            "newton ldlt tol=1e-6 substeps=1");
  SolverSettings s = newton_settings(LinearSolverKind::ConjugateGradient);
  s.substeps = 4;
  EXPECT_EQ(make_newton_solver(scene.model, s)->describe(), "newton pcg tol=1e-6 substeps=4");
}

TEST(NewtonSolver, HangingSheetConvergesEveryStepWithSmallStrain) {
  // The shared hanging-sheet scene: a vertical sheet pinned at its two top corners, starting
  // unstretched, so the first steps must iterate until the membrane carries the weight.
  ClothScene scene = make_hard_case("hanging-sheet");
  const SolverSettings s = newton_settings();
  auto solver = make_newton_solver(scene.model, s);
  ClothState state = scene.initial;
  StepInputs in;
  in.env = &scene.env;
  const double tol = tolerance_for(scene.model, s, scene.env.gravity);
  double max_strain = 0;
  for (int f = 0; f < 45; ++f) {
    const StepReport r = solver->step(state, scene.frame_dt, in);
    ASSERT_TRUE(r.stable) << "frame " << f << ": " << r.message;
    EXPECT_EQ(r.step_halvings, 0) << "frame " << f << ": " << r.message;
    EXPECT_LT(r.residual, tol) << "frame " << f;
    EXPECT_LE(r.iterations, s.newton_max_iterations);
    if (f == 0) {
      EXPECT_GE(r.iterations, 1);
    }
    max_strain = std::max(max_strain, max_edge_strain(scene.model, state.x));
  }
  EXPECT_LT(max_strain, 0.01);
  // The membrane does carry the weight: the bottom edge has sagged by a measurable strain.
  EXPECT_GT(max_strain, 1e-5);
  EXPECT_TRUE(state_is_sane(state));
}

namespace {

// Seed 004's equilateral grid, n x n, laid horizontally and pinned at the two corners of one edge.
ClothModel make_falling_equilateral_sheet(int n) {
  ClothMesh mesh = make_equilateral_sheet(n, n, 1.0 / (n - 1));
  Eigen::Matrix3d lay;
  lay << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  transform_mesh(mesh, lay, Vec3(0, 1, 0));
  return make_model(mesh, Material{}, {grid_index(mesh, 0, 0), grid_index(mesh, n - 1, 0)});
}

}  // namespace

TEST(NewtonSolver, FallingEquilateralSheetConvergesEveryStep) {
  // Seed 004's equilateral grid laid horizontally and pinned at the two corners of one edge: it
  // falls, folds and swings, compressing many edges (the projected-Hessian path).
  const int n = 13;
  const ClothModel model = make_falling_equilateral_sheet(n);
  const ClothMesh& mesh = model.mesh;
  Environment env;
  env.air_drag = 2.0 * model.material.density;
  const SolverSettings s = newton_settings();
  auto solver = make_newton_solver(model, s);
  ClothState state = rest_state(model);
  StepInputs in;
  in.env = &env;
  const double tol = tolerance_for(model, s, env.gravity);
  double max_strain = 0;
  for (int f = 0; f < 30; ++f) {
    const StepReport r = solver->step(state, 1.0 / 30.0, in);
    ASSERT_TRUE(r.stable) << "frame " << f << ": " << r.message;
    EXPECT_LT(r.residual, tol) << "frame " << f;
    EXPECT_GE(r.iterations, 1);
    if (r.step_halvings > 0) {
      EXPECT_NE(r.message.find("halved"), std::string::npos) << r.message;
    }
    max_strain = std::max(max_strain, max_edge_strain(model, state.x));
  }
  EXPECT_LT(max_strain, 0.01);
  // The far corner fell well below the pinned edge.
  const int far = grid_index(mesh, 0, n - 1);
  EXPECT_LT(state.x(1, far), 1.0 - 0.3);
  EXPECT_TRUE(state_is_sane(state));
}

TEST(NewtonSolver, StaticSagMatchesTheMembraneStiffness) {
  // A horizontal strip hanging under its weight from both short ends is a catenary-free check of
  // the stretching stiffness alone: a vertical strip pinned along its top edge stretches under
  // its own weight by strain(y) = rho g (y_top - y) / Y, so its bottom moves down by
  // rho g H^2 / (2 Y) (gravity load carried by the membrane stiffness Y = E t per unit width).
  const double width = 0.2, height = 1.0;
  ClothMesh mesh = make_quad_grid(5, 41, width, height);
  std::vector<int> pins;
  for (int c = 0; c < 5; ++c) pins.push_back(grid_index(mesh, c, 40));
  Material m;
  m.poisson = 0.0;
  m.damping = 0.0;
  const ClothModel model = make_model(mesh, m, pins);
  Environment env;
  SolverSettings s = newton_settings();
  auto solver = make_newton_solver(model, s);
  ClothState state = rest_state(model);
  StepInputs in;
  in.env = &env;
  // Large steps: backward Euler with dt = 10 s is a damped static solve.
  for (int k = 0; k < 6; ++k) ASSERT_TRUE(solver->step(state, 10.0, in).stable);
  double drop = 0;
  for (int c = 0; c < 5; ++c)
    drop += mesh.rest(1, grid_index(mesh, c, 0)) - state.x(1, grid_index(mesh, c, 0));
  drop /= 5;
  const double expected = m.density * 9.81 * height * height / (2 * m.stretch_stiffness());
  // The right-triangle lattice is stiffer than Y in uniaxial stretch with free sides by a Poisson
  // effect of its diagonals; the mapping is calibrated to the equilateral lattice. Within 35 %.
  EXPECT_GT(drop, 0.65 * expected);
  EXPECT_LT(drop, 1.35 * expected);
}

namespace {

// A plate of seed 004's equilateral grid, `rows` node rows long (x, 0.1 m) and 0.15 m wide (z),
// clamped along x = 0 by its first two node rows, under a small gravity load (linear theory),
// solved to rest with large steps. Returns the mean drop of the middle of the free edge and the
// Euler-Bernoulli value q L^4 / (8 D) with the plate rigidity D per unit width (cylindrical
// bending: the plate is wider than long, so away from its free sides it bends as a wide beam).
struct CantileverResult {
  double deflection, expected, row_spacing, length;
};

CantileverResult cantilever_deflection(int rows) {
  const ClothScene scene = make_cantilever_plate(rows);
  const ClothModel& model = scene.model;
  auto solver = make_newton_solver(model, newton_settings());
  ClothState state = scene.initial;
  StepInputs in;
  in.env = &scene.env;
  // Backward Euler with 5 s steps is a damped static solve.
  for (int k = 0; k < 8; ++k) {
    const StepReport r = solver->step(state, 5.0, in);
    EXPECT_TRUE(r.stable) << r.message;
  }
  const int tip_row = rows - 1, mid = model.mesh.grid_columns / 2;
  const double tip = -0.5 * (state.x(1, grid_index(model.mesh, mid, tip_row)) +
                             state.x(1, grid_index(model.mesh, mid - 1, tip_row)));
  // The clamp line is the last clamped row.
  const double h = kCantileverLength / (rows - 1);
  const double free_length = kCantileverLength - h;
  const double q = model.material.density * scene.env.gravity.norm();
  return {tip, q * std::pow(free_length, 4) / (8 * model.material.bending_rigidity()), h,
          free_length};
}

}  // namespace

TEST(NewtonSolver, CantileverMatchesEulerBernoulliAndConvergesUnderRefinement) {
  const CantileverResult coarse = cantilever_deflection(21);
  const CantileverResult fine = cantilever_deflection(31);
  const double err_coarse = std::abs(coarse.deflection / coarse.expected - 1);
  const double err_fine = std::abs(fine.deflection / fine.expected - 1);
  EXPECT_LT(err_fine, 0.10) << "deflection " << fine.deflection << " expected " << fine.expected;
  EXPECT_LT(err_fine, err_coarse) << "coarse " << err_coarse << " fine " << err_fine;
  // The remaining error is the discrete clamp: the hinges on the last clamped row carry the
  // curvature of half a row spacing behind it, so the beam's effective root is h/2 further back.
  // Measured from there, both resolutions agree with the formula within 3 %.
  for (const CantileverResult& c : {coarse, fine}) {
    const double shifted = c.expected * std::pow((c.length + 0.5 * c.row_spacing) / c.length, 4);
    EXPECT_NEAR(c.deflection / shifted, 1.0, 0.03);
  }
  // Small-deflection regime, as the formula assumes.
  EXPECT_LT(fine.deflection, 0.01 * 0.1);
}

TEST(NewtonSolver, LinearSolversAgree) {
#ifndef CLOTHDB_HAVE_CHOLMOD
  GTEST_SKIP() << "built without CHOLMOD";
#else
  ClothScene scene = make_hard_case("hanging-sheet", 15);
  StepInputs in;
  in.env = &scene.env;
  auto run = [&](LinearSolverKind kind, int steps) {
    auto solver = make_newton_solver(scene.model, newton_settings(kind));
    ClothState state = scene.initial;
    for (int k = 0; k < steps; ++k) {
      const StepReport r = solver->step(state, scene.frame_dt, in);
      EXPECT_TRUE(r.stable) << linear_solver_name(kind) << ": " << r.message;
    }
    return state;
  };
  const ClothState ldlt = run(LinearSolverKind::SimplicialLDLT, 1);
  const ClothState cholmod = run(LinearSolverKind::Cholmod, 1);
  EXPECT_LT((ldlt.x - cholmod.x).cwiseAbs().maxCoeff(), 1e-8);
  const ClothState pcg = run(LinearSolverKind::ConjugateGradient, 1);
  // PCG stops at a residual within the Newton tolerance; the positions then agree to that force
  // divided by the smallest stiffness, the mass term m / dt^2.
  double m_min = 1e300;
  for (int i = 0; i < scene.model.vertex_count(); ++i)
    if (scene.model.inv_mass[i] > 0) m_min = std::min(m_min, scene.model.mass[i]);
  const double tol = tolerance_for(scene.model, newton_settings(), scene.env.gravity);
  const double bound = 3 * tol / (m_min / (scene.frame_dt * scene.frame_dt));
  EXPECT_LT((ldlt.x - pcg.x).cwiseAbs().maxCoeff(), bound);
  const ClothState pcg_ic = run(LinearSolverKind::ConjugateGradientIC, 1);
  EXPECT_LT((ldlt.x - pcg_ic.x).cwiseAbs().maxCoeff(), bound);
  // And over several steps, where the differences could accumulate.
  const ClothState ldlt5 = run(LinearSolverKind::SimplicialLDLT, 5);
  const ClothState cholmod5 = run(LinearSolverKind::Cholmod, 5);
  EXPECT_LT((ldlt5.x - cholmod5.x).cwiseAbs().maxCoeff(), 1e-8);
#endif
}

TEST(NewtonSolver, CholmodSupernodalReachesTheLdltEndState) {
#ifndef CLOTHDB_HAVE_CHOLMOD
  GTEST_SKIP() << "built without CHOLMOD";
#else
  // The falling sheet of FallingEquilateralSheetConvergesEveryStep under the default loop
  // (projected Hessian first, then exact): the exact Hessian of the folding sheet is sometimes
  // indefinite, so the supernodal factor is also refactorised after a failed factorisation.
  const int n = 13;
  const ClothModel model = make_falling_equilateral_sheet(n);
  Environment env;
  env.air_drag = 2.0 * model.material.density;
  StepInputs in;
  in.env = &env;
  struct Run {
    ClothState state;
    int iterations = 0, factorizations = 0;
  };
  auto run = [&](LinearSolverKind kind) {
    SolverSettings s;  // the defaults, as the scenes run Newton
    s.linear_solver = kind;
    auto solver = make_newton_solver(model, s);
    Run out{rest_state(model)};
    for (int f = 1; f <= 10; ++f) {
      const StepReport r = solver->step(out.state, 1.0 / 30.0, in);
      EXPECT_TRUE(r.stable) << linear_solver_name(kind) << ": " << r.message;
      EXPECT_EQ(r.step_halvings, 0) << linear_solver_name(kind) << ": " << r.message;
      out.iterations += r.iterations;
      out.factorizations += r.factorizations;
    }
    return out;
  };
  const int levels = omp_get_max_active_levels();
  const Run ldlt = run(LinearSolverKind::SimplicialLDLT);
  const Run super = run(LinearSolverKind::CholmodSupernodal);
  // CHOLMOD ran with this thread's OpenMP regions inactive (the solver has one thread); the
  // setting is restored afterwards.
  EXPECT_EQ(omp_get_max_active_levels(), levels);
  // LL^T and LDL^T differ in rounding only: the same iterates, so the same counts.
  EXPECT_EQ(super.iterations, ldlt.iterations);
  EXPECT_EQ(super.factorizations, ldlt.factorizations);
  EXPECT_GT(ldlt.factorizations, ldlt.iterations);  // some exact Hessian was indefinite
  EXPECT_LT((ldlt.state.x - super.state.x).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_GT((ldlt.state.x - rest_state(model).x).cwiseAbs().maxCoeff(), 0.1);  // it fell
#endif
}

TEST(NewtonSolver, PcgConvergesOnItsOwn) {
  ClothScene scene = make_hard_case("hanging-sheet", 15);
  StepInputs in;
  in.env = &scene.env;
  const SolverSettings s = newton_settings(LinearSolverKind::ConjugateGradient);
  auto solver = make_newton_solver(scene.model, s);
  ClothState state = scene.initial;
  const double tol = tolerance_for(scene.model, s, scene.env.gravity);
  for (int k = 0; k < 10; ++k) {
    const StepReport r = solver->step(state, scene.frame_dt, in);
    ASSERT_TRUE(r.stable) << r.message;
    EXPECT_LT(r.residual, tol);
  }
}

TEST(NewtonSolver, ResultsDoNotDependOnThreadCount) {
  ClothScene scene = make_hard_case("hanging-sheet", 11);
  StepInputs in;
  in.env = &scene.env;
  auto run = [&](int threads) {
    SolverSettings s = newton_settings();
    s.threads = threads;
    auto solver = make_newton_solver(scene.model, s);
    ClothState state = scene.initial;
    for (int k = 0; k < 3; ++k) {
      const StepReport report = solver->step(state, scene.frame_dt, in);
      EXPECT_TRUE(report.stable) << threads << " threads, step " << k << ": " << report.message;
    }
    return state.x;
  };
  const Eigen::Matrix3Xd one = run(1), two = run(2);
  // Both ran: the sheet moved (a solver that did nothing would give equal results too).
  ASSERT_TRUE(one.allFinite());
  EXPECT_GT((one - scene.initial.x).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_EQ((one - two).cwiseAbs().maxCoeff(), 0.0);
}

TEST(NewtonSolver, SubstepsAndMovingPinsStayStable) {
  ClothScene scene = make_hard_case("swung-sheet", 11);
  SolverSettings s = newton_settings();
  s.substeps = 2;
  auto solver = make_newton_solver(scene.model, s);
  const RunResult run = run_scene(scene, *solver, 20, false);
  EXPECT_TRUE(run.stable) << run.message;
  for (const auto& m : run.metrics) EXPECT_LT(m.max_strain, 0.05);
}

TEST(NewtonSolver, SphereContactKeepsTheMargin) {
  // Contacts are a position projection after each solve; sub-steps keep the per-step correction
  // (and so the friction's normal-force estimate) small.
  ClothScene scene = make_hard_case("sphere-drape", 11);
  SolverSettings s = newton_settings();
  s.substeps = 4;
  // The sheet centred on the sphere is a symmetric, unstable balance: with the projected Hessian
  // first (the default) the iterates break the symmetry differently and the sheet slips off the
  // sphere within the second (measured: its centre 0.79 m from the sphere's after 30 frames),
  // so the drape is checked on the exact-Hessian path it was written for.
  s.newton_projected_first = false;
  auto solver = make_newton_solver(scene.model, s);
  const RunResult run = run_scene(scene, *solver, 30, true);
  ASSERT_TRUE(run.stable) << run.message;
  for (const auto& m : run.metrics) EXPECT_LT(m.max_penetration, 1e-9);
  // The sheet came down onto the sphere (it started 5 cm above the top) and stays outside it.
  const ClothMesh& mesh = scene.model.mesh;
  const int centre = grid_index(mesh, mesh.grid_columns / 2, mesh.grid_rows / 2);
  const double r = run.frames.back().col(centre).norm();
  EXPECT_GE(r, 0.3 + scene.env.collision_margin - 1e-9);
  EXPECT_LT(r, 0.3 + 0.025);
}

TEST(NewtonSolver, DegenerateMeshesNeverProduceNaN) {
  for (const char* name : {"slivers", "stretched-start"}) {
    ClothScene scene = make_hard_case(name, 11);
    auto solver = make_newton_solver(scene.model, newton_settings());
    ClothState state = scene.initial;
    StepInputs in;
    in.env = &scene.env;
    for (int f = 0; f < 20; ++f) {
      const ClothState before = state;
      const StepReport r = solver->step(state, scene.frame_dt, in);
      EXPECT_TRUE(state.x.allFinite() && state.v.allFinite()) << name << " frame " << f;
      if (!r.stable) {
        // Honest failure: a message, and the state restored.
        EXPECT_FALSE(r.message.empty()) << name;
        EXPECT_EQ((state.x - before.x).cwiseAbs().maxCoeff(), 0.0) << name;
        break;
      }
      if (r.step_halvings > 0) {
        EXPECT_FALSE(r.message.empty()) << name;
      }
    }
  }
}

TEST(NewtonSolver, StretchedStartRecoversWithinTheHalvingBudget) {
  // 150 % stretch with a single pin: the first step releases a huge elastic energy. Backward
  // Euler absorbs it; Newton may need halvings, which the report must count.
  ClothScene scene = make_hard_case("stretched-start", 11);
  auto solver = make_newton_solver(scene.model, newton_settings());
  ClothState state = scene.initial;
  StepInputs in;
  in.env = &scene.env;
  const double strain0 = max_edge_strain(scene.model, state.x);
  EXPECT_GT(strain0, 0.45);
  const StepReport r = solver->step(state, scene.frame_dt, in);
  ASSERT_TRUE(r.stable) << r.message;
  EXPECT_LT(max_edge_strain(scene.model, state.x), strain0);
  if (r.step_halvings > 0) {
    EXPECT_NE(r.message.find("halved"), std::string::npos) << r.message;
  }
}

TEST(NewtonSolver, ReportsFailureHonestlyWhenHalvingsAreExhausted) {
  // One Newton iteration and no halvings cannot reach the tolerance from a 150 % stretch.
  ClothScene scene = make_hard_case("stretched-start", 11);
  SolverSettings s = newton_settings();
  s.newton_max_iterations = 1;
  s.newton_max_halvings = 0;
  auto solver = make_newton_solver(scene.model, s);
  ClothState state = scene.initial;
  StepInputs in;
  in.env = &scene.env;
  const StepReport r = solver->step(state, scene.frame_dt, in);
  EXPECT_FALSE(r.stable);
  EXPECT_NE(r.message.find("no convergence"), std::string::npos) << r.message;
  EXPECT_EQ((state.x - scene.initial.x).cwiseAbs().maxCoeff(), 0.0);
  // With halvings allowed the same settings recover by splitting the step, and say so.
  s.newton_max_halvings = 8;
  s.newton_max_iterations = 25;
  auto patient = make_newton_solver(scene.model, s);
  ClothState again = scene.initial;
  const StepReport r2 = patient->step(again, scene.frame_dt, in);
  EXPECT_TRUE(r2.stable) << r2.message;
}

// Chord iterations (SolverSettings::newton_reuse_contraction: a factorisation reused while the
// residual keeps contracting) and the predicted start (newton_guess) change the path to the
// minimum, not the minimum: they agree with the plain loop (start at x_n, a factorisation every
// iteration) within what the tolerance allows, and chords need fewer factorisations. (This also
// caught the plain loop never setting the Rayleigh damping matrix K_n when no pin moves.)
TEST(NewtonSolver, ChordIterationsReachTheSameSolutionWithFewerFactorisations) {
  // A soft sheet hanging from its whole top edge, sagging and swinging from rest under its own
  // weight: stretched everywhere, so the incremental potential has one minimum per step. (Where
  // cloth is compressed it buckles, Phi has several minima, and a different start may find
  // another one: the seed 004 falling grid ends centimetres apart after a few frames.)
  const int n = 9;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  std::vector<int> pins;
  for (int c = 0; c < n; ++c) pins.push_back(grid_index(mesh, c, n - 1));
  Material m;
  m.youngs_modulus = 2.0e5;  // E t = 100 N/m: a sag of centimetres
  const ClothModel model = make_model(mesh, m, pins);
  Environment env;
  env.air_drag = 2.0 * m.density;
  StepInputs in;
  in.env = &env;
  auto run = [&](SolverSettings::Guess guess, double contraction, int& factorizations) {
    SolverSettings s = newton_settings();
    s.newton_tolerance = 1e-8;
    s.newton_guess = guess;
    s.newton_reuse_contraction = contraction;
    auto solver = make_newton_solver(model, s);
    ClothState state = rest_state(model);
    factorizations = 0;
    for (int f = 1; f <= 6; ++f) {
      const StepReport r = solver->step(state, 1.0 / 30.0, in);
      EXPECT_TRUE(r.stable) << r.message;
      EXPECT_EQ(r.step_halvings, 0) << r.message;
      factorizations += r.factorizations;
    }
    return state;
  };
  int plain_count = 0, chord_count = 0, guess_count = 0;
  const ClothState plain = run(SolverSettings::Guess::Start, 0.0, plain_count);
  const ClothState chord = run(SolverSettings::Guess::Start, 0.5, chord_count);
  const ClothState guessed = run(SolverSettings::Guess::Extrapolate, 0.0, guess_count);
  EXPECT_LT((plain.x - guessed.x).cwiseAbs().maxCoeff(), 1e-7) << guess_count;
  // The residual tolerance 1e-8 m g over the mass term m / dt^2 is about 1e-10 m per step.
  EXPECT_LT((plain.x - chord.x).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_LT(chord_count, plain_count);
  // The sheet really moved (the comparison is not between sheets at rest).
  EXPECT_GT((plain.x - rest_state(model).x).cwiseAbs().maxCoeff(), 0.004);
}

// Newton's stopping rule (the defaults; docs/notebook/BENCHMARKS.md, "Newton on seed 004's grids"):
// stop once an update changes no velocity by more than 1e-3 m/s, keep a non-converged iterate that
// lowered Phi, projected Hessian first. It must end where a tight force tolerance ends
// (within 0.01 mm), with fewer Newton iterations, no halvings.
TEST(NewtonSolver, StopOnTheUpdateReachesTheTightEndState) {
  // The soft sheet of the chord test, hanging from its top edge: one minimum per step.
  const int n = 9;
  ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  std::vector<int> pins;
  for (int c = 0; c < n; ++c) pins.push_back(grid_index(mesh, c, n - 1));
  Material m;
  m.youngs_modulus = 2.0e5;
  const ClothModel model = make_model(mesh, m, pins);
  Environment env;
  env.air_drag = 2.0 * m.density;
  StepInputs in;
  in.env = &env;
  auto run = [&](const SolverSettings& s, int& iterations) {
    auto solver = make_newton_solver(model, s);
    ClothState state = rest_state(model);
    iterations = 0;
    for (int f = 1; f <= 15; ++f) {
      const StepReport r = solver->step(state, 1.0 / 30.0, in);
      EXPECT_TRUE(r.stable) << r.message;
      EXPECT_EQ(r.step_halvings, 0) << r.message;
      iterations += r.iterations;
    }
    return state;
  };
  SolverSettings tight = newton_settings();
  tight.newton_tolerance = 1e-10;
  SolverSettings update;  // the defaults
  ASSERT_GT(update.newton_velocity_tolerance, 0.0);
  ASSERT_TRUE(update.newton_accept_decrease);
  int tight_iterations = 0, update_iterations = 0;
  const ClothState a = run(tight, tight_iterations);
  const ClothState b = run(update, update_iterations);
  EXPECT_LT((a.x - b.x).colwise().norm().maxCoeff(), 1e-5);
  EXPECT_LT(update_iterations, tight_iterations);
  EXPECT_GT((a.x - rest_state(model).x).cwiseAbs().maxCoeff(), 0.004);  // it moved

  // At the iteration cap with no halvings allowed, a step that lowered Phi is kept (and counted)
  // instead of failing: the stretched start relaxes in one iteration per step.
  ClothScene scene = make_hard_case("stretched-start", 11);
  SolverSettings capped;
  capped.newton_max_iterations = 1;
  capped.newton_max_halvings = 0;
  auto solver = make_newton_solver(scene.model, capped);
  ClothState state = scene.initial;
  StepInputs sin;
  sin.env = &scene.env;
  const double strain0 = max_edge_strain(scene.model, state.x);
  const StepReport r = solver->step(state, scene.frame_dt, sin);
  EXPECT_TRUE(r.stable) << r.message;
  EXPECT_EQ(r.step_halvings, 0);
  EXPECT_GE(r.unconverged, 1);
  EXPECT_LT(max_edge_strain(scene.model, state.x), strain0);
}

// The hinge weighting k_b = D |e|^2 / (A1 + A2) on a quad grid split into right triangles: a sheet
// bent into a cylinder about a grid axis (w = kappa x^2 / 2) stores exactly D/2 kappa^2 per unit
// area in its interior hinges (the diagonal hinges stay flat), while a twist w = tau x y stores
// twice the plate value D tau^2 (nu = 0). A wrong constant in the weighting or the mapping from D
// shows up in the first; the second is the quad grid's anisotropy (docs/notebook/BENCHMARKS.md,
// cantilever).
TEST(ShellEnergy, QuadGridHingeEnergyOfCylindricalBendingAndTwist) {
  const int n = 21;
  const ClothMesh mesh = make_quad_grid(n, n, 1.0, 1.0);
  const double d = 2.0e-3, kappa = 0.01, h = 1.0 / (n - 1);
  std::map<std::pair<int, int>, double> area;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      const int a = t[k], b = t[(k + 1) % 3];
      area[{std::min(a, b), std::max(a, b)}] += triangle_area(mesh.rest, t);
    }
  auto energy = [&](auto w) {
    Eigen::Matrix3Xd x = mesh.rest;
    for (int i = 0; i < x.cols(); ++i) x(2, i) = w(mesh.rest(0, i), mesh.rest(1, i));
    double e = 0;
    for (const Hinge& hg : mesh.hinges) {
      const double le = (mesh.rest.col(hg.v1) - mesh.rest.col(hg.v0)).norm();
      const double kb =
          bend_coefficient(d, le, area[{std::min(hg.v0, hg.v1), std::max(hg.v0, hg.v1)}]);
      e += bend_energy(x.col(hg.v0).data(), x.col(hg.v1).data(), x.col(hg.a).data(),
                       x.col(hg.b).data(), 0.0, kb);
    }
    return e;
  };
  // Bending about y: hinges on the n - 2 interior grid lines x = const, each (n - 1) cells long.
  const double interior = (n - 2) * h * 1.0;
  const double bend = energy([&](double x, double) { return 0.5 * kappa * x * x; });
  EXPECT_NEAR(bend / (0.5 * d * kappa * kappa * interior), 1.0, 1e-3);
  // Twist: every cell's diagonal hinge folds by sqrt(2) tau h; the plate stores D tau^2 per area.
  const double twist = energy([&](double x, double y) { return kappa * x * y; });
  EXPECT_NEAR(twist / (d * kappa * kappa * 1.0), 2.0, 0.01);
}

// `bench newton`'s fast setting on seed 004's falling grid (docs/notebook/newton_auto.md): the
// extrapolated start and the contraction-based stop, on the supernodal factor where there is one.
// Its end state is pinned against a tight-tolerance run of the same sub-steps (force tolerance
// 1e-8, update stop 1e-7 m/s), and it is bit-identical on 1 and 2 threads. The grid folds in the
// first frames, where most Newton iterations are spent.
TEST(NewtonSolver, FastSettingOnTheFallingGridReachesTheTightEndState) {
  const ClothScene scene = make_seed004_fall();
  StepInputs in;
  in.env = &scene.env;
  const int frames = 8;
  auto run = [&](const SolverSettings& s, int& iterations) {
    auto solver = make_newton_solver(scene.model, s);
    ClothState state = scene.initial;
    iterations = 0;
    for (int f = 1; f <= frames; ++f) {
      const StepReport r = solver->step(state, scene.frame_dt, in);
      EXPECT_TRUE(r.stable) << "frame " << f << ": " << r.message;
      EXPECT_EQ(r.step_halvings, 0) << "frame " << f << ": " << r.message;
      iterations += r.iterations;
    }
    return state.x;
  };
  SolverSettings tight;
  tight.newton_tolerance = 1e-8;
  tight.newton_velocity_tolerance = 1e-7;
  tight.newton_max_iterations = 200;
  SolverSettings fast;  // the defaults (update stop 1e-3 m/s) with the extrapolated start
  fast.newton_guess = SolverSettings::Guess::Extrapolate;
#ifdef CLOTHDB_HAVE_CHOLMOD
  // The same iterates as LDLT (CholmodSupernodalReachesTheLdltEndState), in less time.
  tight.linear_solver = fast.linear_solver = LinearSolverKind::CholmodSupernodal;
#endif
  int tight_iterations = 0, fast_iterations = 0, two_iterations = 0;
  const Eigen::Matrix3Xd a = run(tight, tight_iterations);
  const Eigen::Matrix3Xd b = run(fast, fast_iterations);
  fast.threads = 2;
  const Eigen::Matrix3Xd c = run(fast, two_iterations);
  const Eigen::RowVectorXd d = (a - b).colwise().norm();
  // Measured: 0.29 mm RMS, 1.7 mm max after 8 frames (0.06 / 0.3 mm after 30, `bench newton`),
  // while the grid falls by 0.31 m.
  EXPECT_LT(std::sqrt(d.squaredNorm() / static_cast<double>(d.size())), 0.5e-3);
  EXPECT_LT(d.maxCoeff(), 3e-3);
  EXPECT_GT((a - scene.initial.x).colwise().norm().maxCoeff(), 0.2);  // it fell
  EXPECT_LT(fast_iterations, tight_iterations / 2);
  EXPECT_EQ((b - c).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(fast_iterations, two_iterations);
}
