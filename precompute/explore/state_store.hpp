// The explorer's memory-bounded state store (docs/notebook/explorer.md, "Memory per state").
//
// Kim et al. 2013's query (the nearest cloth state at a node, in the state distance of
// database/format/cloth_graph.hpp) needs every state's positions and velocities: 24 bytes per
// vertex per state, 2.9 GB for 10,000 states of a 12,000-vertex garment. The explorer keeps
// instead, per state, a reduced form of kReducedBlocks x 6 doubles and reads exact states back
// from the database through an LRU cache of a fixed capacity, only for near candidates.
//
// The reduced form is the mean of (x, tau v) over each of B blocks of consecutive vertices,
// weighted by sqrt(block size / vertices). It is an orthogonal projection of the state, so the
// Euclidean distance between two reduced forms is a true lower bound of the state distance
// (Cauchy-Schwarz: a block's sum of squared differences is at least its size times the squared
// difference of its means). A candidate is read and measured only when that bound does not
// already exceed the best distance found: the answer is the exact search's, ties included.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace clothdb {

// Blocks of the reduced form: at most this many, and at least kMinBlockVertices vertices each
// (so the reduced form of a small garment stays smaller than the garment).
inline constexpr uint32_t kReducedBlocks = 16;
inline constexpr uint32_t kMinBlockVertices = 8;

struct StateReducer {
  uint32_t vertices = 0;
  double tau = 0;                     // s: the state distance's velocity weight
  std::vector<uint32_t> block_start;  // blocks + 1 entries, the last = vertices
  size_t size() const { return 6 * (block_start.empty() ? 0 : block_start.size() - 1); }
};

StateReducer make_reducer(uint32_t vertices, double tau);

// The reduced form of a state (character space, 3 floats a vertex each).
std::vector<double> reduce(const StateReducer& reducer, const float* x, const float* v);

// Euclidean distance of two reduced forms of `n` doubles: at most the states' distance.
double reduced_distance(const double* a, const double* b, size_t n);

// True when `bound` (a reduced_distance) proves that the state distance exceeds `best`: with a
// margin of 1e-9 relative for the rounding of both sums, so pruning never changes the answer.
inline bool bound_exceeds(double bound, double best) {
  return bound > best * (1 + 1e-9);
}

// The nearest of n candidates to a query by the state distance, ties to the lower k (the order
// of the candidates). lower_bound(k) must be at most exact(k); exact(k) is called only for
// candidates whose bound does not exceed the best exact distance found so far, in order of
// their bound. k = -1 when n = 0.
struct PrunedNearest {
  int k = -1;
  double distance = 0;
  long exact_evaluations = 0;
};
PrunedNearest nearest_pruned(size_t n, const std::function<double(size_t)>& lower_bound,
                             const std::function<double(size_t)>& exact);

struct ExactState {
  std::vector<float> x, v;  // character space, as stored (decoded)
};

// A basis adapted to the garment's motion (docs/notebook/explorer.md, "The motion basis"): the
// principal directions of how states at one node differ from each other, pooled over the nodes,
// taken orthogonal to the block-constant fields the reduced form already holds. With M = [B Q]
// (B: the block-constant fields, Q: these modes), |B^T d|^2 + |Q^T d|^2 <= (1 + delta) |d|^2 for
// every difference d of two states (delta: how far the computed M^T M is from the identity,
// measured when it is built), so sqrt(reduced^2 + projected^2) / sqrt(1 + delta) is a lower bound
// of the state distance like the reduced distance alone, but tight where the states at a node
// vary in a few modes. Rounding of the coefficients is bounded per state (Projection::slack).
struct MotionBasis {
  uint32_t vertices = 0;
  double tau = 0;
  size_t modes = 0;         // 0: no basis (the bound is the reduced distance alone)
  std::vector<double> ref;  // 6 x vertices: the sample's mean, (x, tau v) / sqrt(vertices) a vertex
  std::vector<double> q;    // modes x 6 x vertices, row by row
  double inflation = 1;     // sqrt(1 + delta)
  double slack_per_norm = 0;  // a coefficient vector's rounding error per unit of |y| + |ref|
};

// The basis of at most `modes` modes from sample states grouped by `group` (their node): the
// deviations from their group's mean (groups of one say nothing), block-constant fields removed,
// their leading principal directions (Gram matrix, Eigen's self-adjoint solver), orthonormalised
// twice. modes = 0 when the sample has no deviation.
MotionBasis build_motion_basis(const StateReducer& reducer,
                               const std::vector<const ExactState*>& sample,
                               const std::vector<int>& group, size_t modes);

// A state's coefficients in the basis (of (x, tau v)/sqrt(N) - ref) and a bound of their
// rounding error: |computed - exact| <= slack (as a vector, Euclidean).
struct Projection {
  std::vector<double> c;
  double slack = 0;
};
Projection project(const MotionBasis& basis, const float* x, const float* v);

// The lower bound of the state distance from the reduced distance of two states (reduced_distance)
// and their projections: at most their state distance.
double motion_bound(const MotionBasis& basis, double reduced, const Projection& a,
                    const Projection& b);
using ExactStatePtr = std::shared_ptr<const ExactState>;

// A state as the file stores it: its two one-frame blobs (database/format/reader.hpp state_blobs).
// Decoding them gives the ExactState bit for bit; they are 3-4x smaller, which is what the MPI job
// messages send a worker (explore/job_wire.hpp).
struct StateBlobs {
  std::vector<uint8_t> x, v;
};

// An LRU cache of exact states of a fixed capacity in bytes, reading a state it does not hold
// through `read` (the database). Thread-safe: jobs read steering targets from worker threads,
// and `read` is called under the cache's lock (one reader connection at a time).
class StateCache {
 public:
  using Read = std::function<ExactState(int64_t id)>;
  using ReadBlobs = std::function<StateBlobs(int64_t id)>;
  // read_blobs (optional): the state's stored blobs, read under the same lock as `read` (one reader
  // connection for both).
  StateCache(size_t capacity_bytes, Read read, ReadBlobs read_blobs = {});
  ExactStatePtr get(int64_t id);
  // A state the caller already has (just decoded): cached without a read.
  ExactStatePtr put(int64_t id, ExactState state);
  // The state's stored blobs, never cached; empty when the cache was made without read_blobs.
  StateBlobs blobs(int64_t id);
  // Forgets a state (an MPI worker's replica drops what rank 0 says it dropped); no-op if absent.
  void erase(int64_t id);

  // Bytes of exact states alive: those the cache holds plus those callers still hold after
  // their eviction. The bound (docs/notebook/explorer.md): capacity plus a few states per
  // thread in flight.
  struct Stats {
    size_t capacity = 0, cached_bytes = 0;
    size_t alive_bytes = 0, peak_alive_bytes = 0;
    long reads = 0, hits = 0;
  };
  Stats stats() const;

 private:
  ExactStatePtr track(ExactState state);  // counts its bytes while it is alive
  void insert(int64_t id, const ExactStatePtr& state);

  struct Counter {
    std::mutex mutex;
    size_t alive = 0, peak = 0;
  };
  mutable std::mutex mutex_;
  size_t capacity_;
  Read read_;
  ReadBlobs read_blobs_;
  std::list<std::pair<int64_t, ExactStatePtr>> lru_;  // most recent first
  std::unordered_map<int64_t, std::list<std::pair<int64_t, ExactStatePtr>>::iterator> where_;
  size_t cached_ = 0;
  long reads_ = 0, hits_ = 0;
  std::shared_ptr<Counter> counter_ = std::make_shared<Counter>();
};

// Bytes one exact state of `vertices` vertices takes (positions and velocities as floats).
inline size_t exact_state_bytes(uint32_t vertices) {
  return 24 * size_t(vertices);
}

}  // namespace clothdb
