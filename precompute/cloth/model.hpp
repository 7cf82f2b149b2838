// The cloth model every solver takes: mesh, material in SI units, lumped masses, pins.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cloth/mesh.hpp"

namespace clothdb {

// Material in physical units. Every solver maps this same material to its own parameters
// (spring constants, compliances, constraint stiffness) so that all four simulate the same cloth.
struct Material {
  double density = 0.15;  // area density, kg/m^2 (light fabric ~0.1-0.3)
  // Pa; stretch stiffness per unit width is E * thickness = 5e4 N/m by default (woven cotton is
  // of the order of 1e4-1e5 N/m).
  double youngs_modulus = 1.0e8;
  double poisson = 0.3;       // Poisson ratio (used by the bending rigidity D)
  double thickness = 0.5e-3;  // m; also the default collision margin
  // Bending rigidity D in N*m. Negative means derive the plate value D = E t^3 / (12 (1 - nu^2)),
  // right for plates (the cantilever case) but far too stiff for woven cloth, whose fibres slide:
  // measured fabric rigidities are 1e-6 to 1e-4 N*m, hence the default.
  double bending_stiffness = 1.0e-5;
  // Stiffness-proportional (Rayleigh) damping coefficient beta, in seconds: the damping force of a
  // spring of stiffness k is beta * k times the relative velocity along it (seed 001's damping
  // force with d = beta k; XPBD's Rayleigh damping, Macklin 2016 eq. 26).
  double damping = 1.0e-3;

  // Stretch stiffness per unit width, N/m.
  double stretch_stiffness() const { return youngs_modulus * thickness; }
  // Bending rigidity D, N*m.
  double bending_rigidity() const {
    if (bending_stiffness >= 0.0) return bending_stiffness;
    return youngs_modulus * thickness * thickness * thickness / (12.0 * (1.0 - poisson * poisson));
  }
};

struct ClothModel {
  ClothMesh mesh;
  Material material;
  Eigen::VectorXd mass;         // per vertex, kg: one third of each adjacent triangle's mass
  Eigen::VectorXd inv_mass;     // 1/mass, or 0 for kinematic (pinned or driven) vertices
  Eigen::VectorXd vertex_area;  // per vertex, m^2: one third of each adjacent triangle's area
  // Vertices whose positions are prescribed each step (pins that stay, or pins that follow a bone).
  // Their inverse mass is 0. Order matters: StepInputs::kinematic_targets uses it.
  std::vector<int> kinematic;
  std::vector<double> edge_rest_length;  // per mesh edge, m (from mesh.rest)
  // Per mesh edge, m^2: the rest area of its one or two triangles, summed in triangle order (the
  // A_adj of every solver's stretch stiffness, shell_energy.hpp stretch_coefficient).
  std::vector<double> edge_area;

  int vertex_count() const { return mesh.vertex_count(); }
};

// Lumps masses from area density, sets inverse masses (0 for `kinematic`), rest lengths.
// Throws MeshError if a kinematic index is out of range or a vertex has zero mass and is free.
ClothModel make_model(ClothMesh mesh, const Material& material, std::vector<int> kinematic);

}  // namespace clothdb
