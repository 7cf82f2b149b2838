// Stretching and hinge-bending energies with analytic gradients and Hessians (see shell_energy.hpp
// for the formulas and the material mapping). Checked against finite differences in
// tests/test_solver_newton.cpp.
#include "solvers/shell_energy.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace clothdb {

namespace {

using V3 = Eigen::Vector3d;
using M3 = Eigen::Matrix3d;

constexpr double kPi = 3.14159265358979323846;

V3 load(const double* p) {
  return V3(p[0], p[1], p[2]);
}

// [a]_x: the matrix with [a]_x b = a x b.
M3 cross_matrix(const V3& a) {
  M3 m;
  m << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
  return m;
}

// Wraps an angle difference into (-pi, pi] so that a hinge whose rest angle is near +-pi does not
// see a 2 pi jump.
double wrap_angle(double a) {
  while (a > kPi) a -= 2.0 * kPi;
  while (a <= -kPi) a += 2.0 * kPi;
  return a;
}

// Shared quantities of one hinge at the current positions.
struct HingeGeometry {
  V3 x0, x1, x2, x3;
  V3 e;       // shared edge x1 - x0
  double le;  // |e|
  V3 n1, n2;  // unnormalised normals of (x0, x1, x2) and (x1, x0, x3)
  double n1sq, n2sq;
  double theta;
  bool degenerate;
};

HingeGeometry hinge_geometry(const double* p0, const double* p1, const double* p2,
                             const double* p3) {
  HingeGeometry g;
  g.x0 = load(p0);
  g.x1 = load(p1);
  g.x2 = load(p2);
  g.x3 = load(p3);
  g.e = g.x1 - g.x0;
  g.le = g.e.norm();
  g.n1 = g.e.cross(g.x2 - g.x0);
  g.n2 = (g.x3 - g.x0).cross(g.e);
  g.n1sq = g.n1.squaredNorm();
  g.n2sq = g.n2.squaredNorm();
  // A triangle whose area is below 1e-12 of |e|^2 has no usable normal (its forces scale as
  // 1/height and its Hessian as 1/height^2).
  const double tiny = 1e-24 * g.le * g.le * g.le * g.le;
  g.degenerate = !(g.le > 0.0) || !(g.n1sq > tiny) || !(g.n2sq > tiny);
  g.theta = 0.0;
  if (!g.degenerate) {
    // sin and cos scaled by |N1| |N2|; atan2 is invariant to the common scale.
    g.theta = std::atan2(g.n1.cross(g.n2).dot(g.e) / g.le, g.n1.dot(g.n2));
  }
  return g;
}

// Gradient of theta (Bridson et al. 2003; Tamstorf & Grinspun 2013 eq. for the "bending modes"):
// the wing vertices move along their own triangle's normal with magnitude 1/height,
//   d theta / d x2 = -|e| N1 / |N1|^2,   d theta / d x3 = -|e| N2 / |N2|^2,
// and the edge vertices carry the reaction split by where the wings project onto the edge,
//   d theta / d x0 = -(1 - s2) g2 - (1 - s3) g3,   d theta / d x1 = -s2 g2 - s3 g3,
// with s_k = (x_k - x0) . e / |e|^2 (translation and rotation invariance).
struct ThetaGradient {
  V3 g2, g3;
  double s2, s3;
  Eigen::Matrix<double, 12, 1> full;
};

ThetaGradient theta_gradient(const HingeGeometry& h) {
  ThetaGradient t;
  t.g2 = -h.le / h.n1sq * h.n1;
  t.g3 = -h.le / h.n2sq * h.n2;
  const double le2 = h.le * h.le;
  t.s2 = (h.x2 - h.x0).dot(h.e) / le2;
  t.s3 = (h.x3 - h.x0).dot(h.e) / le2;
  t.full.segment<3>(0) = -(1.0 - t.s2) * t.g2 - (1.0 - t.s3) * t.g3;
  t.full.segment<3>(3) = -t.s2 * t.g2 - t.s3 * t.g3;
  t.full.segment<3>(6) = t.g2;
  t.full.segment<3>(9) = t.g3;
  return t;
}

// Hessian of theta: the Jacobian of the gradient above, differentiated term by term.
//   g2 = -|e| N1 / |N1|^2:  dg2 = -(e^ . de) N1 / |N1|^2 - |e| / |N1|^2 (I - 2 n1 n1^T) dN1,
//   dN1 = -[x2 - x0]_x (dx1 - dx0) + [e]_x (dx2 - dx0),
//   dN2 = [x3 - x0]_x (dx1 - dx0) - [e]_x (dx3 - dx0),
//   ds_k = ((dx_k - dx0) . e + (x_k - x0) . de - 2 s_k e . de) / |e|^2,
// then d(g0) = g2 ds2^T - (1 - s2) dg2 + g3 ds3^T - (1 - s3) dg3 and
//      d(g1) = -g2 ds2^T - s2 dg2 - g3 ds3^T - s3 dg3.
// The result is symmetrised to remove rounding asymmetry.
Eigen::Matrix<double, 12, 12> theta_hessian(const HingeGeometry& h, const ThetaGradient& t) {
  using Row12 = Eigen::Matrix<double, 1, 12>;
  using J = Eigen::Matrix<double, 3, 12>;
  const V3 ehat = h.e / h.le;
  const double le2 = h.le * h.le;
  const V3 w = h.x2 - h.x0, z = h.x3 - h.x0;
  const M3 ex = cross_matrix(h.e), wx = cross_matrix(w), zx = cross_matrix(z);

  Row12 dle = Row12::Zero();  // d|e|
  dle.segment<3>(0) = -ehat.transpose();
  dle.segment<3>(3) = ehat.transpose();

  J dn1 = J::Zero(), dn2 = J::Zero();
  dn1.block<3, 3>(0, 0) = wx - ex;
  dn1.block<3, 3>(0, 3) = -wx;
  dn1.block<3, 3>(0, 6) = ex;
  dn2.block<3, 3>(0, 0) = ex - zx;
  dn2.block<3, 3>(0, 3) = zx;
  dn2.block<3, 3>(0, 9) = -ex;

  const V3 u1 = h.n1 / std::sqrt(h.n1sq), u2 = h.n2 / std::sqrt(h.n2sq);
  const M3 p1 = M3::Identity() - 2.0 * u1 * u1.transpose();
  const M3 p2 = M3::Identity() - 2.0 * u2 * u2.transpose();
  const J dg2 = -(h.n1 / h.n1sq) * dle - (h.le / h.n1sq) * p1 * dn1;
  const J dg3 = -(h.n2 / h.n2sq) * dle - (h.le / h.n2sq) * p2 * dn2;

  Row12 ds2 = Row12::Zero(), ds3 = Row12::Zero();
  ds2.segment<3>(0) = (-h.e - w + 2.0 * t.s2 * h.e).transpose() / le2;
  ds2.segment<3>(3) = (w - 2.0 * t.s2 * h.e).transpose() / le2;
  ds2.segment<3>(6) = h.e.transpose() / le2;
  ds3.segment<3>(0) = (-h.e - z + 2.0 * t.s3 * h.e).transpose() / le2;
  ds3.segment<3>(3) = (z - 2.0 * t.s3 * h.e).transpose() / le2;
  ds3.segment<3>(9) = h.e.transpose() / le2;

  Eigen::Matrix<double, 12, 12> H;
  H.block<3, 12>(0, 0) = t.g2 * ds2 - (1.0 - t.s2) * dg2 + t.g3 * ds3 - (1.0 - t.s3) * dg3;
  H.block<3, 12>(3, 0) = -t.g2 * ds2 - t.s2 * dg2 - t.g3 * ds3 - t.s3 * dg3;
  H.block<3, 12>(6, 0) = dg2;
  H.block<3, 12>(9, 0) = dg3;
  return 0.5 * (H + H.transpose());
}

}  // namespace

double stretch_coefficient(double membrane_stiffness, double adjacent_area, double rest_length) {
  return rest_length > 0.0 ? membrane_stiffness * adjacent_area / rest_length : 0.0;
}

double stretch_energy(const double* x0, const double* x1, double rest_length, double k_s) {
  const double l = (load(x1) - load(x0)).norm();
  const double strain = l / rest_length - 1.0;
  return 0.5 * k_s * rest_length * strain * strain;
}

double stretch_gradient(const double* x0, const double* x1, double rest_length, double k_s,
                        double* grad) {
  const V3 d = load(x1) - load(x0);
  const double l = d.norm();
  const double strain = l / rest_length - 1.0;
  // dE/dx1 = k_s (l / l0 - 1) u; a zero-length edge has no direction and, by symmetry, no force.
  const V3 f = l > 0.0 ? V3(k_s * strain / l * d) : V3::Zero();
  for (int c = 0; c < 3; ++c) {
    grad[c] = -f[c];
    grad[3 + c] = f[c];
  }
  return 0.5 * k_s * rest_length * strain * strain;
}

double stretch_hessians(const double* x0, const double* x1, double rest_length, double k_s,
                        double* grad, double* hess_exact, double* hess_projected) {
  const double energy = stretch_gradient(x0, x1, rest_length, k_s, grad);
  const V3 d = load(x1) - load(x0);
  const double l = d.norm();
  // d2E/dx1^2 = k_s (u u^T / l0 + (l / l0 - 1) (I - u u^T) / l): axial stiffness plus the
  // geometric (string tension) term, which is negative for a compressed edge.
  M3 axial, transverse;
  double t = 0.0;
  if (l > 1e-12 * rest_length) {
    const V3 u = d / l;
    axial = (k_s / rest_length) * (u * u.transpose());
    transverse = M3::Identity() - u * u.transpose();
    t = k_s * (l / rest_length - 1.0) / l;
  } else {
    // Collapsed edge: the axial direction is undefined; the isotropic axial stiffness keeps the
    // system definite and is the limit of the projected Hessian averaged over directions.
    axial = (k_s / rest_length) * M3::Identity();
    transverse.setZero();
  }
  auto store = [](double* out, const M3& k) {
    Eigen::Map<Eigen::Matrix<double, 6, 6>> H(out);
    H.block<3, 3>(0, 0) = k;
    H.block<3, 3>(3, 3) = k;
    H.block<3, 3>(0, 3) = -k;
    H.block<3, 3>(3, 0) = -k;
  };
  if (hess_exact) store(hess_exact, axial + t * transverse);
  if (hess_projected) store(hess_projected, axial + std::max(t, 0.0) * transverse);
  return energy;
}

double stretch_hessian(const double* x0, const double* x1, double rest_length, double k_s,
                       double* grad, double* hess, bool project) {
  return project ? stretch_hessians(x0, x1, rest_length, k_s, grad, nullptr, hess)
                 : stretch_hessians(x0, x1, rest_length, k_s, grad, hess, nullptr);
}

double bend_coefficient(double bending_rigidity, double rest_edge_length, double rest_area_sum) {
  const double l2 = rest_edge_length * rest_edge_length;
  const double area = std::max(rest_area_sum, kMinHingeAreaRatio * l2);
  return area > 0.0 ? bending_rigidity * l2 / area : 0.0;
}

double hinge_angle(const double* x0, const double* x1, const double* x2, const double* x3) {
  return hinge_geometry(x0, x1, x2, x3).theta;
}

double bend_energy(const double* x0, const double* x1, const double* x2, const double* x3,
                   double theta0, double k_b) {
  const HingeGeometry h = hinge_geometry(x0, x1, x2, x3);
  if (h.degenerate) return 0.0;
  const double dtheta = wrap_angle(h.theta - theta0);
  return 0.5 * k_b * dtheta * dtheta;
}

double bend_gradient(const double* x0, const double* x1, const double* x2, const double* x3,
                     double theta0, double k_b, double* grad) {
  Eigen::Map<Eigen::Matrix<double, 12, 1>> G(grad);
  const HingeGeometry h = hinge_geometry(x0, x1, x2, x3);
  if (h.degenerate) {
    G.setZero();
    return 0.0;
  }
  const double dtheta = wrap_angle(h.theta - theta0);
  G = (k_b * dtheta) * theta_gradient(h).full;
  return 0.5 * k_b * dtheta * dtheta;
}

double bend_hessians(const double* x0, const double* x1, const double* x2, const double* x3,
                     double theta0, double k_b, double* grad, double* hess_exact,
                     double* hess_projected) {
  Eigen::Map<Eigen::Matrix<double, 12, 1>> G(grad);
  const HingeGeometry h = hinge_geometry(x0, x1, x2, x3);
  if (h.degenerate) {
    G.setZero();
    if (hess_exact) Eigen::Map<Eigen::Matrix<double, 12, 12>>(hess_exact).setZero();
    if (hess_projected) Eigen::Map<Eigen::Matrix<double, 12, 12>>(hess_projected).setZero();
    return 0.0;
  }
  const double dtheta = wrap_angle(h.theta - theta0);
  const ThetaGradient t = theta_gradient(h);
  G = (k_b * dtheta) * t.full;
  const Eigen::Matrix<double, 12, 12> gauss_newton = k_b * (t.full * t.full.transpose());
  if (hess_projected) {
    Eigen::Map<Eigen::Matrix<double, 12, 12>> P(hess_projected);
    P = gauss_newton;
  }
  if (hess_exact) {
    Eigen::Map<Eigen::Matrix<double, 12, 12>> H(hess_exact);
    H = gauss_newton;
    // The curvature term vanishes with theta - theta0; skipping it then is exact and saves the
    // most expensive part for the many nearly flat hinges of a cloth at rest.
    if (dtheta != 0.0) H += (k_b * dtheta) * theta_hessian(h, t);
  }
  return 0.5 * k_b * dtheta * dtheta;
}

double bend_hessian(const double* x0, const double* x1, const double* x2, const double* x3,
                    double theta0, double k_b, double* grad, double* hess, bool project) {
  return project ? bend_hessians(x0, x1, x2, x3, theta0, k_b, grad, nullptr, hess)
                 : bend_hessians(x0, x1, x2, x3, theta0, k_b, grad, hess, nullptr);
}

}  // namespace clothdb
