#include "explore/state_store.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace clothdb {

StateReducer make_reducer(uint32_t vertices, double tau) {
  StateReducer r;
  r.vertices = vertices;
  r.tau = tau;
  if (vertices == 0) return r;
  const uint32_t blocks = std::max(1u, std::min(kReducedBlocks, vertices / kMinBlockVertices));
  // Consecutive vertices: the garments' meshes number vertices row by row, so a block is a band
  // of cloth that tends to move together (the bound is tightest when a block moves rigidly).
  for (uint32_t b = 0; b <= blocks; ++b)
    r.block_start.push_back(static_cast<uint32_t>(uint64_t(vertices) * b / blocks));
  return r;
}

std::vector<double> reduce(const StateReducer& reducer, const float* x, const float* v) {
  std::vector<double> out(reducer.size());
  for (size_t b = 0; b + 1 < reducer.block_start.size(); ++b) {
    const uint32_t first = reducer.block_start[b], last = reducer.block_start[b + 1];
    double sum[6] = {0, 0, 0, 0, 0, 0};
    for (uint32_t i = first; i < last; ++i)
      for (int c = 0; c < 3; ++c) {
        sum[c] += double(x[3 * size_t(i) + c]);
        sum[3 + c] += reducer.tau * double(v[3 * size_t(i) + c]);
      }
    const double m = double(last - first);
    // sqrt(m / N) x the mean: the projection onto block-constant fields, in the distance's
    // normalisation (RMS over N vertices).
    const double weight = std::sqrt(m / double(reducer.vertices)) / m;
    for (int c = 0; c < 6; ++c) out[6 * b + size_t(c)] = weight * sum[c];
  }
  return out;
}

double reduced_distance(const double* a, const double* b, size_t n) {
  double sum = 0;
  for (size_t i = 0; i < n; ++i) sum += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(sum);
}

PrunedNearest nearest_pruned(size_t n, const std::function<double(size_t)>& lower_bound,
                             const std::function<double(size_t)>& exact) {
  PrunedNearest out;
  if (n == 0) return out;
  std::vector<std::pair<double, size_t>> order(n);
  for (size_t k = 0; k < n; ++k) order[k] = {lower_bound(k), k};
  std::sort(order.begin(), order.end());
  double best = std::numeric_limits<double>::infinity();
  size_t best_k = 0;
  bool found = false;
  for (const auto& [bound, k] : order) {
    // Every later candidate has a bound at least this one: none can be nearer, nor tie.
    if (found && bound_exceeds(bound, best)) break;
    const double d = exact(k);
    ++out.exact_evaluations;
    if (!found || d < best || (d == best && k < best_k)) {
      best = d, best_k = k, found = true;
    }
  }
  out.k = static_cast<int>(best_k);
  out.distance = best;
  return out;
}

StateCache::StateCache(size_t capacity_bytes, Read read, ReadBlobs read_blobs)
    : capacity_(capacity_bytes), read_(std::move(read)), read_blobs_(std::move(read_blobs)) {}

ExactStatePtr StateCache::track(ExactState state) {
  const size_t bytes = (state.x.size() + state.v.size()) * sizeof(float);
  {
    std::lock_guard<std::mutex> lock(counter_->mutex);
    counter_->alive += bytes;
    counter_->peak = std::max(counter_->peak, counter_->alive);
  }
  // The counter outlives the cache if a caller still holds a state: the deleter shares it.
  std::shared_ptr<Counter> counter = counter_;
  return ExactStatePtr(new ExactState(std::move(state)), [counter, bytes](const ExactState* s) {
    {
      std::lock_guard<std::mutex> lock(counter->mutex);
      counter->alive -= bytes;
    }
    delete s;
  });
}

void StateCache::insert(int64_t id, const ExactStatePtr& state) {
  const size_t bytes = (state->x.size() + state->v.size()) * sizeof(float);
  lru_.emplace_front(id, state);
  where_[id] = lru_.begin();
  cached_ += bytes;
  while (cached_ > capacity_ && !lru_.empty()) {
    const auto& last = lru_.back();
    cached_ -= (last.second->x.size() + last.second->v.size()) * sizeof(float);
    where_.erase(last.first);
    lru_.pop_back();
  }
}

ExactStatePtr StateCache::get(int64_t id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto found = where_.find(id);
  if (found != where_.end()) {
    ++hits_;
    lru_.splice(lru_.begin(), lru_, found->second);
    return found->second->second;
  }
  ++reads_;
  ExactStatePtr state = track(read_(id));
  insert(id, state);
  return state;
}

ExactStatePtr StateCache::put(int64_t id, ExactState state) {
  std::lock_guard<std::mutex> lock(mutex_);
  ExactStatePtr tracked = track(std::move(state));
  const auto found = where_.find(id);
  if (found != where_.end()) {
    cached_ -= (found->second->second->x.size() + found->second->second->v.size()) * sizeof(float);
    lru_.erase(found->second);
    where_.erase(found);
  }
  insert(id, tracked);
  return tracked;
}

StateBlobs StateCache::blobs(int64_t id) {
  std::lock_guard<std::mutex> lock(mutex_);
  return read_blobs_ ? read_blobs_(id) : StateBlobs{};
}

void StateCache::erase(int64_t id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto found = where_.find(id);
  if (found == where_.end()) return;
  cached_ -= (found->second->second->x.size() + found->second->second->v.size()) * sizeof(float);
  lru_.erase(found->second);
  where_.erase(found);
}

StateCache::Stats StateCache::stats() const {
  Stats s;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    s.capacity = capacity_;
    s.cached_bytes = cached_;
    s.reads = reads_;
    s.hits = hits_;
  }
  std::lock_guard<std::mutex> lock(counter_->mutex);
  s.alive_bytes = counter_->alive;
  s.peak_alive_bytes = counter_->peak;
  return s;
}

}  // namespace clothdb
