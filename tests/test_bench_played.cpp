// `bench played` (precompute/bench/played_bench.hpp) on the small contractive graph of
// explore_fixture.hpp: what the player shows is within the codec bound of a simulation of the same
// path until the first link, within the blends afterwards; a tighter epsilon plays closer to
// simulation; the chaos floor of a non-chaotic scene is near zero but not zero.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "bench/played_bench.hpp"
#include "database/store/writer.hpp"
#include "support/explore_fixture.hpp"

using namespace clothdb;
using namespace clothdb::test;

namespace {

// The small graph, or only its "hold" loop (a single loop on a scene that settles: not chaotic).
ExploreGraph graph_of(const CharacterScene& scene, bool hold_only) {
  ExploreGraph graph = small_graph(scene);
  if (hold_only) graph.edges.resize(1);
  return graph;
}

std::string build_db(const CharacterScene& scene, const std::string& name, double epsilon,
                     long max_frames, bool hold_only = false) {
  const std::string path = testing::TempDir() + "/clothdb_played_" + name + ".db";
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
  ExploreGraph graph = graph_of(scene, hold_only);
  db::Writer writer = db::Writer::create(path);
  prepare_database(writer, scene, graph, "{}");
  ExploreOptions options;
  options.epsilon = epsilon;
  options.max_frames = max_frames;
  options.threads = 2;
  options.progress = false;
  explore(scene, graph, writer, options);
  return path;
}

PlayedReport play(const CharacterScene& scene, const std::string& path, int paths, double seconds,
                  bool hold_only = false) {
  ExploreGraph graph = graph_of(scene, hold_only);
  // The edges' primary clips, as prepare_database numbered them (graph order, from 1).
  for (size_t e = 0; e < graph.edges.size(); ++e) graph.edges[e].db_clip = int64_t(e) + 1;
  PlayedOptions options;
  options.paths = paths;
  options.seconds = seconds;
  options.progress = false;
  options.threads = 2;
  return bench_played(path, scene, graph, scene.file.solver, scene.file.settings, options);
}

// The small scene settled for 200 frames instead of 10: near its equilibrium.
CharacterScene settled_scene() {
  SceneFile file = small_scene().file;
  file.settle_frames = 200;
  return build_character_scene(file);
}

}  // namespace

TEST(BenchPlayed, WithinTheCodecBoundUntilTheFirstLinkAndTheBlendsAfter) {
  // One linked loop: the skirt holding still, its clip's end linked back to the rest state. Settled
  // for long enough that the rest state is near the skirt's equilibrium: settled for only 10
  // frames, the skirt is still sagging, and a loop that restarts it from the rest state each turn
  // drifts up to 37 mm from a simulation that goes on sagging although each link records only
  // 6 mm (what `bench played` is for; docs/notebook/BENCHMARKS.md).
  const CharacterScene scene = settled_scene();
  const double epsilon = 0.02;
  const std::string path = build_db(scene, "loop", epsilon, 0, true);
  double blend = 0;  // the largest blend error the database records, m
  {
    db::Reader r;
    db::Error err;
    ASSERT_EQ(r.open(path, &err), db::Status::Ok);
    std::vector<db::ClothEdge> edges;
    EXPECT_EQ(r.cloth_edges(&edges, &err), clothdb::Status::Ok);
    for (const auto& e : edges) blend = std::max(blend, e.blend_error);
  }
  ASSERT_GT(blend, 0.0) << "the loop did not link back: the test shows nothing about blending";
  const PlayedReport r = play(scene, path, 1, 6.0, true);
  ASSERT_EQ(r.paths.size(), 1u);
  if (std::getenv("PLAYED_DEBUG")) {
    std::FILE* f = std::fopen("/tmp/played_debug.csv", "w");
    std::fputs(played_path_csv(r.paths[0]).c_str(), f);
    std::fclose(f);
  }
  const double codec = std::sqrt(3.0) * db::CodecSettings{}.position_bound;  // per vertex, m
  long before_link = 0, linked = 0;
  bool any_link = false;
  for (const PlayedFrame& f : r.paths[0].frames) {
    any_link = any_link || f.linked;
    EXPECT_FALSE(f.fallback) << "a converged database needs no fallback";
    if (!any_link) {
      // The same simulation, stored: only the codec stands between them. At frame 0 twice: the
      // clip's first frame re-encodes the stored (already quantised) start state, while the
      // simulation starts from that state with its pins put back exactly on the bones.
      const double bound = f.time == 0 ? 2 * codec : codec;
      EXPECT_LE(f.max_mm, 1e3 * bound * 1.01) << "frame at " << f.time << " s";
      ++before_link;
    } else {
      // Each turn of the loop restarts the played cloth from the rest state while the simulation
      // goes on from where it is: on a settling (contractive) skirt the two differ by at most
      // the blend the loop records, summed geometrically (factor 2 for a contraction of 1/2
      // per turn), plus the codec.
      EXPECT_LE(f.rms_mm, 1e3 * (2 * blend + codec)) << "frame at " << f.time << " s";
      ++linked;
    }
  }
  EXPECT_GT(before_link, 5);
  EXPECT_GT(linked, 100);
  EXPECT_GT(r.linked_fraction, 0.9);
  EXPECT_EQ(r.fallback_fraction, 0.0);
}

TEST(BenchPlayed, TighterEpsilonPlaysCloserToSimulation) {
  // Contractive: the skirt, settled for only 10 frames, goes on sagging toward its equilibrium
  // while the character holds still (chaos floor about 0.02 mm). Swaying, the same skirt is
  // chaotic and both databases play about 43 mm from simulation: epsilon cannot show there.
  const CharacterScene scene = small_scene();
  const std::string loose = build_db(scene, "loose", 0.03, 2500, true);
  const std::string tight = build_db(scene, "tight", 0.002, 2500, true);
  const PlayedReport a = play(scene, loose, 1, 8.0, true);
  const PlayedReport b = play(scene, tight, 1, 8.0, true);
  EXPECT_LT(b.played_rms_mm_p95, a.played_rms_mm_p95)
      << "epsilon 2 mm: p95 " << b.played_rms_mm_p95 << " mm; 30 mm: " << a.played_rms_mm_p95;
  EXPECT_LT(b.played_rms_mm_p50, a.played_rms_mm_p50);
}

TEST(BenchPlayed, ChaosFloorOfAContractiveSceneIsNearZeroButMeasured) {
  // A settled skirt holding still: nothing amplifies a 1 um difference. (Swaying, the same skirt
  // is chaotic: its floor grows to tens of mm within seconds.)
  const CharacterScene scene = settled_scene();
  const std::string path = build_db(scene, "floor", 0.02, 0, true);
  const PlayedReport r = play(scene, path, 1, 4.0, true);
  // The 1 um start perturbation does not grow on a heavily damped skirt...
  EXPECT_LT(r.chaos_floor_rms_mm_p95, 0.002);
  // ...but it is there (a floor of exactly 0 would mean the perturbation was never applied).
  EXPECT_GT(r.chaos_floor_rms_mm_p50, 0.0);
  // Pops and jitter are in the summary (PopAndJitterOfAForcedPop pins their values).
  const std::string json = played_json(r, PlayedOptions{}, path);
  EXPECT_NE(json.find("\"max_pop_mm\": " + nlohmann::json(r.max_pop_mm).dump()), std::string::npos);
  EXPECT_NE(json.find("\"jitter_mm\": " + nlohmann::json(r.jitter_mm).dump()), std::string::npos);
  EXPECT_TRUE(std::isfinite(r.max_pop_mm) && r.max_pop_mm >= 0);
  EXPECT_TRUE(std::isfinite(r.jitter_mm) && r.jitter_mm >= 0);
}

// A forced pop on a tiny case: two vertices over four frames, the simulation still at the origin,
// the played vertex 0 jumping 10 mm out at frame 2 and back at frame 3. Its jump beyond the
// simulation's is 10 mm; its error 0, 0, 10, 0 mm has second differences 10 and -20 mm.
TEST(BenchPlayed, PopAndJitterOfAForcedPop) {
  const size_t frames = 4, vertices = 2;
  std::vector<Eigen::Matrix3Xd> simulated(frames, Eigen::Matrix3Xd::Zero(3, 2));
  std::vector<float> played(frames * vertices * 3, 0.0f);
  played[3 * (2 * vertices + 0) + 0] = 0.01f;
  PopsAndJitter pj = pops_and_jitter(played.data(), simulated, frames, vertices);
  EXPECT_NEAR(pj.max_pop_mm, 10.0, 1e-4);
  EXPECT_NEAR(pj.jitter_mm, 20.0, 1e-4);

  // The same jump in the simulation too: the played cloth follows it, no pop and no jitter.
  simulated[2](0, 0) = 0.01;
  pj = pops_and_jitter(played.data(), simulated, frames, vertices);
  EXPECT_NEAR(pj.max_pop_mm, 0.0, 1e-4);
  EXPECT_NEAR(pj.jitter_mm, 0.0, 1e-4);

  // A steady offset of 3 mm on vertex 1 is error, but neither a pop nor jitter.
  for (size_t f = 0; f < frames; ++f) played[3 * (f * vertices + 1) + 1] = 0.003f;
  pj = pops_and_jitter(played.data(), simulated, frames, vertices);
  EXPECT_NEAR(pj.max_pop_mm, 0.0, 1e-4);
  EXPECT_NEAR(pj.jitter_mm, 0.0, 1e-4);

  // A smaller jump than the simulation's is not a pop: the played vertex stays put.
  for (size_t f = 0; f < frames; ++f) played[3 * (f * vertices + 0) + 0] = 0.0f;
  pj = pops_and_jitter(played.data(), simulated, frames, vertices);
  EXPECT_EQ(pj.max_pop_mm, 0.0);
  EXPECT_NEAR(pj.jitter_mm, 20.0, 1e-4);  // its error 0, 0, 10, 0 mm flickers all the same
}
