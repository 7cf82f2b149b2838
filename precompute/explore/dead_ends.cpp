#include "explore/dead_ends.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace clothdb {

double weighted_priority(const ExploreGraph& graph, double error, int edge) {
  const double reach = graph.edges[static_cast<size_t>(edge)].reach;
  return error >= kNoNeighbour ? kNoNeighbour * (1 + reach) : error * reach;
}

std::vector<Job> dead_ends(const SecondaryGraph& sg, const ExploreGraph& graph,
                           int64_t min_state_id) {
  std::vector<Job> jobs;
  for (size_t s = 0; s < sg.states.size(); ++s) {
    if (sg.states[s].id < min_state_id) continue;
    for (int e : sg.out_edges[static_cast<size_t>(sg.states[s].node)])
      if (!sg.done.count({sg.states[s].id, e}))
        jobs.push_back(
            {static_cast<int>(s), e, weighted_priority(graph, sg.states[s].priority, e)});
  }
  std::sort(jobs.begin(), jobs.end(), [&](const Job& a, const Job& b) {
    if (a.priority != b.priority) return a.priority > b.priority;
    const int64_t ida = sg.states[static_cast<size_t>(a.state)].id,
                  idb = sg.states[static_cast<size_t>(b.state)].id;
    if (ida != idb) return ida < idb;
    return a.edge < b.edge;
  });
  return jobs;
}

std::vector<Job> choose_batch(const SecondaryGraph& sg, const FailedDeadEnds& failed,
                              const std::vector<Job>& queue, int size) {
  std::vector<Job> batch;
  for (const Job& j : queue) {
    if (static_cast<int>(batch.size()) >= size) break;
    if (failed.count({sg.states[static_cast<size_t>(j.state)].id, j.edge})) continue;
    batch.push_back(j);
  }
  return batch;
}

std::vector<db::ClothLink> link_dead_ends(SecondaryGraph& sg, const ExploreGraph& graph,
                                          int64_t run_id) {
  std::vector<db::ClothLink> links;
  const size_t n = sg.reducer.size();
  for (size_t node = 0; node < sg.states_at_node.size(); ++node) {
    const std::vector<int>& here = sg.states_at_node[node];
    for (int e : sg.out_edges[node]) {
      std::vector<int> with_clip;
      for (int s : here)
        if (sg.clip_of.count({sg.states[static_cast<size_t>(s)].id, e})) with_clip.push_back(s);
      if (with_clip.empty()) continue;
      for (int s : here) {
        const StateRec& from = sg.states[static_cast<size_t>(s)];
        if (sg.clip_of.count({from.id, e})) continue;
        const ExactStatePtr from_exact = sg.state(s);
        const PrunedNearest found = nearest_pruned(
            with_clip.size(),
            [&](size_t k) {
              return reduced_distance(from.reduced.data(),
                                      sg.states[static_cast<size_t>(with_clip[k])].reduced.data(),
                                      n);
            },
            [&](size_t k) {
              const ExactStatePtr to = sg.state(with_clip[k]);
              return db::state_distance(from_exact->x, from_exact->v, to->x, to->v, sg.tau);
            });
        sg.exact_evaluations += found.exact_evaluations;
        const int best_state = with_clip[static_cast<size_t>(std::max(0, found.k))];
        db::ClothLink link;
        link.from_state = from.id;
        link.primary_clip = graph.edges[static_cast<size_t>(e)].db_clip;
        link.to_clip = sg.clip_of.at({sg.states[static_cast<size_t>(best_state)].id, e});
        link.blend_error = std::isfinite(found.distance) ? found.distance : 1.0;
        link.run = run_id;
        links.push_back(link);
      }
    }
  }
  return links;
}

}  // namespace clothdb
