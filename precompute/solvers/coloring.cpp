#include "solvers/coloring.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace clothdb {

std::vector<std::vector<int>> greedy_coloring(std::span<const int> vertices, int arity) {
  if (arity < 1) throw std::invalid_argument("greedy_coloring: arity must be at least 1");
  const std::size_t a = static_cast<std::size_t>(arity);
  if (vertices.size() % a != 0) {
    throw std::invalid_argument("greedy_coloring: " + std::to_string(vertices.size()) +
                                " indices is not a multiple of the arity " + std::to_string(arity));
  }
  const std::size_t count = vertices.size() / a;
  int max_vertex = -1;
  for (int v : vertices) max_vertex = std::max(max_vertex, v);

  // Colours already taken at each vertex. Cloth vertices touch few constraints, so a short list per
  // vertex is cheaper than a bit set sized by the (unknown) colour count.
  std::vector<std::vector<int>> taken(static_cast<std::size_t>(max_vertex + 1));
  std::vector<std::vector<int>> groups;
  std::vector<char> blocked;
  for (std::size_t c = 0; c < count; ++c) {
    const std::span<const int> tuple = vertices.subspan(c * a, a);
    blocked.assign(groups.size() + 1, 0);
    for (int v : tuple) {
      if (v < 0) continue;
      for (int colour : taken[static_cast<std::size_t>(v)])
        blocked[static_cast<std::size_t>(colour)] = 1;
    }
    const std::size_t colour =
        static_cast<std::size_t>(std::find(blocked.begin(), blocked.end(), 0) - blocked.begin());
    if (colour == groups.size()) groups.emplace_back();
    groups[colour].push_back(static_cast<int>(c));
    for (int v : tuple)
      if (v >= 0) taken[static_cast<std::size_t>(v)].push_back(static_cast<int>(colour));
  }
  return groups;
}

}  // namespace clothdb
