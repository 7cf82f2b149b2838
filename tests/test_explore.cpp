// The explorer (Kim et al. 2013) on a small graph: it converges, every edge's blend error is
// within epsilon, every state has cloth for every way out of its node, the result does not depend
// on the thread count, and a run stopped part-way resumes to the same database content.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <set>
#include <sstream>

#include "clothrt.h"
#include "database/codec/codec.hpp"
#include "database/format/checksum.hpp"
#include "database/format/contracts.hpp"
#include "database/store/check.hpp"
#include "database/store/writer.hpp"
#include "explore/explorer.hpp"
#include "explore/job_wire.hpp"
#include "explore/precompute.hpp"
#include "support/db_rows.hpp"
#include "support/explore_fixture.hpp"

using namespace clothdb;
using namespace clothdb::test;

namespace {

// Per process: CTest runs these tests two at a time, and several use the same names.
std::string db_path(const std::string& name) {
  return testing::TempDir() + "/clothdb_explore_" + std::to_string(getpid()) + "_" + name + ".db";
}

// A fresh (removed) database path.
std::string temp_db(const std::string& name) {
  const std::string path = db_path(name);
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
  return path;
}

ExploreReport run_graph(const CharacterScene& scene, ExploreGraph graph, const std::string& path,
                        ExploreOptions options, const BatchRunner& runner = {}) {
  db::Writer writer =
      std::filesystem::exists(path) ? db::Writer::open(path) : db::Writer::create(path);
  prepare_database(writer, scene, graph, "{}");
  options.progress = std::getenv("CLOTHDB_PROGRESS") != nullptr;
  return explore(scene, graph, writer, options, runner);
}

ExploreReport run(const CharacterScene& scene, const std::string& path, ExploreOptions options,
                  double hold_reach = 1.0, const BatchRunner& runner = {}) {
  ExploreGraph graph = small_graph(scene);
  graph.edges[0].reach = hold_reach;
  return run_graph(scene, graph, path, options, runner);
}

// Every clip blob and every state blob, in id order: the database's cloth content, as one
// checksum per row (so a mismatch prints a short diff).
std::vector<uint64_t> content(const std::string& path) {
  db::Reader r;
  db::Error err;
  EXPECT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  std::vector<uint64_t> out;
  auto add = [&](const std::vector<uint8_t>& bytes) {
    out.push_back(db::xxh64(bytes.data(), bytes.size()));
  };
  std::vector<db::ClothClip> clips;
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  for (const auto& c : clips) {
    std::vector<uint8_t> blob;
    EXPECT_EQ(r.clip_blob(c.id, &blob, &err), clothdb::Status::Ok);
    add(blob);
    out.push_back(static_cast<uint64_t>(c.start_state) << 32 |
                  static_cast<uint64_t>(c.primary_clip));
  }
  std::vector<db::StoredState> states;
  EXPECT_EQ(r.cloth_states(&states, &err), clothdb::Status::Ok);
  for (const auto& s : states) {
    std::vector<uint8_t> p, v;
    EXPECT_EQ(r.state_blobs(s.id, &p, &v, &err), clothdb::Status::Ok);
    add(p);
    add(v);
  }
  std::vector<db::ClothEdge> edges;
  EXPECT_EQ(r.cloth_edges(&edges, &err), clothdb::Status::Ok);
  for (const auto& e : edges)
    out.push_back(static_cast<uint64_t>(e.from_clip) << 32 | static_cast<uint64_t>(e.to_state));
  return out;
}

// `db check` finds nothing wrong with the file.
void expect_checks(const std::string& path) {
  const db::CheckReport check = db::check_database(path);
  for (const auto& problem : check.problems) ADD_FAILURE() << path << ": " << problem;
}

// Two files made two ways (threads, resumed, through the wire) hold the same content, every
// table compared (cloth_link, cloth_clip_steering, meta and codec_basis included) but the run
// bookkeeping named in run_bookkeeping(), and both pass `db check`.
void expect_same_file(const std::string& a, const std::string& b) {
  EXPECT_EQ(content(a), content(b));
  expect_same_rows(a, b);
  expect_checks(a);
  expect_checks(b);
}

}  // namespace

TEST(Explore, ConvergesWithinEpsilonAndCoversEveryWayOut) {
  const CharacterScene scene = small_scene();
  const std::string path = temp_db("converge");
  ExploreOptions options;
  options.epsilon = 0.02;
  const ExploreReport report = run(scene, path, options);
  EXPECT_TRUE(report.converged);
  EXPECT_EQ(report.dead_ends, 0);
  EXPECT_GE(report.states, 2);  // the sway moves the skirt: one state cannot serve

  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::StoredState> states;
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  std::vector<db::PrimaryClip> primary;
  EXPECT_EQ(r.cloth_states(&states, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_edges(&edges, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.primary_clips(&primary, &err), clothdb::Status::Ok);
  // Every state at the node has a clip along both primary edges leaving it.
  for (const auto& s : states)
    for (const auto& p : primary) {
      int found = 0;
      for (const auto& c : clips) found += (c.start_state == s.id && c.primary_clip == p.id);
      EXPECT_EQ(found, 1) << "state " << s.id << " along " << p.name;
    }
  // Every clip continues somewhere, within epsilon.
  EXPECT_EQ(edges.size(), clips.size());
  for (const auto& e : edges) EXPECT_LE(e.blend_error, options.epsilon);
  // The unresolved error falls to zero along the curve.
  EXPECT_EQ(report.curve.back().worst_error, 0.0);
  db::CheckReport check = db::check_database(path);
  for (const auto& problem : check.problems) ADD_FAILURE() << problem;
}

TEST(Explore, SameDatabaseForOneAndTwoThreads) {
  const CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.02;
  options.threads = 1;
  ASSERT_TRUE(run(scene, temp_db("t1"), options).converged);
  options.threads = 2;
  ASSERT_TRUE(run(scene, temp_db("t2"), options).converged);
  const auto one = content(db_path("t1"));
  EXPECT_GT(one.size(), 4u);
  expect_same_file(db_path("t1"), db_path("t2"));
}

TEST(Explore, StoppedRunResumesToTheSameContent) {
  const CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.02;
  options.batch = 2;
  ASSERT_TRUE(run(scene, temp_db("whole"), options).converged);
  // Stop after a few batches (a frame budget), then run the same command again until done.
  const std::string path = temp_db("parts");
  options.max_frames = 30;
  const ExploreReport first = run(scene, path, options);
  EXPECT_FALSE(first.converged);
  // The stopped run closed its dead ends with links (which the resumed run must replace).
  EXPECT_GT(first.links, 0);
  expect_checks(path);
  options.max_frames = 0;
  const ExploreReport second = run(scene, path, options);
  EXPECT_TRUE(second.resumed);
  ASSERT_TRUE(second.converged);
  expect_same_file(db_path("whole"), path);
}

// The same with codec version 2 and bases built as the file grows: a run stopped on its budget
// keeps every basis it built (even one no clip chose yet), so the run that resumes it encodes as
// an uninterrupted run would; the bases none chose are removed once the exploration converges;
// and the thread count changes nothing.
TEST(Explore, StoppedRunWithCodecV2ResumesToTheSameContent) {
  const CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.02;
  options.batch = 2;
  options.subspace_modes = 4;
  options.subspace_first_frames = 40;
  const ExploreReport whole = run(scene, temp_db("v2_whole"), options);
  EXPECT_TRUE(whole.converged);
  EXPECT_GE(whole.bases_built, 3);
  const std::string path = temp_db("v2_parts");
  int parts = 0, built = 0, removed = 0;
  // Parts of about a sixth of the whole run: how many frames it takes to converge changes
  // chaotically with any change to the scene (a collider radius 1e-7 off), the parts must not.
  ASSERT_GT(whole.frames, 60);
  for (options.max_frames = whole.frames / 6;; ++parts) {
    const ExploreReport part = run(scene, path, options);
    built += part.bases_built;
    removed += part.bases_removed;
    if (part.converged) break;
    EXPECT_EQ(part.bases_removed, 0);  // not before convergence
    ASSERT_LT(parts, 20);
  }
  EXPECT_GE(parts, 3);
  EXPECT_EQ(built, whole.bases_built);
  EXPECT_EQ(removed, whole.bases_removed);
  expect_same_file(db_path("v2_whole"), path);
  EXPECT_EQ(db::read_database_info(path).bases.size(),
            static_cast<size_t>(whole.bases_built - whole.bases_removed));
  // Bases are built between batches, on the explorer's thread: two threads give the same file.
  options.max_frames = 0;
  options.threads = 2;
  ASSERT_TRUE(run(scene, temp_db("v2_two_threads"), options).converged);
  expect_same_file(db_path("v2_whole"), db_path("v2_two_threads"));
}

// Clips in the order they were explored: (start state, primary clip) by clip id.
std::vector<std::pair<int64_t, int64_t>> clip_order(const std::string& path) {
  db::Reader r;
  db::Error err;
  EXPECT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  std::vector<db::ClothClip> clips;
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  std::vector<std::pair<int64_t, int64_t>> out;
  for (const auto& c : clips) out.emplace_back(c.start_state, c.primary_clip);
  return out;
}

// For each state with clips along both edges: is the "hold" clip (primary clip 1) explored first?
std::vector<bool> hold_first(const std::vector<std::pair<int64_t, int64_t>>& order) {
  std::map<int64_t, std::vector<int64_t>> by_state;
  for (const auto& [state, primary] : order) by_state[state].push_back(primary);
  std::vector<bool> out;
  for (const auto& [state, primaries] : by_state)
    if (primaries.size() == 2) out.push_back(primaries[0] == 1);
  return out;
}

// The clips of two runs that made the same graph, one stored with codec version 1 only: the same
// clip ids, each within twice the bound of the other's (both are within the bound of the same
// simulation), every version 2 clip naming a stored basis, the newest when its batch was chosen.
// Returns how many clips of the second file are version 2.
static int expect_same_clips_within_twice_the_bound(const std::string& v1_path,
                                                    const std::string& v2_path) {
  const db::DatabaseInfo info = db::read_database_info(v2_path);
  db::Reader r1, r2;
  db::Error err;
  EXPECT_EQ(r1.open(v1_path, &err), db::Status::Ok);
  EXPECT_EQ(r2.open(v2_path, &err), db::Status::Ok);
  std::vector<db::ClothClip> clips1, clips2;
  EXPECT_EQ(r1.cloth_clips(&clips1, &err), clothdb::Status::Ok);
  EXPECT_EQ(r2.cloth_clips(&clips2, &err), clothdb::Status::Ok);
  EXPECT_EQ(clips1.size(), clips2.size());
  const double bound = r2.codec().position_bound;
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob1, blob2;
  std::vector<float> f1, f2;
  int64_t previous_basis = 0;
  int v2 = 0;
  for (size_t k = 0; k < std::min(clips1.size(), clips2.size()); ++k) {
    EXPECT_EQ(clips1[k].id, clips2[k].id);
    EXPECT_EQ(r1.clip_blob(clips1[k].id, &blob1, &err), db::Status::Ok);
    EXPECT_EQ(r2.clip_blob(clips2[k].id, &blob2, &err), db::Status::Ok);
    codec::BlobInfo b;
    EXPECT_EQ(codec::read_info(blob2.data(), blob2.size(), &b, &err), db::Status::Ok);
    if (b.version == codec::kFormatVersionV2) {
      ++v2;
      EXPECT_GE(b.basis_id, previous_basis) << "clip " << clips2[k].id;
      previous_basis = b.basis_id;
      bool stored = false;
      for (const auto& row : info.bases) stored |= row.id == b.basis_id;
      EXPECT_TRUE(stored) << "clip " << clips2[k].id << " names basis " << b.basis_id;
    }
    EXPECT_EQ(r1.decode_all(blob1, &f1, scratch, &err), db::Status::Ok) << err.message;
    EXPECT_EQ(r2.decode_all(blob2, &f2, scratch, &err), db::Status::Ok) << err.message;
    EXPECT_EQ(f1.size(), f2.size());
    double worst = 0;
    for (size_t i = 0; i < std::min(f1.size(), f2.size()); ++i)
      worst = std::max(worst, std::fabs(static_cast<double>(f1[i]) - f2[i]));
    EXPECT_LE(worst, 2 * bound * (1 + 1e-6)) << "clip " << clips2[k].id;
  }
  const db::CheckReport check = db::check_database(v2_path);
  for (const auto& problem : check.problems) ADD_FAILURE() << problem;
  return v2;
}

// Codec version 2 during the run (docs/DATABASE.md, "clothdb precompute ... --codec v2"): the
// explorer builds a basis from the clips stored so far and new ones as the frames grow; the
// simulations (which start from version 1 states) are the same as a version 1 run's, so the files
// hold the same graph. With a body frame as without. Keeping the smaller of the two encodings, no
// basis stays that no clip chose.
TEST(Explore, CodecV2BasesFromTheStoredClipsKeepTheGraphAndTheBound) {
  const CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.02;
  const std::string v1_path = temp_db("codec_v1");
  const ExploreReport v1 = run(scene, v1_path, options);
  ASSERT_GE(v1.frames, 160);  // so the bases are due at 40, 80 and 160 frames
  options.subspace_modes = 8;
  options.subspace_first_frames = 40;
  options.subspace_always = true;  // every later clip as version 2, whatever its size
  for (bool body : {false, true}) {
    SCOPED_TRACE(body ? "body frame" : "character space");
    options.subspace_body_frame = body;
    const std::string v2_path = temp_db(body ? "codec_v2_body" : "codec_v2");
    const ExploreReport v2 = run(scene, v2_path, options);
    EXPECT_EQ(v2.states, v1.states);
    EXPECT_EQ(v2.clips, v1.clips);
    EXPECT_GE(v2.bases_built, 3);
    EXPECT_EQ(v2.bases_removed, 0);
    const db::DatabaseInfo info = db::read_database_info(v2_path);
    EXPECT_EQ(info.bases.size(), static_cast<size_t>(v2.bases_built));
    EXPECT_GT(info.clips_v1, 0u);  // those stored before the first basis
    EXPECT_EQ(info.clips_v2, static_cast<uint64_t>(v2.clips_v2));
    EXPECT_EQ(info.clips_v1 + info.clips_v2, info.cloth_clips);
    EXPECT_EQ(info.states_v2, 0u);
    EXPECT_EQ(expect_same_clips_within_twice_the_bound(v1_path, v2_path), v2.clips_v2);
    EXPECT_GT(v2.clips_v2, 0);
  }

  options.subspace_always = false;
  options.subspace_body_frame = false;
  const std::string smaller_path = temp_db("codec_v2_smaller");
  const ExploreReport smaller = run(scene, smaller_path, options);
  const db::DatabaseInfo kept = db::read_database_info(smaller_path);
  EXPECT_EQ(kept.bases.size(), static_cast<size_t>(smaller.bases_built - smaller.bases_removed));
  EXPECT_LE(kept.clip_blob_bytes, db::read_database_info(v1_path).clip_blob_bytes);
  db::Reader r3;
  db::Error err;
  ASSERT_EQ(r3.open(smaller_path, &err), db::Status::Ok);
  std::vector<db::ClothClip> clips3;
  EXPECT_EQ(r3.cloth_clips(&clips3, &err), clothdb::Status::Ok);
  std::vector<uint8_t> blob;
  for (const auto& row : kept.bases) {
    bool named = false;
    for (const auto& c : clips3) {
      ASSERT_EQ(r3.clip_blob(c.id, &blob, &err), db::Status::Ok);
      codec::BlobInfo b;
      ASSERT_EQ(codec::read_info(blob.data(), blob.size(), &b, &err), db::Status::Ok);
      named |= b.basis_id == row.id;
    }
    EXPECT_TRUE(named) << "basis " << row.id << " is named by no clip";
  }
}

// Codec version 3 during the run (docs/DATABASE.md, "clothdb precompute ... --codec v3"): on the
// bases built as the file grows, every later clip is coded within the contract against its
// simulated frames, its figures recorded within the caps; the graph is a version 1 run's, db check
// passes, a run stopped in parts resumes to the same file, and two threads give the same file.
TEST(Explore, CodecV3ClipsWithinTheirContractAndResumeToTheSameContent) {
  const CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.02;
  options.batch = 2;
  const ExploreReport v1 = run(scene, temp_db("codec3_v1"), options);
  options.subspace_modes = 8;
  options.subspace_first_frames = 40;
  options.subspace_always = true;
  options.subspace_contract = {0.001, 0.003, 0.0001};
  const std::string path = temp_db("codec3_whole");
  const ExploreReport whole = run(scene, path, options);
  ASSERT_TRUE(whole.converged);
  EXPECT_EQ(whole.states, v1.states);
  EXPECT_EQ(whole.clips, v1.clips);
  EXPECT_GT(whole.clips_v3, 0);
  const db::DatabaseInfo info = db::read_database_info(path);
  EXPECT_EQ(info.clips_v3, static_cast<uint64_t>(whole.clips_v3));
  EXPECT_EQ(info.contracts, info.clips_v3);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok) << err.message;
  std::vector<db::ClipContract> contracts;
  ASSERT_EQ(db::clip_contracts(r.handle(), path, &contracts, &err), db::Status::Ok) << err.message;
  EXPECT_EQ(contracts.size(), static_cast<size_t>(whole.clips_v3));
  for (const db::ClipContract& c : contracts) {
    EXPECT_TRUE(codec::within(c.measured, options.subspace_contract))
        << "clip " << c.clip << ": " << codec::describe(c.measured);
    EXPECT_EQ(c.caps.jitter, options.subspace_contract.jitter);
  }
  const db::CheckReport check = db::check_database(path);
  EXPECT_TRUE(check.problems.empty());
  for (const auto& problem : check.problems) ADD_FAILURE() << problem;
  // Stopped in parts and resumed.
  const std::string parts_path = temp_db("codec3_parts");
  options.max_frames = whole.frames / 3;
  for (int parts = 0;; ++parts) {
    if (run(scene, parts_path, options).converged) break;
    ASSERT_LT(parts, 10);
  }
  expect_same_file(db_path("codec3_whole"), parts_path);
  options.max_frames = 0;
  options.threads = 2;
  ASSERT_TRUE(run(scene, temp_db("codec3_two_threads"), options).converged);
  expect_same_file(db_path("codec3_whole"), db_path("codec3_two_threads"));
}

TEST(Explore, RarelyTakenEdgesAreExpandedLater) {
  // The two dead ends of a state have the same unresolved error (the state's); with equal reach
  // the tie goes to the lower edge ("hold"), so the order is decided by reach alone when "hold"
  // is rarely taken.
  const CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.02;
  options.batch = 1;
  options.max_frames = 800;
  run(scene, temp_db("reach_equal"), options, 1.0);
  run(scene, temp_db("reach_rare"), options, 0.05);
  const std::vector<bool> equal = hold_first(clip_order(db_path("reach_equal")));
  const std::vector<bool> rare = hold_first(clip_order(db_path("reach_rare")));
  ASSERT_GE(equal.size(), 3u);
  ASSERT_GE(rare.size(), 3u);
  for (bool b : equal) EXPECT_TRUE(b);
  for (bool b : rare) EXPECT_FALSE(b);
  // And a rare dead end waits behind likely ones of other states with a smaller error: in the
  // weighted run, some "sway" clip of a later state comes before an earlier state's "hold".
  const auto order = clip_order(db_path("reach_rare"));
  bool overtaken = false;
  for (size_t i = 0; i < order.size(); ++i)
    for (size_t j = i + 1; j < order.size(); ++j)
      overtaken |= order[i].second == 2 && order[j].second == 1 && order[i].first > order[j].first;
  EXPECT_TRUE(overtaken);
}

TEST(Explore, RefusesAChangedScene) {
  CharacterScene scene = small_scene();
  const std::string path = temp_db("changed");
  ExploreOptions options;
  options.max_frames = 12;
  run(scene, path, options);
  scene.file.text += " ";  // the scene file as given changed
  EXPECT_THROW(run(scene, path, options), std::runtime_error);
}

// What an MPI worker does, without MPI: every job and result goes through the wire format, and
// the jobs of a batch finish in reverse order. The database must be the OpenMP runner's, every
// table compared: without steering, and with it (the demo scene steers: the jobs then carry the
// explorer's epsilon and the states at the end node, which the wire must keep).
TEST(Explore, JobsThroughTheWireInAnyOrderGiveTheSameDatabase) {
  for (bool steering : {false, true}) {
    SCOPED_TRACE(steering ? "steering" : "no steering");
    CharacterScene scene = small_scene();
    ExploreOptions options;
    options.epsilon = 0.02;
    options.batch = 4;
    if (steering) {
      scene.file.steering.frames = 6;
      scene.file.steering.max_distance = 0.2;
      options.epsilon = 0.002;
      options.max_frames = 500;
    }
    const ExploreGraph graph = small_graph(scene);  // the same edges run() builds
    const std::string omp = temp_db(steering ? "omp_steered" : "omp");
    const std::string wire = temp_db(steering ? "wire_steered" : "wire");
    const ExploreReport direct = run(scene, omp, options);
    ASSERT_TRUE(steering || direct.converged);
    long wired = 0;
    // One worker's replica across the run, kept to one state beyond those a job names so that it
    // drops some: the file must not change.
    ReplicaLedger ledger;
    ledger.capacity_bytes = exact_state_bytes(uint32_t(scene.model.vertex_count()));
    StateReplica worker = make_replica(uint32_t(scene.model.vertex_count()), 1.0 / graph.rate);
    JobWireCounts counts;
    const BatchRunner reversed = [&](const std::vector<JobInput>& jobs,
                                     std::vector<JobResult>& results) {
      for (size_t k = jobs.size(); k-- > 0;) {
        const std::vector<uint8_t> out = encode_job(1000 + k, jobs[k], ledger, &counts);
        uint64_t seq = 0;
        const JobInput received = decode_job(out.data(), out.size(), &seq, worker);
        ASSERT_EQ(seq, 1000 + k);
        const std::vector<uint8_t> back = encode_result(seq, run_job(scene, graph, received));
        results[k] = decode_result(back.data(), back.size(), &seq);
        ++wired;
      }
    };
    const ExploreReport report = run(scene, wire, options, 1.0, reversed);
    EXPECT_EQ(report.converged, direct.converged);
    EXPECT_GE(wired, 4) << report.clips << " clips, " << report.frames << " frames, converged "
                        << report.converged;
    if (steering) {
      ASSERT_GT(direct.steered, 0);
      EXPECT_EQ(report.steered, direct.steered);
    }
    // States crossed as the file's blobs, were named by id once the worker held them, and were
    // dropped beyond one.
    EXPECT_GT(counts.states_sent, 0);
    EXPECT_EQ(counts.sent_as_blobs, counts.states_sent);
    EXPECT_GT(counts.states_named, 0);
    if (!steering) {  // (the steered run, cut at 500 frames, makes two states: both always named)
      EXPECT_GT(counts.states_dropped, 0);
    }
    std::printf("%ld states sent (%ld as blobs), %ld named by id, %ld dropped\n",
                counts.states_sent, counts.sent_as_blobs, counts.states_named,
                counts.states_dropped);
    expect_same_file(omp, wire);
  }
}

// The precompute's orchestration (explore/precompute.hpp), without the CLI.
TEST(Precompute, InvalidRunSettingsAreRefusedBeforeAFileExists) {
  const std::string path = temp_db("refused");
  const struct {
    const char* field;
    void (*set)(ExploreOptions&);
  } cases[] = {
      {"epsilon_m", [](ExploreOptions& o) { o.epsilon = std::nan(""); }},
      {"epsilon_m", [](ExploreOptions& o) { o.epsilon = -0.005; }},
      {"cpu_hours", [](ExploreOptions& o) { o.cpu_hours = -1; }},
      {"cpu_hours", [](ExploreOptions& o) { o.cpu_hours = std::nan(""); }},
      {"max_frames", [](ExploreOptions& o) { o.max_frames = -5; }},
      {"threads", [](ExploreOptions& o) { o.threads = 100000; }},
  };
  for (const auto& c : cases) {
    PrecomputeRequest request;
    request.scene = kMotions + "skirt_walk.json";
    request.db = path;
    request.explore.progress = false;
    c.set(request.explore);
    try {
      run_precompute(request, nullptr);
      ADD_FAILURE() << c.field << " accepted";
    } catch (const db::SettingsError& e) {
      EXPECT_NE(std::string(e.what()).find(c.field), std::string::npos) << e.what();
    }
    EXPECT_FALSE(std::filesystem::exists(path)) << c.field;
  }
}

TEST(Precompute, MotionGraphRuleAndResumeRule) {
  CharacterScene scene = small_scene();
  // Built from the scene's clips when nothing else is given; the database's own graph is taken
  // as stored (its JSON is kept byte for byte) and --graph is taken over it.
  const ChosenGraph built = choose_motion_graph(scene, "", "", -1);
  ASSERT_GT(built.graph.edge_count(), 0);
  EXPECT_EQ(built.where, scene.file.path.string());
  const ChosenGraph stored = choose_motion_graph(scene, "", built.json, -1);
  EXPECT_EQ(stored.json, built.json);
  EXPECT_EQ(stored.graph.edge_count(), built.graph.edge_count());
  const std::string graph_file =
      testing::TempDir() + "/clothdb_explore_graph_" + std::to_string(getpid()) + ".json";
  std::ofstream(graph_file) << built.json;
  EXPECT_EQ(choose_motion_graph(scene, graph_file, "{\"not\": \"this\"}", -1).where, graph_file);
  EXPECT_THROW(choose_motion_graph(scene, "", "{not json", -1), std::runtime_error);

  // Resume: a database made with one solver setting refuses a scene giving another, naming the
  // database; with --auto it takes the stored setting instead.
  const std::string path = temp_db("resume_rule");
  ExploreGraph eg = explore_graph(scene, built.graph, "test");
  {
    db::Writer writer = db::Writer::create(path);
    prepare_database(writer, scene, eg, built.json);
  }
  PrecomputeRequest request;
  request.db = path;
  EXPECT_EQ(choose_solver(request, scene, eg), "");  // same setting: fine
  CharacterScene changed = scene;
  changed.file.settings.substeps += 1;
  try {
    choose_solver(request, changed, eg);
    ADD_FAILURE() << "a different solver setting resumed";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
  request.automatic = true;
  EXPECT_EQ(choose_solver(request, changed, eg), "");
  EXPECT_EQ(changed.file.settings.substeps, scene.file.settings.substeps);
}

// A dead end's unresolved error (docs/SECONDARY_GRAPH.md, "Which dead end next") is its state's
// distance to the nearest OTHER state at the node, newer ones included, so the reported worst falls
// when a state lands near an old dead end (it used to stay at the distance to the nearest older
// state forever).
TEST(Explore, UnresolvedErrorIsTheDistanceToTheNearestOtherStateAtItsNode) {
  const CharacterScene scene = small_scene();
  const std::string path = temp_db("unresolved");
  ExploreOptions options;
  options.epsilon = 0.0005;  // nothing links: every clip end is a new state
  options.max_frames = 400;
  const ExploreReport report = run(scene, path, options);
  ASSERT_GT(report.dead_ends, 0);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::StoredState> states;
  std::vector<db::ClothClip> clips;
  EXPECT_EQ(r.cloth_states(&states, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  std::vector<std::vector<float>> x(states.size()), v(states.size());
  codec::DecodeScratch scratch;
  for (size_t i = 0; i < states.size(); ++i)
    ASSERT_EQ(r.read_state(states[i].id, &x[i], &v[i], scratch, &err), db::Status::Ok);
  double worst = 0;
  for (size_t i = 0; i < states.size(); ++i) {
    int clips_from = 0;
    for (const auto& c : clips) clips_from += c.start_state == states[i].id;
    if (clips_from == 2) continue;  // both ways out have cloth: no dead end
    double nearest = INFINITY;
    for (size_t j = 0; j < states.size(); ++j)
      if (j != i) nearest = std::min(nearest, db::state_distance(x[i], v[i], x[j], v[j], 1.0 / 30));
    if (std::isfinite(nearest)) worst = std::max(worst, nearest);
  }
  EXPECT_NEAR(report.worst_error, worst, 1e-12);
  EXPECT_NEAR(report.weighted_worst_error, worst, 1e-12);  // every edge has reach 1 here
  EXPECT_EQ(report.linked_fraction, 0.0);
}

// Every edge's blend error recomputed (docs/notebook/tests-that-can-fail.md), on a graph of two
// nodes, independently of the figure the explorer stored: each clip's job is run again from its
// stored start state (giving the stored clip, blob for blob), and the state distance from its end
// to the state its edge lands on is the recorded blend error, at most epsilon; the landing state is
// at the edge's end node; and the stored clip's last frame is that near the state in position too
// (the position part of the distance), within the codec's bound.
TEST(Explore, EveryEdgeErrorRecomputedFromTheClipEndOnTwoNodes) {
  const CharacterScene scene = small_scene();
  const ExploreGraph graph = two_node_graph(scene);
  const std::string path = temp_db("two_nodes");
  ExploreOptions options;
  options.epsilon = 0.02;
  options.max_frames = 400;  // the turned node converges slowly; a few dozen clips are enough
  const ExploreReport report = run_graph(scene, graph, path, options);
  ASSERT_GT(report.clips, 10);
  expect_checks(path);

  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::StoredState> states;
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  std::vector<db::PrimaryClip> primary;
  ASSERT_EQ(r.cloth_states(&states, &err), db::Status::Ok);
  ASSERT_EQ(r.cloth_clips(&clips, &err), db::Status::Ok);
  ASSERT_EQ(r.cloth_edges(&edges, &err), db::Status::Ok);
  ASSERT_EQ(r.primary_clips(&primary, &err), db::Status::Ok);
  // Graph edge of each primary clip (by name), and the node each state is at (node-anchor rule:
  // a state is stored under the first edge leaving its node).
  std::map<int64_t, int> edge_of;
  for (const auto& p : primary)
    for (size_t e = 0; e < graph.edges.size(); ++e)
      if (graph.edges[e].name == p.name) edge_of[p.id] = static_cast<int>(e);
  ASSERT_EQ(edge_of.size(), graph.edges.size());
  std::map<int64_t, int> node_of;
  std::map<int64_t, std::pair<std::vector<float>, std::vector<float>>> state;
  codec::DecodeScratch scratch;
  std::set<int> nodes;
  for (const auto& s : states) {
    node_of[s.id] = graph.edges[static_cast<size_t>(edge_of.at(s.primary_clip))].from_node;
    nodes.insert(node_of[s.id]);
    auto& [x, v] = state[s.id];
    ASSERT_EQ(r.read_state(s.id, &x, &v, scratch, &err), db::Status::Ok);
  }
  EXPECT_EQ(nodes.size(), 2u) << "states at both nodes";
  std::map<int64_t, const db::ClothClip*> clip_by_id;
  for (const auto& c : clips) clip_by_id[c.id] = &c;
  ASSERT_EQ(edges.size(), clips.size());
  const double tau = 1.0 / graph.rate, bound = r.codec().position_bound;
  int linked = 0;
  for (const auto& e : edges) {
    const db::ClothClip& c = *clip_by_id.at(e.from_clip);
    const int g = edge_of.at(c.primary_clip);
    EXPECT_EQ(node_of.at(c.start_state), graph.edges[static_cast<size_t>(g)].from_node);
    EXPECT_EQ(node_of.at(e.to_state), graph.edges[static_cast<size_t>(g)].to_node)
        << "clip " << c.id << " lands at a state of the other node";
    JobInput job;
    job.edge = g;
    job.x = state.at(c.start_state).first;
    job.v = state.at(c.start_state).second;
    job.solver = scene.file.solver;
    job.settings = scene.file.settings;
    job.settings.threads = 1;
    job.codec = r.codec();
    job.epsilon = options.epsilon;
    const JobResult again = run_job(scene, graph, job);
    ASSERT_TRUE(again.stable) << again.message;
    std::vector<uint8_t> stored;
    ASSERT_EQ(r.clip_blob(c.id, &stored, &err), db::Status::Ok);
    EXPECT_TRUE(again.clip_blob == stored) << "clip " << c.id << " is not what its job makes";
    std::vector<float> end_x, end_v, frames;
    ASSERT_EQ(
        codec::decode_all(again.end_x_blob.data(), again.end_x_blob.size(), end_x, scratch, &err),
        db::Status::Ok);
    ASSERT_EQ(
        codec::decode_all(again.end_v_blob.data(), again.end_v_blob.size(), end_v, scratch, &err),
        db::Status::Ok);
    const auto& [tx, tv] = state.at(e.to_state);
    const double d = db::state_distance(end_x, end_v, tx, tv, tau);
    EXPECT_NEAR(d, e.blend_error, 1e-12) << "clip " << c.id << " -> state " << e.to_state;
    EXPECT_LE(d, options.epsilon) << "clip " << c.id;
    linked += d > 0;
    // The stored clip's last frame: its RMS position distance to the state is at most the state
    // distance plus the codec's error on each side.
    ASSERT_EQ(codec::decode_all(stored.data(), stored.size(), frames, scratch, &err),
              db::Status::Ok);
    const size_t n = tx.size();
    ASSERT_GE(frames.size(), n);
    double sum = 0;
    for (size_t i = 0; i < n; i += 3) {
      double v2 = 0;
      for (size_t a = 0; a < 3; ++a) {
        const double dx = static_cast<double>(frames[frames.size() - n + i + a]) - tx[i + a];
        v2 += dx * dx;
      }
      sum += v2;
    }
    EXPECT_LE(std::sqrt(sum / static_cast<double>(n / 3)), d + 2 * std::sqrt(3.0) * bound)
        << "clip " << c.id;
  }
  EXPECT_GT(linked, 0) << "no clip linked to an existing state: nothing recomputed";
}

// No runtime fallback (docs/GUIDE.md#the-precompute-kim-et-al-2013): a run stopped by its budget
// links every dead end to the clip of the nearest state at its node that has one, with that state
// distance as the blend error; every way out of every state then plays without a fallback, and db
// check refuses a file that lost a link.
TEST(Explore, BudgetLimitedRunLinksEveryDeadEndSoPlaybackNeverFallsBack) {
  const CharacterScene scene = small_scene();
  const std::string path = temp_db("links");
  ExploreOptions options;
  options.epsilon = 0.0005;  // nothing links back: dead ends are left when the budget ends
  options.max_frames = 400;
  const ExploreReport report = run(scene, path, options);
  ASSERT_GT(report.dead_ends, 0);
  EXPECT_EQ(report.links, report.dead_ends);

  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::StoredState> states;
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothLink> links;
  std::vector<db::PrimaryClip> primary;
  EXPECT_EQ(r.cloth_states(&states, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_links(&links, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.primary_clips(&primary, &err), clothdb::Status::Ok);
  ASSERT_EQ(static_cast<int>(links.size()), report.dead_ends);
  std::map<int64_t, size_t> index;
  std::vector<std::vector<float>> x(states.size()), v(states.size());
  codec::DecodeScratch scratch;
  for (size_t i = 0; i < states.size(); ++i) {
    index[states[i].id] = i;
    ASSERT_EQ(r.read_state(states[i].id, &x[i], &v[i], scratch, &err), db::Status::Ok);
  }
  // Each (state, primary clip) has exactly one of a clip and a link; a link goes to the clip of
  // the nearest state that has one along the same primary clip, its distance recorded.
  for (const auto& s : states)
    for (const auto& p : primary) {
      int own = 0, linked = 0;
      for (const auto& c : clips) own += c.start_state == s.id && c.primary_clip == p.id;
      const db::ClothLink* link = nullptr;
      for (const auto& l : links)
        if (l.from_state == s.id && l.primary_clip == p.id) ++linked, link = &l;
      EXPECT_EQ(own + linked, 1) << "state " << s.id << " along " << p.name;
      if (!link) continue;
      double nearest = INFINITY;
      int64_t nearest_clip = 0;
      for (const auto& c : clips) {
        if (c.primary_clip != p.id) continue;
        const size_t a = index[s.id], b = index[c.start_state];
        const double d = db::state_distance(x[a], v[a], x[b], v[b], 1.0 / 30);
        if (d < nearest) nearest = d, nearest_clip = c.id;
      }
      EXPECT_EQ(link->to_clip, nearest_clip);
      EXPECT_NEAR(link->blend_error, nearest, 1e-12);
    }
  r.close();
  {
    const db::CheckReport check = db::check_database(path);
    for (const auto& problem : check.problems) ADD_FAILURE() << problem;
  }

  // Every clip, then each way out of the state it ends in: no fallback, no error.
  clothrt_db* rt = nullptr;
  ASSERT_EQ(clothrt_db_open(path.c_str(), nullptr, &rt), CLOTHRT_OK) << clothrt_last_open_errmsg();
  clothrt_player* player = nullptr;
  ASSERT_EQ(clothrt_player_create(rt, &player), CLOTHRT_OK);
  int transitions = 0;
  for (const auto& c : clips)
    for (const auto& p : primary) {
      ASSERT_EQ(clothrt_player_start_cloth_clip(player, c.id), CLOTHRT_OK)
          << clothrt_player_errmsg(player);
      ASSERT_EQ(clothrt_player_set_next(player, p.id), CLOTHRT_OK) << clothrt_player_errmsg(player);
      clothrt_frame_info before{}, info{};
      ASSERT_EQ(clothrt_player_info(player, &before), CLOTHRT_OK);
      for (int step = 0; step < 40; ++step) {
        ASSERT_EQ(clothrt_player_advance(player, 1.0 / 30), CLOTHRT_OK)
            << clothrt_player_errmsg(player);
        ASSERT_EQ(clothrt_player_info(player, &info), CLOTHRT_OK);
        if (info.transitions > before.transitions) break;
      }
      ASSERT_EQ(info.transitions, before.transitions + 1) << "clip " << c.id;
      EXPECT_EQ(info.primary_clip, p.id);
      EXPECT_EQ(info.fallback, 0) << "clip " << c.id << " then " << p.name;
      EXPECT_EQ(info.fallbacks, before.fallbacks);
      ++transitions;
    }
  EXPECT_EQ(transitions, static_cast<int>(clips.size() * primary.size()));
  clothrt_stats stats{};
  ASSERT_EQ(clothrt_db_stats(rt, &stats), CLOTHRT_OK);
  EXPECT_EQ(stats.fallbacks_resolved, 0u);
  clothrt_player_destroy(player);
  clothrt_db_close(rt);

  // A file that lost one link: db check names the dead end.
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    ASSERT_EQ(
        sqlite3_exec(raw, "DELETE FROM cloth_link WHERE id = (SELECT min(id) FROM cloth_link)",
                     nullptr, nullptr, nullptr),
        SQLITE_OK);
    sqlite3_close(raw);
  }
  const db::CheckReport check = db::check_database(path);
  bool named = false;
  for (const auto& problem : check.problems)
    named |= problem.find("neither a clip nor a link") != std::string::npos;
  EXPECT_TRUE(named) << "db check did not report the missing link";
}

// The steered tail against the unsteered one (docs/notebook/tests-that-can-fail.md): the job that
// made a steered clip is run again with and without its target, and over the last K frames each
// frame's movement (the largest vertex displacement from the frame before) may exceed the unsteered
// tail's by at most the share of the end's offset to the target that the pull's ramp brings in one
// frame: the smoothstep over K frames rises by at most 1.5 / K a frame (measured on this scene: at
// most half of that). A pull that arrives in one frame (the whole offset at
// the last frame) exceeds it. Also: the job run again gives the stored clip, blob for blob.
// Returns 1 when the tail was compared.
int expect_steered_tail_moves_like_the_unsteered_one(const CharacterScene& scene, db::Reader& r,
                                                     const db::ClothClip& clip,
                                                     const db::ClipSteering& st, double epsilon) {
  const ExploreGraph graph = small_graph(scene);
  std::vector<db::PrimaryClip> primary;
  db::Error err;
  EXPECT_EQ(r.primary_clips(&primary, &err), db::Status::Ok);
  JobInput job;
  job.edge = -1;
  for (const auto& p : primary)
    if (p.id == clip.primary_clip)
      for (size_t e = 0; e < graph.edges.size(); ++e)
        if (graph.edges[e].name == p.name) job.edge = static_cast<int>(e);
  EXPECT_GE(job.edge, 0) << "clip " << clip.id << ": primary clip " << clip.primary_clip;
  if (job.edge < 0) return 0;
  codec::DecodeScratch scratch;
  SteerTarget target;
  target.state = st.target_state;
  EXPECT_EQ(r.read_state(clip.start_state, &job.x, &job.v, scratch, &err), db::Status::Ok);
  EXPECT_EQ(r.read_state(st.target_state, &target.x, &target.v, scratch, &err), db::Status::Ok);
  job.solver = scene.file.solver;
  job.settings = scene.file.settings;
  job.settings.threads = 1;
  job.codec = r.codec();
  job.epsilon = epsilon;
  const JobResult unsteered = run_job(scene, graph, job);
  job.targets = {target};
  const JobResult steered = run_job(scene, graph, job);
  EXPECT_TRUE(unsteered.stable) << unsteered.message;
  EXPECT_TRUE(steered.stable) << steered.message;
  EXPECT_EQ(steered.steer_target, st.target_state)
      << "clip " << clip.id << " was not steered again";
  EXPECT_EQ(unsteered.steer_target, 0);
  std::vector<uint8_t> stored;
  EXPECT_EQ(r.clip_blob(clip.id, &stored, &err), db::Status::Ok);
  EXPECT_TRUE(steered.clip_blob == stored) << "clip " << clip.id << " is not what its job makes";
  std::vector<float> s_frames, u_frames;
  EXPECT_EQ(codec::decode_all(steered.clip_blob.data(), steered.clip_blob.size(), s_frames, scratch,
                              &err),
            db::Status::Ok);
  EXPECT_EQ(codec::decode_all(unsteered.clip_blob.data(), unsteered.clip_blob.size(), u_frames,
                              scratch, &err),
            db::Status::Ok);
  const size_t n = job.x.size();
  if (s_frames.size() != u_frames.size() || s_frames.size() < 2 * n) {
    ADD_FAILURE() << "clip " << clip.id << ": steered and unsteered clips differ in length";
    return 0;
  }
  const size_t frames = s_frames.size() / n;
  auto frame = [n](const std::vector<float>& f, size_t k) { return f.data() + k * n; };
  auto largest = [n](const float* a, const float* b) {
    double m = 0;
    for (size_t i = 0; i < n; i += 3) {
      const double dx = a[i] - b[i], dy = a[i + 1] - b[i + 1], dz = a[i + 2] - b[i + 2];
      m = std::max(m, std::sqrt(dx * dx + dy * dy + dz * dz));
    }
    return m;
  };
  // The offset the pull closes: the unsteered end to the target, largest over vertices.
  const double offset = largest(frame(u_frames, frames - 1), target.x.data());
  const size_t k = std::min(static_cast<size_t>(scene.file.steering.frames), frames - 2);
  const double per_frame = 1.5 / static_cast<double>(k) * offset;
  const double codec = 4 * r.codec().position_bound;  // two frames, each side within the bound
  for (size_t f = frames - k; f < frames; ++f) {
    const double s_move = largest(frame(s_frames, f - 1), frame(s_frames, f));
    const double u_move = largest(frame(u_frames, f - 1), frame(u_frames, f));
    EXPECT_LE(s_move, u_move + per_frame + codec)
        << "clip " << clip.id << ", frame " << f << " of " << frames << ": the steered tail moves "
        << s_move * 1e3 << " mm, the unsteered " << u_move * 1e3 << " mm, the offset to the target "
        << offset * 1e3 << " mm over " << k << " frames";
    if (std::getenv("CLOTHDB_TEST_VERBOSE"))
      std::printf("clip %lld frame %zu: steered %.2f mm unsteered %.2f mm offset %.2f mm\n",
                  static_cast<long long>(clip.id), f, s_move * 1e3, u_move * 1e3, offset * 1e3);
  }
  return 1;
}

// Steered clip ends (docs/GUIDE.md#the-precompute-kim-et-al-2013): with steering on, a clip whose
// end lands farther than epsilon but within max_mm of a state at its end node is pulled onto that
// state over its last frames, so it links with a blend within epsilon instead of making a new
// state; what the pull did is recorded.
TEST(Explore, SteeredClipsEndWithinEpsilonOfTheirTargetState) {
  CharacterScene scene = small_scene();
  ExploreOptions options;
  options.epsilon = 0.002;
  options.max_frames = 500;
  const std::string unsteered_path = temp_db("unsteered");
  const ExploreReport unsteered = run(scene, unsteered_path, options);
  EXPECT_EQ(unsteered.steered, 0);

  scene.file.steering.frames = 6;
  scene.file.steering.max_distance = 0.2;
  const std::string path = temp_db("steered");
  const ExploreReport report = run(scene, path, options);
  ASSERT_GT(report.steered, 0);
  // More clip ends link (fewer new states) than without steering, on the same budget.
  EXPECT_GT(report.linked_fraction, unsteered.linked_fraction);

  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::ClipSteering> steering;
  std::vector<db::ClothEdge> edges;
  std::vector<db::ClothClip> clips;
  ASSERT_EQ(r.clip_steering(&steering, &err), db::Status::Ok);
  EXPECT_EQ(r.cloth_edges(&edges, &err), clothdb::Status::Ok);
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  EXPECT_EQ(static_cast<int>(steering.size()), report.steered);
  int tails = 0;
  for (const auto& st : steering) {
    EXPECT_GT(st.distance, options.epsilon);  // ends already within epsilon are not steered
    EXPECT_LE(st.distance, scene.file.steering.max_distance);
    EXPECT_GT(st.displacement, 0.0);
    EXPECT_NEAR(st.acceleration, st.displacement * 30 * 30, 1e-9);
    // It links within epsilon (to its target, or to a state nearer still) ...
    int found = 0;
    for (const auto& e : edges)
      if (e.from_clip == st.clip) {
        ++found;
        EXPECT_LE(e.blend_error, options.epsilon) << "clip " << st.clip;
      }
    EXPECT_EQ(found, 1);
    // ... and its last frame, as stored, is on the target state: the RMS position distance (the
    // position part of the state distance) within the codec's bound.
    const db::ClothClip* clip = nullptr;
    for (const auto& c : clips)
      if (c.id == st.clip) clip = &c;
    ASSERT_NE(clip, nullptr);
    std::vector<uint8_t> blob;
    ASSERT_EQ(r.clip_blob(clip->id, &blob, &err), db::Status::Ok);
    std::vector<float> frames, tx, tv;
    codec::DecodeScratch scratch;
    ASSERT_EQ(codec::decode_all(blob.data(), blob.size(), frames, scratch, &err), db::Status::Ok);
    ASSERT_EQ(r.read_state(st.target_state, &tx, &tv, scratch, &err), db::Status::Ok);
    const size_t n = tx.size();
    double sum = 0;
    for (size_t i = 0; i < n; ++i) {
      const double d = frames[frames.size() - n + i] - tx[i];
      sum += d * d;
    }
    EXPECT_LE(std::sqrt(sum / static_cast<double>(n / 3)), 2 * r.codec().position_bound)
        << "clip " << st.clip;
    tails += expect_steered_tail_moves_like_the_unsteered_one(scene, r, *clip, st, options.epsilon);
  }
  EXPECT_EQ(tails, static_cast<int>(steering.size()));
  r.close();
  const db::CheckReport check = db::check_database(path);
  for (const auto& problem : check.problems) ADD_FAILURE() << problem;
}

namespace {

std::vector<char> file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Makes every read of `table` fail (SQLITE_CORRUPT) and nothing else: the first byte of its root
// page, the b-tree page type, becomes 0, which no page type has. The schema, meta and the other
// tables still read.
void corrupt_table(const std::string& path, const char* table) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* s = nullptr;
  const std::string sql =
      std::string("SELECT rootpage FROM sqlite_master WHERE type = 'table' AND name = '") + table +
      "'";
  ASSERT_EQ(sqlite3_prepare_v2(db, sql.c_str(), -1, &s, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(s), SQLITE_ROW);
  const int64_t root = sqlite3_column_int64(s, 0);
  sqlite3_finalize(s);
  ASSERT_EQ(sqlite3_prepare_v2(db, "PRAGMA page_size", -1, &s, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(s), SQLITE_ROW);
  const int64_t page_size = sqlite3_column_int64(s, 0);
  sqlite3_finalize(s);
  sqlite3_close(db);
  ASSERT_GT(root, 1);  // page 1 starts with the file header
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp((root - 1) * page_size);
  f.put(0);
  ASSERT_TRUE(f.good());
}

}  // namespace

// Every read error surfaces: a resumed run that cannot read the states it must continue from
// stops with an error naming the file and the table, and writes nothing (a run that took the
// failed read for an empty table would settle again and store a second start state).
TEST(Explore, ResumeThatCannotReadTheStatesFailsAndLeavesTheFileAsItWas) {
  const CharacterScene scene = small_scene();
  const std::string path = temp_db("unreadable");
  ExploreOptions options;
  options.epsilon = 0.02;
  options.batch = 2;
  options.max_frames = 30;
  ASSERT_FALSE(run(scene, path, options).converged);
  ASSERT_FALSE(std::filesystem::exists(path + "-wal"));  // checkpointed: the file is all there is
  corrupt_table(path, "cloth_state");
  const std::vector<char> before = file_bytes(path);
  options.max_frames = 0;
  try {
    run(scene, path, options);
    ADD_FAILURE() << "a resume that could not read cloth_state ran";
  } catch (const std::exception& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find(path), std::string::npos) << message;
    EXPECT_NE(message.find("cloth_state"), std::string::npos) << message;
  }
  EXPECT_EQ(file_bytes(path), before);
  EXPECT_TRUE(!std::filesystem::exists(path + "-wal") ||
              std::filesystem::file_size(path + "-wal") == 0);
}

// A dead end whose state is alone at its node has no unresolved error yet (Kim et al.'s error is a
// distance to another state there): the curve counts it as unexplored and never as 0 mm, which
// made the curve rise from 0 over a run. On a graph of two nodes (0 -> 1, 1 -> 0, 1 -> 1), the
// first clip's end is the first state at node 1: both its ways out are unexplored.
TEST(Explore, UnexploredWaysOutAreCountedAndNeverReportedAsZero) {
  const CharacterScene scene = small_scene();
  const auto pose = clip_pose(scene.clips.front(), 0);
  ExploreGraph graph;
  graph.node_count = 2;
  graph.rate = 30;
  graph.edges.push_back({0, 1, "hold", std::vector<std::vector<JointPose>>(12, pose), 0});
  graph.edges.push_back({1, 0, "sway", sway(pose, 0.6, 16), 0});
  graph.edges.push_back({1, 1, "hold again", std::vector<std::vector<JointPose>>(10, pose), 0});
  const std::string path = temp_db("unexplored");
  ExploreOptions options;
  options.epsilon = 0.02;
  options.batch = 1;
  options.max_frames = 1;  // one clip
  options.progress = false;
  std::vector<CurvePoint> curve;
  {
    db::Writer writer = db::Writer::create(path);
    prepare_database(writer, scene, graph, "{}");
    curve = explore(scene, graph, writer, options).curve;
  }
  ASSERT_EQ(curve.size(), 2u);
  // The start state alone at node 0 with its one way out, then the clip's end alone at node 1.
  EXPECT_EQ(curve[0].dead_ends, 1);
  EXPECT_EQ(curve[0].unexplored, 1);
  EXPECT_EQ(curve[1].dead_ends, 2);
  EXPECT_EQ(curve[1].unexplored, 2);
  for (const CurvePoint& p : curve) {
    EXPECT_TRUE(std::isnan(p.worst_error)) << p.worst_error;
    EXPECT_TRUE(std::isnan(p.mean_error)) << p.mean_error;
  }
  // The CSV leaves the error cells empty (unknown), not 0.
  std::istringstream csv(curve_csv(curve));
  std::string header, row;
  std::getline(csv, header);
  EXPECT_NE(header.find("dead_ends,unexplored,worst_error_mm"), std::string::npos) << header;
  while (std::getline(csv, row)) {
    std::vector<std::string> cells;
    std::istringstream fields(row);
    for (std::string c; std::getline(fields, c, ',');) cells.push_back(c);
    cells.resize(10);
    EXPECT_EQ(cells[3], cells[4]) << row;  // dead_ends == unexplored on both points
    for (size_t k : {5u, 6u, 7u}) EXPECT_EQ(cells[k], "") << row;
  }

  // Resumed to convergence: every point's count of unexplored ways out is within its dead ends,
  // a point whose dead ends are all unexplored has no error (NaN), and a point with a measured
  // dead end has a positive one (a state distance between two different states).
  options.max_frames = 0;
  ExploreReport done;
  {
    db::Writer writer = db::Writer::open(path);
    prepare_database(writer, scene, graph, "{}");
    done = explore(scene, graph, writer, options);
  }
  ASSERT_TRUE(done.converged);
  for (const CurvePoint& p : done.curve) {
    EXPECT_LE(p.unexplored, p.dead_ends);
    if (p.dead_ends == 0) {
      EXPECT_EQ(p.worst_error, 0.0);
    } else if (p.unexplored == p.dead_ends) {
      EXPECT_TRUE(std::isnan(p.worst_error));
    } else {
      EXPECT_GT(p.worst_error, 0.0);
      EXPECT_GT(p.mean_error, 0.0);
    }
  }
  EXPECT_EQ(done.curve.back().unexplored, 0);
}
