#include "explore/state_store.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
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

namespace {

// The block-constant part of a field of 6 x vertices doubles (vertex-major): each block's mean
// per channel, subtracted. What remains is orthogonal to every field the reduced form holds.
void remove_block_means(const StateReducer& reducer, double* f) {
  for (size_t b = 0; b + 1 < reducer.block_start.size(); ++b) {
    const uint32_t first = reducer.block_start[b], last = reducer.block_start[b + 1];
    for (size_t c = 0; c < 6; ++c) {
      double sum = 0;
      for (uint32_t i = first; i < last; ++i) sum += f[6 * size_t(i) + c];
      const double mean = sum / double(last - first);
      for (uint32_t i = first; i < last; ++i) f[6 * size_t(i) + c] -= mean;
    }
  }
}

// (x, tau v) / sqrt(N), vertex-major: the state distance is the Euclidean distance of these.
void weighted_state(const StateReducer& reducer, const float* x, const float* v, double* y) {
  const double w = 1 / std::sqrt(double(reducer.vertices));
  for (size_t i = 0; i < reducer.vertices; ++i)
    for (size_t c = 0; c < 3; ++c) {
      y[6 * i + c] = w * double(x[3 * i + c]);
      y[6 * i + 3 + c] = w * (reducer.tau * double(v[3 * i + c]));
    }
}

// Four partial sums (what lets the compiler use vector registers); the rounding bound of
// project() holds for any order of summation.
double dot(const double* a, const double* b, size_t n) {
  double s[4] = {0, 0, 0, 0};
  size_t i = 0;
  for (; i + 4 <= n; i += 4)
    for (size_t l = 0; l < 4; ++l) s[l] += a[i + l] * b[i + l];
  for (; i < n; ++i) s[0] += a[i] * b[i];
  return (s[0] + s[1]) + (s[2] + s[3]);
}

}  // namespace

MotionBasis build_motion_basis(const StateReducer& reducer,
                               const std::vector<const ExactState*>& sample,
                               const std::vector<int>& group, size_t modes) {
  MotionBasis mb;
  mb.vertices = reducer.vertices;
  mb.tau = reducer.tau;
  const size_t dim = 6 * size_t(reducer.vertices);
  if (dim == 0 || sample.size() < 2 || modes == 0) return mb;
  std::vector<std::vector<double>> y(sample.size(), std::vector<double>(dim));
  for (size_t s = 0; s < sample.size(); ++s)
    weighted_state(reducer, sample[s]->x.data(), sample[s]->v.data(), y[s].data());
  // Deviations from the mean of their own node: what tells states at one node apart.
  std::map<int, std::vector<size_t>> members;
  for (size_t s = 0; s < sample.size(); ++s) members[group[s]].push_back(s);
  std::vector<std::vector<double>> dev;
  for (const auto& [node, at] : members) {
    if (at.size() < 2) continue;
    std::vector<double> mean(dim, 0.0);
    for (size_t s : at)
      for (size_t i = 0; i < dim; ++i) mean[i] += y[s][i];
    for (double& m : mean) m /= double(at.size());
    for (size_t s : at) {
      dev.emplace_back(dim);
      for (size_t i = 0; i < dim; ++i) dev.back()[i] = y[s][i] - mean[i];
      remove_block_means(reducer, dev.back().data());
    }
  }
  if (dev.size() < 2) return mb;
  // The leading principal directions of the deviations, from their Gram matrix (a few dozen
  // deviations of thousands of doubles each).
  const size_t m = dev.size();
  Eigen::MatrixXd gram(m, m);
  for (size_t a = 0; a < m; ++a)
    for (size_t b = 0; b <= a; ++b)
      gram(a, b) = gram(b, a) = dot(dev[a].data(), dev[b].data(), dim);
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(gram);
  const Eigen::VectorXd& lambda = eig.eigenvalues();  // ascending
  std::vector<std::vector<double>> q;
  for (size_t j = 0; j < m && q.size() < modes; ++j) {
    const Eigen::Index e = Eigen::Index(m - 1 - j);
    if (!(lambda(e) > 1e-12 * lambda(Eigen::Index(m - 1)))) break;
    std::vector<double> mode(dim, 0.0);
    for (size_t a = 0; a < m; ++a) {
      const double w = eig.eigenvectors()(Eigen::Index(a), e);
      for (size_t i = 0; i < dim; ++i) mode[i] += w * dev[a][i];
    }
    // Orthogonal to the block fields and to the modes before (twice: Gram-Schmidt, then again
    // for what rounding left), unit length; dropped when little of it is new.
    const double before = std::sqrt(dot(mode.data(), mode.data(), dim));
    for (int pass = 0; pass < 2; ++pass) {
      remove_block_means(reducer, mode.data());
      for (const auto& p : q) {
        const double c = dot(mode.data(), p.data(), dim);
        for (size_t i = 0; i < dim; ++i) mode[i] -= c * p[i];
      }
    }
    const double norm = std::sqrt(dot(mode.data(), mode.data(), dim));
    if (!(norm > 1e-6 * before)) continue;
    for (double& f : mode) f /= norm;
    q.push_back(std::move(mode));
  }
  if (q.empty()) return mb;
  // delta >= |M^T M - I|_2 for M = [B Q], B the block fields (orthonormal by construction):
  // |M^T M - I|_F = sqrt(|Q^T Q - I|_F^2 + 2 |Q^T B|_F^2), plus a margin for computing it.
  double e2 = 0, f2 = 0, qmax = 0;
  for (size_t a = 0; a < q.size(); ++a) {
    for (size_t b = 0; b < q.size(); ++b) {
      const double g = dot(q[a].data(), q[b].data(), dim) - (a == b ? 1.0 : 0.0);
      e2 += g * g;
    }
    qmax = std::max(qmax, std::sqrt(dot(q[a].data(), q[a].data(), dim)));
    for (size_t b = 0; b + 1 < reducer.block_start.size(); ++b) {
      const uint32_t first = reducer.block_start[b], last = reducer.block_start[b + 1];
      for (size_t c = 0; c < 6; ++c) {
        double sum = 0;
        for (uint32_t i = first; i < last; ++i) sum += q[a][6 * size_t(i) + c];
        const double f = sum / std::sqrt(double(last - first));
        f2 += f * f;
      }
    }
  }
  const double delta = std::sqrt(e2 + 2 * f2) + 1e-12;
  mb.inflation = std::sqrt(1 + delta);
  mb.modes = q.size();
  mb.ref.assign(dim, 0.0);
  for (const auto& ys : y)
    for (size_t i = 0; i < dim; ++i) mb.ref[i] += ys[i];
  for (double& r : mb.ref) r /= double(y.size());
  mb.q.reserve(mb.modes * dim);
  for (const auto& p : q) mb.q.insert(mb.q.end(), p.begin(), p.end());
  // A coefficient sum_i q_i (y_i - ref_i) of dim terms: y_i is rounded (1/sqrt(N), the products:
  // 4 roundings), then the difference, the product and the sum (Higham's gamma_n): its error is
  // at most gamma_{dim+6} sum_i |q_i| (|y_i| + |ref_i|) <= gamma_{dim+6} |q| (|y| + |ref|); over
  // the modes, sqrt(modes) times the largest. 1 % more for computing |y| and |ref|.
  const double u = std::ldexp(1.0, -53), n = double(dim + 6);
  const double gamma = n * u / (1 - n * u);
  mb.slack_per_norm = 1.01 * std::sqrt(double(mb.modes)) * gamma * qmax;
  return mb;
}

Projection project(const MotionBasis& basis, const float* x, const float* v) {
  Projection p;
  if (basis.modes == 0) return p;
  const size_t dim = 6 * size_t(basis.vertices);
  std::vector<double> y(dim);
  StateReducer shape;  // weighted_state needs only vertices and tau
  shape.vertices = basis.vertices;
  shape.tau = basis.tau;
  weighted_state(shape, x, v, y.data());
  const double y_norm = std::sqrt(dot(y.data(), y.data(), dim));
  const double ref_norm = std::sqrt(dot(basis.ref.data(), basis.ref.data(), dim));
  for (size_t i = 0; i < dim; ++i) y[i] -= basis.ref[i];
  p.c.resize(basis.modes);
  for (size_t j = 0; j < basis.modes; ++j) p.c[j] = dot(&basis.q[j * dim], y.data(), dim);
  p.slack = basis.slack_per_norm * (y_norm + ref_norm);
  return p;
}

double motion_bound(const MotionBasis& basis, double reduced, const Projection& a,
                    const Projection& b) {
  if (basis.modes == 0 || a.c.size() != basis.modes || b.c.size() != basis.modes) return reduced;
  // |Q^T d| >= |computed difference| - both rounding errors (the triangle inequality).
  const double projected =
      std::max(0.0, reduced_distance(a.c.data(), b.c.data(), basis.modes) - a.slack - b.slack);
  return std::sqrt(reduced * reduced + projected * projected) / basis.inflation;
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
