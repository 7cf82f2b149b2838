// Discrete elastic plates / shells energies for the implicit Newton solver (seed 004 Algorithm 1,
// GRADES_HESSES and GRADEB_HESSEB; Jawed et al., "Discrete simulation of slender structures";
// Grinspun et al. 2003, "Discrete shells"; Tamstorf & Grinspun 2013, "Discrete bending forces and
// their Jacobians"). Free functions on plain arrays: positions are 3 doubles each, gradients are
// flat (x0, y0, z0, x1, ...), Hessians are square and column-major (they are symmetric, so row-
// or column-major is the same). Every function returns the energy in joules.
#pragma once

namespace clothdb {

// ---- Stretching: one axial spring per mesh edge -------------------------------------------------
//
//   E_s = 1/2 k_s l0 (l / l0 - 1)^2,   l = |x1 - x0|,
//
// Jawed's discrete-rod stretching energy with axial stiffness k_s in newtons (EA for a rod).
// For a membrane of stretch stiffness Y = E t (N/m) we give each edge the spring constant
// k_s / l0 = Y A_adj / l0^2 (A_adj: rest area of the one or two triangles adjacent to the edge),
// i.e. k_s = Y A_adj / l0. On a regular equilateral mesh this is the classical triangular spring
// lattice with 2D Young's modulus Y (and Poisson ratio 1/3): an interior edge has
// A_adj = (sqrt(3)/2) l0^2, so k_s / l0 = (sqrt(3)/2) Y, the lattice value. On other meshes it is
// the energy-density-matching approximation (each triangle's area is shared by its three edges).
double stretch_coefficient(double membrane_stiffness, double adjacent_area, double rest_length);

double stretch_energy(const double* x0, const double* x1, double rest_length, double k_s);
// Energy and gradient (6).
double stretch_gradient(const double* x0, const double* x1, double rest_length, double k_s,
                        double* grad);
// Energy, gradient (6) and Hessian (6 x 6). With `project`, the transverse term of a compressed
// edge (negative when l < l0) is clamped to zero, which is exactly the projection of the element
// Hessian onto the positive semi-definite cone (its eigenvalues are 2 k_s / l0 along the edge and
// 2 k_s (l/l0 - 1) / l twice across it, plus three zeros).
double stretch_hessian(const double* x0, const double* x1, double rest_length, double k_s,
                       double* grad, double* hess, bool project);
// Both Hessians at once (exact and projected), for solvers that try the exact one first.
double stretch_hessians(const double* x0, const double* x1, double rest_length, double k_s,
                        double* grad, double* hess_exact, double* hess_projected);

// ---- Bending: one hinge per interior edge -------------------------------------------------------
//
// Hinge (x0, x1 | x2, x3): the edge x0 -> x1 is shared by triangles (x0, x1, x2) and (x1, x0, x3)
// (the mesh's Hinge {v0, v1, a, b}). theta is the signed angle between the triangle normals
// N1 = (x1 - x0) x (x2 - x0) and N2 = (x3 - x0) x (x1 - x0), in (-pi, pi], 0 when flat; it
// decreases when x2 moves along N1 or x3 along N2.
//
//   E_b = 1/2 k_b (theta - theta0)^2,   k_b = D |e0|^2 / (A1 + A2)   (rest edge and areas),
//
// the discrete-shells energy of Grinspun et al. 2003, (theta - theta0)^2 |e| / h_e with h_e a third
// of the mean height of the two triangles, i.e. |e| / h_e = 3 |e|^2 / (A1 + A2), scaled by D / 6 so
// that a sheet bent into a cylinder of curvature kappa stores D/2 kappa^2 per unit area. On an
// equilateral mesh |e|^2 / (A1 + A2) = 2 / sqrt(3), so k_b = 2 D / sqrt(3), Jawed's DEP value (the
// cantilever test checks it against Euler-Bernoulli). On a quad grid split into right triangles, a
// cylinder about a grid axis is carried by the hinges across the grid lines with theta = kappa h
// exactly, D/2 kappa^2 h^2 per cell, while a twist folds every diagonal hinge and costs twice the
// plate value (test ShellEnergy.QuadGridHingeEnergyOfCylindricalBendingAndTwist). The quad grid is
// nevertheless about 20 % too soft in a cantilever, under refinement too: the minimiser folds the
// diagonal hinges in a pattern that a smooth field cannot express and adds deflection that the
// grid-line hinges do not pay for (docs/notebook/BENCHMARKS.md has the refinement table). The
// rest area is floored at kMinHingeAreaRatio |e0|^2 so that sliver rest triangles do not make a
// hinge arbitrarily stiff.
constexpr double kMinHingeAreaRatio = 0.05;
double bend_coefficient(double bending_rigidity, double rest_edge_length, double rest_area_sum);

double hinge_angle(const double* x0, const double* x1, const double* x2, const double* x3);
double bend_energy(const double* x0, const double* x1, const double* x2, const double* x3,
                   double theta0, double k_b);
// Energy and gradient (12). Degenerate hinges (a triangle of zero area at x) contribute nothing:
// their angle is undefined and their forces would be infinite.
double bend_gradient(const double* x0, const double* x1, const double* x2, const double* x3,
                     double theta0, double k_b, double* grad);
// Energy, gradient (12) and Hessian (12 x 12):
//   H = k_b (grad theta grad theta^T + (theta - theta0) Hess theta).
// With `project` only the Gauss-Newton term k_b grad theta grad theta^T is kept, which is positive
// semi-definite; the solver uses it when the exact Hessian makes the system indefinite.
double bend_hessian(const double* x0, const double* x1, const double* x2, const double* x3,
                    double theta0, double k_b, double* grad, double* hess, bool project);
// Both Hessians at once (exact and Gauss-Newton).
double bend_hessians(const double* x0, const double* x1, const double* x2, const double* x3,
                     double theta0, double k_b, double* grad, double* hess_exact,
                     double* hess_projected);

}  // namespace clothdb
