#include "cloth/model.hpp"

#include <algorithm>
#include <array>
#include <utility>
#include <vector>

namespace clothdb {

ClothModel make_model(ClothMesh mesh, const Material& material, std::vector<int> kinematic) {
  if (mesh.edges.empty()) build_topology(mesh);
  ClothModel model;
  model.material = material;
  const int n = mesh.vertex_count();
  model.mass = Eigen::VectorXd::Zero(n);
  model.vertex_area = Eigen::VectorXd::Zero(n);
  for (const auto& t : mesh.triangles) {
    const double third = triangle_area(mesh.rest, t) / 3.0;
    for (int k = 0; k < 3; ++k) model.vertex_area[t[k]] += third;
  }
  model.mass = model.vertex_area * material.density;
  // A vertex of near-zero-area triangles only (slivers) still needs a mass to be simulated:
  // give it a floor of 1e-6 of the mean vertex mass so inverse masses stay finite.
  const double floor_mass = 1e-6 * model.mass.mean();
  for (int i = 0; i < n; ++i) model.mass[i] = std::max(model.mass[i], floor_mass);
  model.inv_mass = model.mass.cwiseInverse();
  // Keep the caller's order (StepInputs::kinematic_targets follows it); reject duplicates.
  std::vector<int> seen = kinematic;
  std::sort(seen.begin(), seen.end());
  if (std::adjacent_find(seen.begin(), seen.end()) != seen.end()) {
    throw MeshError("pinned vertex " +
                    std::to_string(*std::adjacent_find(seen.begin(), seen.end())) +
                    " is listed twice");
  }
  for (int k : kinematic) {
    if (k < 0 || k >= n) {
      throw MeshError("pinned vertex " + std::to_string(k) + " outside the mesh's " +
                      std::to_string(n) + " vertices");
    }
    model.inv_mass[k] = 0.0;
  }
  model.kinematic = std::move(kinematic);
  model.edge_rest_length.resize(mesh.edges.size());
  for (size_t e = 0; e < mesh.edges.size(); ++e)
    model.edge_rest_length[e] =
        (mesh.rest.col(mesh.edges[e][0]) - mesh.rest.col(mesh.edges[e][1])).norm();
  // Adjacent areas, matched to mesh.edges by binary search over their sorted (i < j) keys.
  model.edge_area.assign(mesh.edges.size(), 0.0);
  std::vector<std::pair<std::array<int, 2>, int>> index;
  index.reserve(mesh.edges.size());
  for (std::size_t e = 0; e < mesh.edges.size(); ++e)
    index.push_back({mesh.edges[e], static_cast<int>(e)});
  std::sort(index.begin(), index.end());
  for (const auto& t : mesh.triangles) {
    const double area = triangle_area(mesh.rest, t);
    for (std::size_t k = 0; k < 3; ++k) {
      const int i = t[k], j = t[(k + 1) % 3];
      const std::array<int, 2> key{std::min(i, j), std::max(i, j)};
      const auto it = std::lower_bound(index.begin(), index.end(), std::make_pair(key, -1));
      if (it != index.end() && it->first == key)
        model.edge_area[static_cast<std::size_t>(it->second)] += area;
    }
  }
  model.mesh = std::move(mesh);
  return model;
}

}  // namespace clothdb
