// EXPERIMENT for issue 28 (docs/notebook/resolution.md, "Eighth round"): Vertex Block Descent
// (Chen, Liu, Yang & Yuksel 2024, "Vertex Block Descent", SIGGRAPH 2024) on the XPBD solver's
// cloth model, to measure whether its convergence per iteration degrades with the resolution less
// than XPBD's Gauss-Seidel. Used only by a disabled probe test; no scene, setting or default
// reaches it.
#pragma once

#include <Eigen/Core>
#include <memory>

#include "solvers/solver.hpp"

namespace clothdb {

struct VbdSettings {
  int substeps = 4;
  int iterations = 8;  // vertex sweeps (all colours) per sub-step
  // Chebyshev semi-iterative acceleration over the sweeps (Chen et al. 2024 sec. 3.7, after Wang
  // 2015): 0 off.
  double chebyshev_rho = 0.0;
  // Initial guess of a sub-step: the paper's adaptive one, y (inertia and gravity), or x_t.
  enum class Init { Adaptive, Inertia, Previous };
  Init init = Init::Adaptive;
  int threads = 1;
};

std::unique_ptr<Solver> make_vbd_solver(const ClothModel& model, const VbdSettings& settings);

// The sub-step problem both VBD and XPBD approximate (Chen et al. 2024 eq. 1; Macklin 2016 eqs.
// 9-10 at convergence): x = argmin 1/(2h^2) |x - y|_M^2 + E(x), E the edge springs and hinges
// with the XPBD solver's coefficients (shell_energy.hpp), the kinematic vertices held.
// y = x_t + h v~, v~ = (v_t + h g) / (1 + h c A_i / m_i): XPBD's prediction with its implicit air
// drag; kinematic vertices take their positions in `x_end`.
Eigen::Matrix3Xd implicit_euler_target(const ClothModel& model, const Environment& env,
                                       const ClothState& start, double h,
                                       const Eigen::Matrix3Xd& x_end);
// |grad| of that objective over the free vertices (N): m_i/h^2 (x_i - y_i) + dE/dx_i.
double implicit_euler_residual(const ClothModel& model, const Eigen::Matrix3Xd& y, double h,
                               const Eigen::Matrix3Xd& x);
// The same problem solved tightly: Newton with the elements' PSD-projected Hessians (stretch with
// the transverse term of compressed edges clamped, bending Gauss-Newton), a sparse LDLT and a
// backtracking line search, from `x0` (its kinematic columns are kept), until the residual is
// below rel_tol times its value at y or 40 iterations. `residual` receives the residual reached.
Eigen::Matrix3Xd implicit_euler_solve(const ClothModel& model, const Eigen::Matrix3Xd& y, double h,
                                      const Eigen::Matrix3Xd& x0, double rel_tol, double* residual);

}  // namespace clothdb
