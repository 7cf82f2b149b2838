// The explorer's state store (precompute/explore/state_store.hpp): the reduced form is a true lower
// bound of the state distance, the pruned nearest search returns exactly what brute force returns
// (ties included), the LRU cache of exact states stays within its capacity, and an exploration of
// thousands of states on a small garment keeps the store within its bound, gives the same file for
// 1 and 2 threads, and resumes after a SIGKILL to the file of an uninterrupted run.
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <random>
#include <thread>

#include "database/format/cloth_graph.hpp"
#include "explore/secondary_graph.hpp"
#include "explore/state_store.hpp"
#include "support/db_rows.hpp"
#include "support/explore_fixture.hpp"
#include "support/temp_dir.hpp"

using namespace clothdb;
using namespace clothdb::test;

namespace {

struct Cloud {
  std::vector<std::vector<float>> x, v;
};

// n states of `vertices` vertices in a few clusters (as states at a node are: near each other,
// with outliers), and some exact duplicates (ties).
Cloud cloud(size_t n, uint32_t vertices, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  Cloud c;
  std::vector<std::vector<float>> centres(4, std::vector<float>(3 * vertices));
  for (auto& centre : centres)
    for (float& f : centre) f = 0.05f * noise(rng);
  for (size_t s = 0; s < n; ++s) {
    if (s > 3 && s % 17 == 0) {  // a duplicate of an earlier state: a tie
      c.x.push_back(c.x[s / 2]);
      c.v.push_back(c.v[s / 2]);
      continue;
    }
    const std::vector<float>& centre = centres[s % centres.size()];
    std::vector<float> x(3 * vertices), v(3 * vertices);
    // Cloth moves in smooth waves: a few low-frequency modes of random amplitude, and a little
    // noise of the vertex's own.
    const float spread = (s % 5 == 0) ? 0.02f : 0.005f;
    float a[3], b[3];
    for (int m = 0; m < 3; ++m) a[m] = spread * noise(rng), b[m] = spread * noise(rng);
    for (size_t i = 0; i < x.size(); ++i) {
      const float t = float(i / 3) / float(vertices);
      float wave = 0, wave_v = 0;
      for (int m = 0; m < 3; ++m) {
        wave += a[m] * std::cos(3.14159f * float(m) * t);
        wave_v += b[m] * std::cos(3.14159f * float(m) * t);
      }
      x[i] = centre[i] + wave + 0.05f * spread * noise(rng);
      v[i] = 10 * wave_v + 0.5f * spread * noise(rng);
    }
    c.x.push_back(std::move(x));
    c.v.push_back(std::move(v));
  }
  return c;
}

}  // namespace

TEST(StateStore, ReducedDistanceIsALowerBoundOfTheStateDistance) {
  for (uint32_t vertices : {1u, 7u, 36u, 200u, 1001u}) {
    const Cloud c = cloud(40, vertices, vertices);
    const StateReducer reducer = make_reducer(vertices, 1.0 / 30);
    EXPECT_LE(reducer.size(), 6 * size_t(kReducedBlocks));
    std::vector<std::vector<double>> r;
    for (size_t s = 0; s < c.x.size(); ++s)
      r.push_back(reduce(reducer, c.x[s].data(), c.v[s].data()));
    for (size_t a = 0; a < c.x.size(); ++a)
      for (size_t b = 0; b < c.x.size(); ++b) {
        const double d = db::state_distance(c.x[a], c.v[a], c.x[b], c.v[b], reducer.tau);
        const double lb = reduced_distance(r[a].data(), r[b].data(), reducer.size());
        EXPECT_FALSE(bound_exceeds(lb, d)) << vertices << " vertices, states " << a << ", " << b;
      }
  }
  // Not vacuous: a rigid shift of the whole garment is all in its block means (bound = distance).
  const uint32_t vertices = 64;
  const StateReducer reducer = make_reducer(vertices, 1.0 / 30);
  std::vector<float> x(3 * vertices, 0.0f), y(3 * vertices, 0.0f), v(3 * vertices, 0.0f);
  for (uint32_t i = 0; i < vertices; ++i) x[3 * i] = 0.01f * float(i), y[3 * i] = x[3 * i] + 0.003f;
  const std::vector<double> rx = reduce(reducer, x.data(), v.data()),
                            ry = reduce(reducer, y.data(), v.data());
  EXPECT_NEAR(reduced_distance(rx.data(), ry.data(), reducer.size()),
              db::state_distance(x, v, y, v, reducer.tau), 1e-9);
}

TEST(StateStore, PrunedNearestIsBruteForceTiesIncluded) {
  const uint32_t vertices = 120;
  // 400 states at a node, and 60 new states of the same clusters to look up.
  Cloud c = cloud(460, vertices, 7), queries;
  queries.x.assign(c.x.begin() + 400, c.x.end());
  queries.v.assign(c.v.begin() + 400, c.v.end());
  c.x.resize(400);
  c.v.resize(400);
  const StateReducer reducer = make_reducer(vertices, 1.0 / 30);
  std::vector<std::vector<double>> r;
  for (size_t s = 0; s < c.x.size(); ++s)
    r.push_back(reduce(reducer, c.x[s].data(), c.v[s].data()));
  long exact_total = 0;
  for (size_t q = 0; q < queries.x.size() + 20; ++q) {
    // Queries: new states, and states of the set itself (distance 0, and ties with duplicates).
    const std::vector<float>& qx = q < queries.x.size() ? queries.x[q] : c.x[(q * 37) % c.x.size()];
    const std::vector<float>& qv = q < queries.x.size() ? queries.v[q] : c.v[(q * 37) % c.x.size()];
    int brute = -1;
    double best = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < c.x.size(); ++k) {
      const double d = db::state_distance(qx, qv, c.x[k], c.v[k], reducer.tau);
      if (d < best) best = d, brute = int(k);
    }
    const std::vector<double> rq = reduce(reducer, qx.data(), qv.data());
    const PrunedNearest found = nearest_pruned(
        c.x.size(), [&](size_t k) { return reduced_distance(rq.data(), r[k].data(), rq.size()); },
        [&](size_t k) { return db::state_distance(qx, qv, c.x[k], c.v[k], reducer.tau); });
    EXPECT_EQ(found.k, brute) << "query " << q;
    EXPECT_EQ(found.distance, best) << "query " << q;
    exact_total += found.exact_evaluations;
  }
  // Not vacuous: the bound rules out most states (brute force measures 400 per query).
  EXPECT_LT(exact_total, long(80 * 400 / 2));
  EXPECT_EQ(nearest_pruned(0, {}, {}).k, -1);
}

TEST(StateStore, CacheStaysWithinItsCapacityAndReadsBackWhatItEvicted) {
  const uint32_t vertices = 50;
  const size_t state_bytes = exact_state_bytes(vertices);
  long reads = 0;
  StateCache cache(3 * state_bytes, [&](int64_t id) {
    ++reads;
    ExactState s;
    s.x.assign(3 * vertices, float(id));
    s.v.assign(3 * vertices, -float(id));
    return s;
  });
  for (int round = 0; round < 3; ++round)
    for (int64_t id = 1; id <= 10; ++id) {
      const ExactStatePtr s = cache.get(id);
      ASSERT_EQ(s->x.front(), float(id));
      ASSERT_EQ(s->v.back(), -float(id));
      EXPECT_LE(cache.stats().cached_bytes, 3 * state_bytes);
    }
  EXPECT_EQ(reads, 30);  // 10 states cycled through 3 places: every get is a read (LRU)
  (void)cache.get(10);
  EXPECT_EQ(reads, 30);  // the most recent is still there
  const StateCache::Stats stats = cache.stats();
  EXPECT_EQ(stats.hits, 1);
  // Alive: what the cache holds plus the one state a caller held at a time.
  EXPECT_LE(stats.peak_alive_bytes, 4 * state_bytes);
  EXPECT_EQ(stats.alive_bytes, 3 * state_bytes);
  // put() of a state it holds replaces it without growing.
  (void)cache.put(10, ExactState{std::vector<float>(3 * vertices, 5.0f),
                                 std::vector<float>(3 * vertices, 5.0f)});
  EXPECT_EQ(cache.get(10)->x.front(), 5.0f);
  EXPECT_LE(cache.stats().cached_bytes, 3 * state_bytes);
}

namespace {

// The scale test's budget: frames for the whole file (explore_run counts what a killed run
// stored), enough for more than 5,000 states at the fixture's epsilon of 1 um.
constexpr long kTotalFrames = 31500;
// A cache smaller than the states (about a quarter of them): the store must read states back.
constexpr size_t kCacheBytes = 1000000;

struct Ran {
  int exit_code = -1;
  std::string out;
};

// Runs explore_run to its end; its stdout.
Ran explore_run(const std::string& db, int threads) {
  const std::string command = std::string(CLOTHDB_EXPLORE_RUN) + " " + db + " " +
                              std::to_string(threads) + " " + std::to_string(kTotalFrames) + " " +
                              std::to_string(kCacheBytes);
  Ran ran;
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) return ran;
  char buf[512];
  while (std::fgets(buf, sizeof buf, pipe)) ran.out += buf;
  const int status = pclose(pipe);
  ran.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return ran;
}

long states_in(const std::string& db) {
  sqlite3* h = nullptr;
  long n = 0;
  if (sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
    sqlite3_busy_timeout(h, 1000);
    sqlite3_stmt* s = nullptr;
    if (sqlite3_prepare_v2(h, "SELECT count(*) FROM cloth_state", -1, &s, nullptr) == SQLITE_OK &&
        sqlite3_step(s) == SQLITE_ROW)
      n = sqlite3_column_int64(s, 0);
    sqlite3_finalize(s);
  }
  sqlite3_close(h);
  return n;
}

// The figures explore_run prints: "states N bytes_per_state B cache_capacity C peak_alive P".
struct StoreFigures {
  long states = 0, bytes_per_state = 0, capacity = 0, peak_alive = 0, resumed = -1;
};
StoreFigures figures(const std::string& out) {
  StoreFigures f;
  std::sscanf(out.c_str(),
              "states %ld bytes_per_state %ld cache_capacity %ld peak_alive %ld resumed %ld",
              &f.states, &f.bytes_per_state, &f.capacity, &f.peak_alive, &f.resumed);
  return f;
}

// The bound of the store (docs/notebook/explorer.md#memory-per-state): per state its record,
// reduced form and index at its node; exact states within the cache's capacity plus, in flight,
// two per thread and two on the explorer's thread.
void expect_within_bound(const ExploreReport& r, int threads, uint32_t vertices) {
  EXPECT_LE(r.bytes_per_state,
            sizeof(StateRec) + sizeof(int) + (6 * kReducedBlocks + kMotionModes) * sizeof(double));
  EXPECT_LE(r.state_cache.peak_alive_bytes,
            r.state_cache.capacity + size_t(2 * (threads + 1)) * exact_state_bytes(vertices));
  // Not vacuous: the states did not fit in the cache, so they were read back.
  EXPECT_GT(size_t(r.states) * exact_state_bytes(vertices), 3 * r.state_cache.capacity);
  EXPECT_GT(r.state_cache.reads, 0);
}

ExploreReport explore_in_process(const std::string& path, int threads) {
  const CharacterScene scene = tiny_scene();
  ExploreGraph graph = tiny_graph(scene);
  db::Writer writer = db::Writer::create(path);
  prepare_database(writer, scene, graph, "{}");
  return explore(scene, graph, writer, many_states_options(threads, kTotalFrames, kCacheBytes));
}

}  // namespace

TEST(StateStore, FiveThousandStatesWithinTheBoundAndOneFileForOneAndTwoThreads) {
  const TempDir dir("clothdb_state_store");
  const uint32_t vertices = uint32_t(tiny_scene().model.vertex_count());
  const ExploreReport one = explore_in_process(dir.file("one.db"), 1);
  const ExploreReport two = explore_in_process(dir.file("two.db"), 2);
  EXPECT_GE(one.states, 5000);
  expect_within_bound(one, 1, vertices);
  expect_within_bound(two, 2, vertices);
  EXPECT_EQ(one.states, two.states);
  expect_same_rows(dir.file("one.db"), dir.file("two.db"));
}

TEST(StateStore, SigkillMidRunAndTheSameCommandGiveTheUninterruptedFile) {
  const TempDir dir("clothdb_state_store_kill");
  const std::string whole = dir.file("whole.db"), killed = dir.file("killed.db");
  const Ran uninterrupted = explore_run(whole, 1);
  ASSERT_EQ(uninterrupted.exit_code, 0) << uninterrupted.out;
  const StoreFigures w = figures(uninterrupted.out);
  EXPECT_GE(w.states, 5000) << uninterrupted.out;
  EXPECT_EQ(w.resumed, 0);

  // The same command, killed once the file holds 1,500 states.
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    std::freopen("/dev/null", "w", stdout);
    execl(CLOTHDB_EXPLORE_RUN, CLOTHDB_EXPLORE_RUN, killed.c_str(), "2",
          std::to_string(kTotalFrames).c_str(), std::to_string(kCacheBytes).c_str(), nullptr);
    _exit(127);
  }
  const auto start = std::chrono::steady_clock::now();
  while (states_in(killed) < 1500 &&
         std::chrono::steady_clock::now() - start < std::chrono::seconds(40)) {
    int status = 0;
    if (waitpid(child, &status, WNOHANG) == child) FAIL() << "explore_run ended before the kill";
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_EQ(kill(child, SIGKILL), 0);
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
  const long at_kill = states_in(killed);
  EXPECT_GE(at_kill, 1500);
  EXPECT_LT(at_kill, w.states);

  const Ran resumed = explore_run(killed, 2);
  ASSERT_EQ(resumed.exit_code, 0) << resumed.out;
  const StoreFigures r = figures(resumed.out);
  EXPECT_EQ(r.resumed, 1) << resumed.out;
  EXPECT_EQ(r.states, w.states);
  // Two threads: the cache's capacity plus six states in flight.
  const uint32_t vertices = uint32_t(tiny_scene().model.vertex_count());
  EXPECT_LE(r.peak_alive, r.capacity + 6 * long(exact_state_bytes(vertices)));
  expect_same_rows(whole, killed);
}

namespace {

// A secondary graph of one node whose exact states live only in the cache (read back: none).
SecondaryGraph one_node_graph(uint32_t vertices) {
  SecondaryGraph sg;
  sg.tau = 1.0 / 30;
  sg.out_edges.assign(1, {});
  sg.states_at_node.assign(1, {});
  sg.reducer = make_reducer(vertices, sg.tau);
  sg.exact = std::make_shared<StateCache>(size_t(1) << 30, [](int64_t id) -> ExactState {
    throw std::runtime_error("state " + std::to_string(id) + " is not cached");
  });
  return sg;
}

// Adds the cloud's states one by one as the explorer does (nearest_state, then add_state),
// checking each query's answer and every priority against brute force over the exact distances
// (ties to the state added first). Returns the state distances measured.
long add_all_against_brute_force(const Cloud& c, uint32_t vertices, size_t* basis_modes = nullptr) {
  SecondaryGraph sg = one_node_graph(vertices);
  std::vector<double> brute_priority;
  for (size_t s = 0; s < c.x.size(); ++s) {
    const Nearest found = nearest_state(sg, 0, c.x[s], c.v[s]);
    int brute = -1;
    double best = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < s; ++k) {
      const double d = db::state_distance(c.x[s], c.v[s], c.x[k], c.v[k], sg.tau);
      if (d < best) best = d, brute = int(k);
      brute_priority[k] = std::min(brute_priority[k], d);
    }
    EXPECT_EQ(found.state, brute) << "state " << s;
    if (brute >= 0) {
      EXPECT_EQ(found.distance, best) << "state " << s;
    }
    brute_priority.push_back(brute >= 0 ? best : kNoNeighbour);
    StateRec rec;
    rec.id = int64_t(s) + 1;
    add_state(sg, std::move(rec), ExactState{c.x[s], c.v[s]}, found);
    if (::testing::Test::HasFailure()) return sg.exact_evaluations;
  }
  for (size_t k = 0; k < c.x.size(); ++k)
    EXPECT_EQ(sg.states[k].priority, brute_priority[k]) << "state " << k;
  if (basis_modes) *basis_modes = sg.basis.modes;
  return sg.exact_evaluations;
}

// States at one node moving in a few modes: four smooth over the garment (block means see them
// in part) and four alternating between neighbouring vertices (block means see nothing), of
// random amplitude, plus noise of each vertex's own (sigma): small, the motion basis holds nearly
// all of a difference and its bound is tight; as large as the modes, it is loose. Some exact
// duplicates (ties).
Cloud moving_cloud(size_t n, uint32_t vertices, float sigma, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  Cloud c;
  std::vector<float> centre(3 * vertices);
  for (float& f : centre) f = 0.05f * noise(rng);
  for (size_t s = 0; s < n; ++s) {
    if (s > 3 && s % 19 == 0) {
      c.x.push_back(c.x[s / 2]);
      c.v.push_back(c.v[s / 2]);
      continue;
    }
    std::vector<float> x = centre, v(3 * vertices, 0.0f);
    for (int m = 0; m < 8; ++m) {
      const float a = 0.004f * noise(rng), b = 0.06f * noise(rng);
      for (uint32_t i = 0; i < vertices; ++i) {
        const float sign = m < 4 || i % 2 == 0 ? 1.0f : -1.0f;
        const float wave = std::cos(0.07f * float(m % 4 + 1) * float(i / 2));
        x[3 * i + size_t(m % 3)] += sign * a * wave;
        v[3 * i + size_t((m + 1) % 3)] += sign * b * wave;
      }
    }
    for (float& f : x) f += sigma * noise(rng);
    for (float& f : v) f += 10 * sigma * noise(rng);
    c.x.push_back(std::move(x));
    c.v.push_back(std::move(v));
  }
  return c;
}

// States that differ only where block means cannot see it: each block's mean is the cluster
// centre's (the reduced forms coincide), so only exact distances can tell them apart.
Cloud hidden_cluster(size_t n, uint32_t vertices, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, 1.0f);
  Cloud c;
  std::vector<float> centre(3 * vertices);
  for (float& f : centre) f = 0.05f * noise(rng);
  for (size_t s = 0; s < n; ++s) {
    if (s > 3 && s % 23 == 0) {  // a duplicate: a tie
      c.x.push_back(c.x[s / 3]);
      c.v.push_back(c.v[s / 3]);
      continue;
    }
    std::vector<float> x = centre, v(3 * vertices, 0.0f);
    // A few smooth modes, each of zero mean over every pair of neighbouring vertices.
    for (int m = 0; m < 3; ++m) {
      const float a = 0.003f * noise(rng), b = 0.03f * noise(rng);
      for (uint32_t i = 0; i < vertices; ++i) {
        const float sign = (i % 2 == 0) ? 1.0f : -1.0f;
        const float wave = std::cos(0.1f * float(m + 1) * float(i / 2));
        x[3 * i + size_t(m)] += sign * a * wave;
        v[3 * i + size_t(m)] += sign * b * wave;
      }
    }
    c.x.push_back(std::move(x));
    c.v.push_back(std::move(v));
  }
  return c;
}

}  // namespace

TEST(StateStore, NearestStateAndPrioritiesAreBruteForceOnRandomAndClusteredStates) {
  const uint32_t vertices = 64;
  // Random states (no structure), the clustered cloud, and a cluster the reduced form is blind to.
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> uniform(-0.1f, 0.1f);
  Cloud random;
  for (int s = 0; s < 600; ++s) {
    random.x.emplace_back(3 * vertices);
    random.v.emplace_back(3 * vertices);
    for (float& f : random.x.back()) f = uniform(rng);
    for (float& f : random.v.back()) f = uniform(rng);
  }
  const Cloud clustered = cloud(600, vertices, 5), hidden = hidden_cluster(600, vertices, 9);
  for (const Cloud* c : std::vector<const Cloud*>{&random, &clustered, &hidden}) {
    const long measured = add_all_against_brute_force(*c, vertices);
    // The hidden cluster is where the block means are blind (the search measured nearly every
    // pair before the motion basis); its three modes lie in the basis, which sees them: under a
    // tenth of the pairs, and the answers still brute force's.
    if (c == &hidden) {
      EXPECT_LT(measured, (600L * 599 / 2) / 10);
    }
  }
}

TEST(StateStore, MotionBoundIsALowerBoundEverywhereAndTightWhereStatesMoveInFewModes) {
  const uint32_t vertices = 64;
  const StateReducer reducer = make_reducer(vertices, 1.0 / 30);
  for (const float sigma : {1e-5f, 3e-3f}) {
    const Cloud c = moving_cloud(200, vertices, sigma, 21);
    std::vector<ExactState> states;
    for (size_t s = 0; s < c.x.size(); ++s) states.push_back({c.x[s], c.v[s]});
    std::vector<const ExactState*> sample;
    for (size_t s = 0; s < 48; ++s) sample.push_back(&states[4 * s]);
    const MotionBasis basis =
        build_motion_basis(reducer, sample, std::vector<int>(sample.size(), 0), kMotionModes);
    ASSERT_GT(basis.modes, 8u);
    std::vector<Projection> p;
    std::vector<std::vector<double>> reduced;
    for (const ExactState& e : states) {
      p.push_back(project(basis, e.x.data(), e.v.data()));
      reduced.push_back(reduce(reducer, e.x.data(), e.v.data()));
    }
    double worst_ratio = 0, sum_ratio = 0, sum_reduced_ratio = 0;
    long pairs = 0;
    for (size_t a = 0; a < states.size(); ++a)
      for (size_t b = 0; b < a; ++b) {
        const double d = db::state_distance(c.x[a], c.v[a], c.x[b], c.v[b], reducer.tau);
        const double r = reduced_distance(reduced[a].data(), reduced[b].data(), reducer.size());
        const double bound = motion_bound(basis, r, p[a], p[b]);
        EXPECT_FALSE(bound_exceeds(bound, d)) << a << " " << b << ": " << bound << " > " << d;
        EXPECT_GE(bound, r / basis.inflation);  // never looser than the block means
        if (d > 0) {
          worst_ratio = std::max(worst_ratio, bound / d);
          sum_ratio += bound / d, sum_reduced_ratio += r / d, ++pairs;
        }
      }
    // Not vacuous: the bound comes close to the distance (a bound that ignored the basis would
    // stay at the block means', far below), and a basis that overstated a difference would have
    // failed above on some pair.
    if (sigma < 1e-4f) {
      EXPECT_GT(sum_ratio / double(pairs), 0.99);
      EXPECT_LT(sum_reduced_ratio / double(pairs), 0.8);
    }
    EXPECT_LE(worst_ratio, 1 + 1e-9);
  }
}

TEST(StateStore, NearestStateAndPrioritiesAreBruteForceWithTheMotionBasisTightAndLoose) {
  const uint32_t vertices = 64;
  const size_t n = 700;
  const long pairs = long(n) * long(n - 1) / 2;
  // Tight: nearly every difference lies in the basis; the search with it measures a few
  // distances a state. Loose: the noise is as large as the modes; still brute force's answers.
  size_t modes = 0;
  const long tight =
      add_all_against_brute_force(moving_cloud(n, vertices, 1e-5f, 3), vertices, &modes);
  EXPECT_GT(modes, 8u);
  EXPECT_LT(tight, pairs / 20);
  const long loose =
      add_all_against_brute_force(moving_cloud(n, vertices, 3e-3f, 4), vertices, &modes);
  EXPECT_GT(modes, 8u);
  EXPECT_GT(loose, tight);
}
