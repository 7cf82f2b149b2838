#include "bench/nearest_bench.hpp"

#include <time.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <random>
#include <stdexcept>
#include <vector>

#include "database/codec/codec.hpp"
#include "database/format/reader.hpp"
#include "explore/secondary_graph.hpp"

namespace clothdb {

namespace {

struct StateSet {
  double tau = 0;
  int nodes = 0;
  std::vector<int> node;  // per state
  std::vector<ExactState> exact;
};

double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

struct Answers {
  std::vector<int> nearest;
  std::vector<double> distance, priority;
};

// Adds every state as the explorer and a resume do (nearest_state, then add_state).
Answers replay(const StateSet& set, bool early_exit, bool coarse_first, size_t motion_modes,
               NearestBenchSide* side) {
  SecondaryGraph sg;
  sg.tau = set.tau;
  sg.out_edges.assign(size_t(set.nodes), {});
  sg.states_at_node.assign(size_t(set.nodes), {});
  const uint32_t vertices = static_cast<uint32_t>(set.exact.front().x.size() / 3);
  sg.reducer = make_reducer(vertices, sg.tau);
  sg.early_exit = early_exit;
  sg.coarse_first = coarse_first;
  sg.motion_modes = motion_modes;
  // Every state stays cached: the figure is the search's, not the file's reads.
  const StateSet* from = &set;
  sg.exact = std::make_shared<StateCache>(
      size_t(-1), [from](int64_t id) { return from->exact[size_t(id - 1)]; });
  Answers a;
  const double t0 = thread_cpu_seconds();
  for (size_t s = 0; s < set.exact.size(); ++s) {
    const ExactState& e = set.exact[s];
    const Nearest found = nearest_state(sg, set.node[s], e.x, e.v);
    a.nearest.push_back(found.state);
    a.distance.push_back(found.distance);
    StateRec rec;
    rec.id = int64_t(s) + 1;
    rec.node = set.node[s];
    add_state(sg, std::move(rec), e, found);
  }
  side->cpu_seconds = thread_cpu_seconds() - t0;
  side->exact_evaluations = sg.exact_evaluations;
  for (const StateRec& r : sg.states) a.priority.push_back(r.priority);
  return a;
}

NearestBenchResult run(const StateSet& set, size_t motion_modes) {
  if (set.exact.empty()) throw std::runtime_error("bench nearest: no states");
  NearestBenchResult r;
  r.states = set.exact.size();
  r.vertices = static_cast<uint32_t>(set.exact.front().x.size() / 3);
  std::vector<size_t> per_node(size_t(set.nodes), 0);
  for (int n : set.node) ++per_node[size_t(n)];
  r.nodes = size_t(std::count_if(per_node.begin(), per_node.end(), [](size_t k) { return k > 0; }));
  r.largest_node = *std::max_element(per_node.begin(), per_node.end());
  r.motion_modes = motion_modes;
  const Answers old = replay(set, false, false, 0, &r.reduced_only);
  const Answers early = replay(set, true, false, 0, &r.early_exit);
  const Answers coarse = replay(set, true, true, 0, &r.coarse);
  const Answers motion = replay(set, true, true, motion_modes, &r.motion);
  auto same = [](const Answers& a, const Answers& b) {
    return a.nearest == b.nearest && a.distance == b.distance && a.priority == b.priority;
  };
  r.identical = same(old, early) && same(old, coarse) && same(old, motion);
  return r;
}

}  // namespace

NearestBenchResult bench_nearest_file(const std::string& path, size_t motion_modes) {
  db::Reader reader;
  db::Error err;
  std::vector<db::StoredState> states;
  std::vector<db::PrimaryClip> clips;
  if (reader.open(path, &err) != db::Status::Ok ||
      reader.cloth_states(&states, &err) != db::Status::Ok ||
      reader.primary_clips(&clips, &err) != db::Status::Ok)
    // The reader's messages name the file; said once.
    throw std::runtime_error(std::string(err.message).find(path) == std::string::npos
                                 ? path + ": " + err.message
                                 : std::string(err.message));
  if (clips.empty() || states.empty())
    throw std::runtime_error(path + ": no primary clips or no cloth states to search");
  std::sort(states.begin(), states.end(),
            [](const db::StoredState& a, const db::StoredState& b) { return a.id < b.id; });
  StateSet set;
  set.tau = 1.0 / clips.front().frame_rate;
  // A state's node is named by the anchor clip it is stored under (the node-anchor rule).
  std::map<int64_t, int> node_of;
  codec::DecodeScratch scratch;
  for (const db::StoredState& s : states) {
    const auto found = node_of.emplace(s.primary_clip, int(node_of.size()));
    set.node.push_back(found.first->second);
    ExactState e;
    if (reader.read_state(s.id, &e.x, &e.v, scratch, &err) != db::Status::Ok)
      throw std::runtime_error(path + ": cloth state " + std::to_string(s.id) + ": " +
                               std::string(err.message));
    set.exact.push_back(std::move(e));
  }
  set.nodes = int(node_of.size());
  return run(set, motion_modes);
}

NearestBenchResult bench_nearest_synthetic(size_t n, uint32_t vertices, int clusters, uint32_t seed,
                                           size_t motion_modes) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  StateSet set;
  set.tau = 1.0 / 30;
  set.nodes = 1;
  std::vector<std::vector<float>> centre(size_t(std::max(1, clusters)),
                                         std::vector<float>(3 * vertices));
  for (auto& c : centre)
    for (float& f : c) f = 0.05f * noise(rng);
  for (size_t s = 0; s < n; ++s) {
    set.node.push_back(0);
    if (s > 3 && s % 29 == 0) {  // a duplicate: a tie
      set.exact.push_back(set.exact[s / 3]);
      continue;
    }
    ExactState e;
    e.x = centre[s % centre.size()];
    e.v.assign(3 * vertices, 0.0f);
    for (int m = 0; m < 6; ++m) {
      // Modes 0-2 are smooth over the garment (block means see them), 3-5 alternate between
      // neighbouring vertices (zero mean over every block: only exact distances see them).
      const float a = (m < 3 ? 0.001f : 0.004f) * noise(rng), b = 0.02f * noise(rng);
      for (uint32_t i = 0; i < vertices; ++i) {
        const float wave = std::cos(0.05f * float(m % 3 + 1) * float(i / 2));
        const float sign = m < 3 || i % 2 == 0 ? 1.0f : -1.0f;
        e.x[3 * i + size_t(m % 3)] += sign * a * wave;
        e.v[3 * i + size_t(m % 3)] += sign * b * wave;
      }
    }
    for (float& f : e.x) f += 0.0002f * noise(rng);
    set.exact.push_back(std::move(e));
  }
  return run(set, motion_modes);
}

}  // namespace clothdb
