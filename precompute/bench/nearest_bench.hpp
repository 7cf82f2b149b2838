// `clothdb bench nearest`: the explorer's nearest-state search and its priority updates
// (explore/secondary_graph.hpp) with early exit, the coarse bound first and the motion basis
// against the reduced bound alone, on a file's states replayed in the order a resume adds them, or
// on a synthetic clustered set at one node. All give the same answers (checked, every query and
// every priority); the figures are CPU time and state distances measured. (The pivot table it also
// measured until 2026-12-04 is gone: docs/notebook/explorer.md, "The pivots removed".)
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

namespace clothdb {

struct NearestBenchSide {
  double cpu_seconds = 0;  // this thread's, adding every state (nearest_state + add_state)
  long exact_evaluations = 0;
};

struct NearestBenchResult {
  size_t states = 0, nodes = 0, largest_node = 0;
  uint32_t vertices = 0;
  // The search as it was (every candidate's reduced bound, sorted; every distance summed to its
  // end), then adding one by one: early exit, the coarse bound first (a heap; both: what the
  // explorer runs).
  NearestBenchSide reduced_only, early_exit, coarse;
  // And the motion basis's bound (explore/state_store.hpp) on top: what the explorer runs.
  NearestBenchSide motion;
  size_t motion_modes = 0;
  bool identical = false;  // same nearest state, distance and priority for every state, all four
};

// The file's states (cloth_state, in id order, at the node their anchor clip names), decoded
// first; the timing covers the search only. Throws std::runtime_error naming the file.
NearestBenchResult bench_nearest_file(const std::string& path, size_t motion_modes);

// n states of `vertices` vertices at one node in `clusters` clusters, each state its cluster's
// centre moved by smooth modes that block means see and by modes they do not (a node whose
// states cluster closer than the reduced form resolves), some exact duplicates (ties).
NearestBenchResult bench_nearest_synthetic(size_t n, uint32_t vertices, int clusters, uint32_t seed,
                                           size_t motion_modes);

}  // namespace clothdb
