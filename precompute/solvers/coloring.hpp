// Greedy graph colouring of constraints for parallel Gauss-Seidel (Macklin 2016 sec. 5;
// Fratarcangeli et al. 2016 "Vivace"): constraints of one colour share no vertex, so they can be
// projected concurrently with the same result as any sequential order; colours are processed in a
// fixed order, which makes the solve deterministic whatever the thread count.
#pragma once

#include <array>
#include <span>
#include <vector>

namespace clothdb {

// Colours `count` constraints whose vertex indices are stored flat, `arity` per constraint
// (constraint c touches vertices[c * arity + k], k < arity). Negative indices are ignored (padding
// for mixed arities). Greedy in constraint order: each constraint takes the smallest colour that no
// earlier constraint sharing a vertex has, so the result is deterministic. Returns the colour
// groups, each listing constraint indices in increasing order; no two constraints in a group share
// a vertex. Throws std::invalid_argument if arity < 1 or vertices.size() is not a multiple of it.
std::vector<std::vector<int>> greedy_coloring(std::span<const int> vertices, int arity);

// Convenience for constraints stored as fixed-size tuples (edges, hinges as arrays).
template <std::size_t N>
std::vector<std::vector<int>> greedy_coloring(const std::vector<std::array<int, N>>& constraints) {
  return greedy_coloring(std::span<const int>(constraints.empty() ? nullptr : constraints[0].data(),
                                              constraints.size() * N),
                         static_cast<int>(N));
}

}  // namespace clothdb
