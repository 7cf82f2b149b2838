// The clothdb database: schema, WAL, writer/reader round trip, recognition of foreign and newer
// files, `db check`, and a writer killed mid-transaction.
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "clothrt.h"
#include "database/codec/codec.hpp"
#include "database/format/graph_index.hpp"
#include "database/store/basis_store.hpp"
#include "database/store/check.hpp"
#include "database/store/contract_store.hpp"
#include "database/store/dump.hpp"
#include "database/store/writer.hpp"
#include "database/store/writer_lock.hpp"
#include "runtime/tools/synthetic_db.hpp"
#include "support/temp_dir.hpp"

namespace clothdb::db {
namespace {

namespace fs = std::filesystem;

using clothdb::test::TempDir;

constexpr uint32_t kSide = 12;
constexpr uint32_t kVertices = kSide * kSide;

std::vector<float> sheet_frames(uint32_t frames, double phase) {
  std::vector<float> x(size_t(frames) * kVertices * 3);
  for (uint32_t f = 0; f < frames; ++f)
    for (uint32_t i = 0; i < kSide; ++i)
      for (uint32_t j = 0; j < kSide; ++j) {
        float* p = x.data() + (size_t(f) * kVertices + i * kSide + j) * 3;
        const double t = f / 30.0 + phase;
        p[0] = float(0.05 * i);
        p[1] = float(1.0 - 0.05 * j + 0.1 * std::sin(2 * t + 0.3 * i));
        p[2] = float(0.1 * std::cos(3 * t + 0.2 * j) * j / kSide);
      }
  return x;
}

Garment make_garment() {
  Garment g;
  for (uint32_t i = 0; i < kSide; ++i)
    for (uint32_t j = 0; j < kSide; ++j) {
      g.rest_positions.insert(g.rest_positions.end(),
                              {0.05f * float(i), 1.0f - 0.05f * float(j), 0.0f});
      if (i + 1 < kSide && j + 1 < kSide) {
        const uint32_t a = i * kSide + j, b = a + 1, c = a + kSide, d = c + 1;
        g.triangles.insert(g.triangles.end(), {a, b, c, b, d, c});
      }
    }
  g.material = R"({"density": 0.2, "stretch": 1e4})";
  g.solver = R"({"solver": "xpbd", "substeps": 20})";
  return g;
}

double max_diff(const float* a, const float* b, size_t n) {
  double m = 0;
  for (size_t i = 0; i < n; ++i) m = std::max(m, std::fabs(double(a[i]) - double(b[i])));
  return m;
}

// A small complete database: two primary clips in a loop (two transitions), one state per clip
// start, one cloth clip per primary clip and the edges between them.
struct Fixture {
  int64_t walk = 0, run_clip = 0, state0 = 0, state1 = 0, clip0 = 0, clip1 = 0, edge = 0;
  std::vector<float> frames0, frames1;
};

Fixture populate(Writer& w) {
  Fixture f;
  w.set_meta("scene", R"({"garment": "skirt.obj", "motions": ["walk.bvh"]})");
  w.put_garment(make_garment());
  const int64_t motion = w.add_motion_file("walk.bvh", "sha256:0123abcd");
  f.walk = w.add_primary_clip({0, "walk", motion, 0, 40, 30.0});
  f.run_clip = w.add_primary_clip({0, "run", motion, 40, 30, 30.0});
  w.add_primary_transition({0, f.walk, 39, f.run_clip, 0, 4, 0.25});
  // And back: clip1's edge leads to state0 at walk's start, which must be run's end node.
  w.add_primary_transition({0, f.run_clip, 29, f.walk, 0, 4, 0.25});
  const int64_t run = w.begin_run(R"({"solver": "xpbd"})", "test-host");
  Writer::Transaction t(w);
  f.frames0 = sheet_frames(40, 0.0);
  f.frames1 = sheet_frames(30, 1.0);
  std::vector<float> velocities(kVertices * 3, 0.01f);
  f.state0 = w.add_cloth_state(f.walk, 0, f.frames0.data(), velocities.data(), kVertices, run);
  f.clip0 = w.add_cloth_clip({f.state0, f.walk, 0, 0.02, 0.001, ClipStatus::Ok, run},
                             f.frames0.data(), 40, kVertices);
  f.state1 = w.add_cloth_state(f.run_clip, 0, f.frames1.data(), velocities.data(), kVertices, run,
                               f.clip0);
  f.clip1 = w.add_cloth_clip({f.state1, f.run_clip, 0, 0.03, 0.0, ClipStatus::Flagged, run},
                             f.frames1.data(), 30, kVertices);
  f.edge = w.add_cloth_edge(f.clip0, f.state1, 0.004);
  w.add_cloth_edge(f.clip1, f.state0, 0.02);
  t.commit();
  w.finish_run(run, 12.5, "two clips");
  return f;
}

void exec_raw(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* msg = nullptr;
  const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &msg);
  EXPECT_EQ(rc, SQLITE_OK) << (msg ? msg : "");
  sqlite3_free(msg);
  sqlite3_close(db);
}

bool mentions(const CheckReport& r, const std::string& text) {
  for (const auto& p : r.problems)
    if (p.find(text) != std::string::npos) return true;
  return false;
}

TEST(Database, WriterReaderRoundTrip) {
  TempDir dir;
  const std::string path = dir.file("a.clothdb");
  Fixture f;
  {
    Writer w = Writer::create(path);
    f = populate(w);
  }
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok) << err.message;
  EXPECT_EQ(r.schema_version(), kSchemaVersion);
  EXPECT_DOUBLE_EQ(r.codec().position_bound, codec::kDefaultPositionBound);
  std::string value;
  ASSERT_EQ(r.meta("units", &value, &err), Status::Ok);
  EXPECT_NE(value.find("length m"), std::string::npos);
  ASSERT_EQ(r.meta("scene", &value, &err), Status::Ok);
  EXPECT_NE(value.find("skirt.obj"), std::string::npos);
  EXPECT_EQ(r.meta("nope", &value, &err), Status::NotFound);

  Garment g;
  ASSERT_EQ(r.garment(&g, &err), Status::Ok);
  const Garment expected = make_garment();
  EXPECT_EQ(g.triangles, expected.triangles);
  EXPECT_EQ(g.rest_positions, expected.rest_positions);
  EXPECT_EQ(g.solver, expected.solver);

  std::vector<MotionFile> motions;
  ASSERT_EQ(r.motion_files(&motions, &err), Status::Ok);
  ASSERT_EQ(motions.size(), 1u);
  EXPECT_EQ(motions[0].content_hash, "sha256:0123abcd");
  std::vector<PrimaryClip> clips;
  ASSERT_EQ(r.primary_clips(&clips, &err), Status::Ok);
  ASSERT_EQ(clips.size(), 2u);
  EXPECT_EQ(clips[1].name, "run");
  EXPECT_EQ(clips[1].first_frame, 40);
  std::vector<PrimaryTransition> transitions;
  ASSERT_EQ(r.primary_transitions(&transitions, &err), Status::Ok);
  ASSERT_EQ(transitions.size(), 2u);
  EXPECT_EQ(transitions[0].blend_frames, 4);

  std::vector<StoredState> states;
  ASSERT_EQ(r.cloth_states(&states, &err), Status::Ok);
  ASSERT_EQ(states.size(), 2u);
  EXPECT_EQ(states[1].source_clip, f.clip0);
  std::vector<ClothClip> cloth;
  ASSERT_EQ(r.cloth_clips(&cloth, &err), Status::Ok);
  ASSERT_EQ(cloth.size(), 2u);
  EXPECT_EQ(cloth[1].status, ClipStatus::Flagged);
  EXPECT_EQ(cloth[0].frame_count, 40);
  EXPECT_LE(cloth[0].max_error, cloth[0].error_bound);
  EXPECT_DOUBLE_EQ(cloth[0].max_strain, 0.02);
  std::vector<ClothEdge> edges;
  ASSERT_EQ(r.cloth_edges(&edges, &err), Status::Ok);
  ASSERT_EQ(edges.size(), 2u);
  EXPECT_EQ(edges[0].to_state, f.state1);
  EXPECT_DOUBLE_EQ(edges[0].blend_error, 0.004);
  std::vector<db::Run> runs;
  ASSERT_EQ(r.runs(&runs, &err), Status::Ok);
  ASSERT_EQ(runs.size(), 1u);
  EXPECT_DOUBLE_EQ(runs[0].cpu_seconds, 12.5);
  EXPECT_FALSE(runs[0].finished.empty());

  // Cloth frames and states decode within the file's bounds.
  std::vector<uint8_t> blob;
  ASSERT_EQ(r.clip_blob(f.clip0, &blob, &err), Status::Ok);
  codec::DecodeScratch scratch;
  std::vector<float> decoded;
  ASSERT_EQ(codec::decode_all(blob.data(), blob.size(), decoded, scratch, &err), Status::Ok);
  ASSERT_EQ(decoded.size(), f.frames0.size());
  EXPECT_LE(max_diff(decoded.data(), f.frames0.data(), decoded.size()), r.codec().position_bound);
  std::vector<float> pos, vel;
  ASSERT_EQ(r.read_state(f.state1, &pos, &vel, scratch, &err), Status::Ok);
  EXPECT_LE(max_diff(pos.data(), f.frames1.data(), pos.size()), r.codec().position_bound);
  for (float v : vel) EXPECT_NEAR(v, 0.01f, r.codec().velocity_bound);
  EXPECT_EQ(r.clip_blob(999, &blob, &err), Status::NotFound);
  EXPECT_NE(std::strstr(err.message, "999"), nullptr);

  const DatabaseInfo info = read_database_info(path);
  EXPECT_EQ(info.cloth_clips, 2u);
  EXPECT_EQ(info.cloth_frames, 70u);
  EXPECT_EQ(info.clips_flagged, 1u);
  EXPECT_EQ(info.garment_vertices, kVertices);
  EXPECT_GT(info.clip_raw_bytes, info.clip_blob_bytes);
  EXPECT_TRUE(check_database(path).ok());
}

// The codec's position bound is chosen when a file is made (`--position-bound`) and fixed after:
// opening an existing file with another bound is refused, naming the file and the field, and
// the file keeps its own.
TEST(Database, PositionBoundIsChosenAtCreationAndAnotherIsRefused) {
  TempDir dir;
  const std::string path = dir.file("bound.clothdb");
  { Writer w = Writer::open_or_create(path, 1e-4); }
  { Writer w = Writer::open_or_create(path, 1e-4); }  // the same bound: accepted
  { Writer w = Writer::open_or_create(path, 0.0); }   // no bound asked: the file's
  try {
    Writer w = Writer::open_or_create(path, 2e-4);
    FAIL() << "a different bound was accepted";
  } catch (const ClothdbError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("bound.clothdb"), std::string::npos) << what;
    EXPECT_NE(what.find("codec.position_bound is 0.1 mm"), std::string::npos) << what;
    EXPECT_NE(what.find("0.2 mm"), std::string::npos) << what;
  }
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok) << err.message;
  EXPECT_DOUBLE_EQ(r.codec().position_bound, 1e-4);
}

TEST(Database, UsesWalAndReadersSeeOnlyCommittedData) {
  TempDir dir;
  const std::string path = dir.file("wal.clothdb");
  Writer w = Writer::create(path);
  Fixture f = populate(w);
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok) << err.message;
  {
    sqlite3_stmt* s = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(r.handle(), "PRAGMA journal_mode", -1, &s, nullptr), SQLITE_OK);
    ASSERT_EQ(sqlite3_step(s), SQLITE_ROW);
    EXPECT_STREQ(reinterpret_cast<const char*>(sqlite3_column_text(s, 0)), "wal");
    sqlite3_finalize(s);
  }
  std::vector<ClothClip> clips;
  {
    Writer::Transaction t(w);
    w.add_cloth_clip({f.state0, f.walk, 0, 0, 0, ClipStatus::Ok, 0}, f.frames0.data(), 40,
                     kVertices);
    // The writer holds an open write transaction; the reader is not blocked and sees 2 clips.
    ASSERT_EQ(r.cloth_clips(&clips, &err), Status::Ok) << err.message;
    EXPECT_EQ(clips.size(), 2u);
    t.commit();
  }
  ASSERT_EQ(r.cloth_clips(&clips, &err), Status::Ok);
  EXPECT_EQ(clips.size(), 3u);
  {
    Writer::Transaction t(w);
    w.add_cloth_edge(f.clip1, f.state1, 0.1);
  }  // not committed: rolled back
  std::vector<ClothEdge> edges;
  ASSERT_EQ(r.cloth_edges(&edges, &err), Status::Ok);
  EXPECT_EQ(edges.size(), 2u);
}

TEST(Database, ForeignAndNewerFilesAreRecognised) {
  TempDir dir;
  Error err;
  Reader r;
  EXPECT_EQ(r.open(dir.file("missing.clothdb"), &err), Status::IoError);
  EXPECT_NE(std::strstr(err.message, "missing.clothdb"), nullptr);

  const std::string text = dir.file("notes.txt");
  std::ofstream(text) << "this is not a database, just some text that is long enough to matter\n";
  EXPECT_EQ(r.open(text, &err), Status::NotClothdb);
  EXPECT_NE(std::strstr(err.message, "not a clothdb database"), nullptr) << err.message;

  const std::string other = dir.file("other.sqlite");
  exec_raw(other, "CREATE TABLE t(x); INSERT INTO t VALUES(1);");
  EXPECT_EQ(r.open(other, &err), Status::NotClothdb);
  EXPECT_NE(std::strstr(err.message, "SQLite database but not a clothdb"), nullptr) << err.message;
  EXPECT_THROW(Writer::open(other), ClothdbError);
  EXPECT_FALSE(check_database(other).ok());
  EXPECT_FALSE(check_database(text).ok());
  // An empty file and one cut inside SQLite's header read as empty databases to SQLite: named as
  // what they are, not as "a SQLite database but not a clothdb one".
  const std::string empty = dir.file("empty.clothdb");
  std::ofstream{empty};
  EXPECT_EQ(r.open(empty, &err), Status::NotClothdb);
  EXPECT_NE(std::strstr(err.message,
                        "empty.clothdb is not a clothdb database: an empty file (0 "
                        "bytes"),
            nullptr)
      << err.message;
  const std::string cut = dir.file("cut.clothdb");
  {
    std::ifstream in(other, std::ios::binary);
    std::string head(50, '\0');
    in.read(head.data(), 50);
    std::ofstream(cut, std::ios::binary) << head;
  }
  EXPECT_EQ(r.open(cut, &err), Status::NotClothdb);
  EXPECT_NE(std::strstr(err.message, "truncated, or not a database (50 bytes"), nullptr)
      << err.message;

  const std::string newer = dir.file("newer.clothdb");
  { Writer::create(newer); }
  exec_raw(newer, "PRAGMA user_version = " + std::to_string(kSchemaVersion + 1));
  EXPECT_EQ(r.open(newer, &err), Status::NewerVersion);
  EXPECT_NE(std::strstr(err.message, "newer"), nullptr) << err.message;
  try {
    Writer::open(newer);
    FAIL() << "newer file opened for writing";
  } catch (const ClothdbError& e) {
    EXPECT_EQ(e.status(), Status::NewerVersion);
  }
  const CheckReport report = check_database(newer);
  ASSERT_FALSE(report.ok());
  EXPECT_NE(report.problems[0].find("newer"), std::string::npos);

  // Creating over an existing file is refused.
  EXPECT_THROW(Writer::create(other), ClothdbError);
}

TEST(Database, WriterRejectsInconsistentData) {
  TempDir dir;
  Writer w = Writer::create(dir.file("w.clothdb"));
  Fixture f = populate(w);
  std::vector<float> small(3 * 10, 0.0f);
  EXPECT_THROW(
      w.add_cloth_clip({f.state0, f.walk, 0, 0, 0, ClipStatus::Ok, 0}, small.data(), 1, 10),
      ClothdbError);
  // Foreign keys: an edge to a state that does not exist.
  try {
    w.add_cloth_edge(f.clip0, 12345, 0.0);
    FAIL() << "dangling edge accepted";
  } catch (const ClothdbError& e) {
    EXPECT_NE(std::string(e.what()).find("w.clothdb"), std::string::npos) << e.what();
  }
  EXPECT_THROW(w.add_primary_clip({0, "walk", 0, 0, 10, 30}), ClothdbError);  // duplicate name
  EXPECT_THROW(w.add_primary_clip({0, "bad", 0, 0, 0, 30}), ClothdbError);    // no frames
  EXPECT_THROW(w.finish_run(777, 1.0), ClothdbError);
}

TEST(Database, EditLogUndoesInOrder) {
  TempDir dir;
  const std::string path = dir.file("e.clothdb");
  Writer w = Writer::create(path);
  Fixture f = populate(w);
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok);
  std::vector<uint8_t> original, edited, restored;
  ASSERT_EQ(r.clip_blob(f.clip0, &original, &err), Status::Ok);

  {
    Writer::Edit e(w, f.clip0, "flag", "ana");
    w.set_clip_status_unlogged(f.clip0, ClipStatus::Flagged);
    e.commit("pokes through hip");
  }
  std::vector<float> fixed = f.frames0;
  for (size_t i = 2; i < fixed.size(); i += 3) fixed[i] += 0.01f;  // push the cloth out by 1 cm
  {
    Writer::Edit e(w, f.clip0, "import", "ana");
    double max_error = 0;
    w.replace_clip_blob(f.clip0, w.encode_clip(fixed.data(), 40, kVertices, &max_error), max_error,
                        ClipStatus::Edited);
    e.commit("pushed out of the hip");
  }
  ClothClip c;
  ASSERT_EQ(r.cloth_clip(f.clip0, &c, &err), Status::Ok);
  EXPECT_EQ(c.status, ClipStatus::Edited);
  ASSERT_EQ(r.clip_blob(f.clip0, &edited, &err), Status::Ok);
  EXPECT_NE(edited, original);

  // Newest first: the import, then the flag.
  EXPECT_EQ(w.undo_last("ben").action, "import");
  ASSERT_EQ(r.clip_blob(f.clip0, &restored, &err), Status::Ok);
  EXPECT_EQ(restored, original);
  ASSERT_EQ(r.cloth_clip(f.clip0, &c, &err), Status::Ok);
  EXPECT_EQ(c.status, ClipStatus::Flagged);
  EXPECT_EQ(w.undo_last("ben").action, "flag");
  ASSERT_EQ(r.cloth_clip(f.clip0, &c, &err), Status::Ok);
  EXPECT_EQ(c.status, ClipStatus::Ok);
  EXPECT_THROW(w.undo_last("ben"), ClothdbError);  // nothing left to undo

  std::vector<EditLogEntry> log;
  ASSERT_EQ(r.edit_log(&log, &err), Status::Ok);
  ASSERT_EQ(log.size(), 4u);
  EXPECT_EQ(log[0].author, "ana");
  EXPECT_EQ(log[1].action, "import");
  EXPECT_TRUE(log[1].has_changeset);
  EXPECT_EQ(log[2].action, "undo");
  EXPECT_EQ(log[3].action, "undo");
  EXPECT_TRUE(check_database(path).ok());
}

TEST(Database, CheckFindsCorruptBlobsAndDanglingEdges) {
  TempDir dir;
  const std::string path = dir.file("c.clothdb");
  Fixture f;
  {
    Writer w = Writer::create(path);
    f = populate(w);
  }
  ASSERT_TRUE(check_database(path).ok());
  // Flip one byte in the middle of a clip blob (SQLite's own pages stay consistent).
  exec_raw(path,
           "UPDATE cloth_clip SET frames = substr(frames, 1, 200) || "
           "x'ff' || substr(frames, 202) WHERE id = " +
               std::to_string(f.clip1));
  // A dangling edge, as another tool with foreign keys off could leave it.
  exec_raw(path,
           "PRAGMA foreign_keys = OFF; INSERT INTO cloth_edge(from_clip, to_state, "
           "blend_error) VALUES(" +
               std::to_string(f.clip0) + ", 4242, 0.0);");
  // A truncated state blob.
  exec_raw(path, "UPDATE cloth_state SET velocities = substr(velocities, 1, 50) WHERE id = " +
                     std::to_string(f.state0));
  const CheckReport report = check_database(path);
  EXPECT_FALSE(report.ok());
  EXPECT_TRUE(mentions(report, "cloth clip " + std::to_string(f.clip1))) << report.problems[0];
  EXPECT_TRUE(mentions(report, "checksum"));
  EXPECT_TRUE(mentions(report, "to state 4242 does not exist"));
  EXPECT_TRUE(mentions(report, "velocities: frame blob truncated"));
  EXPECT_FALSE(mentions(report, "cloth clip " + std::to_string(f.clip0) + ":"));

  // The reader refuses the damaged clip with a clear error, never garbage.
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok);
  std::vector<uint8_t> blob;
  ASSERT_EQ(r.clip_blob(f.clip1, &blob, &err), Status::Ok);
  codec::DecodeScratch scratch;
  std::vector<float> out;
  EXPECT_EQ(codec::decode_all(blob.data(), blob.size(), out, scratch, &err),
            Status::ChecksumMismatch);
}

TEST(Database, CheckReportsADamagedFile) {
  TempDir dir;
  const std::string path = dir.file("d.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  // Checkpointed and closed: all data is in the main file. Overwrite a page in the middle.
  const auto size = fs::file_size(path);
  {
    std::fstream file(path, std::ios::in | std::ios::out | std::ios::binary);
    file.seekp(std::streamoff(size / 2));
    std::vector<char> junk(4096);
    std::mt19937 rng(3);
    for (auto& c : junk) c = char(rng());
    file.write(junk.data(), std::streamsize(junk.size()));
  }
  EXPECT_FALSE(check_database(path).ok());
  // Truncated to a few pages: an error, not a crash.
  fs::resize_file(path, 3000);
  EXPECT_FALSE(check_database(path).ok());
}

// Child process: writes clips one transaction at a time, reporting each committed id on `fd`.
// With stop_after >= 0 it then starts one more transaction, writes into it and _exit()s without
// committing; otherwise it writes until killed.
[[noreturn]] void child_writer(const std::string& path, int fd, int stop_after) {
  try {
    Writer w = Writer::open(path);
    Reader r;
    Error err;
    if (r.open(path, &err) != Status::Ok) _exit(3);
    std::vector<StoredState> states;
    std::vector<PrimaryClip> clips;
    if (r.cloth_states(&states, &err) != Status::Ok || r.primary_clips(&clips, &err) != Status::Ok)
      _exit(3);
    const auto frames = sheet_frames(40, 0.5);
    for (int i = 0;; ++i) {
      Writer::Transaction t(w);
      const int64_t id =
          w.add_cloth_clip({states[0].id, clips[0].id, 0, 0.0, 0.0, ClipStatus::Ok, 0},
                           frames.data(), 40, kVertices);
      w.add_cloth_edge(id, states[1].id, 0.001);
      if (stop_after >= 0 && i == stop_after) _exit(0);  // mid-transaction, nothing committed
      t.commit();
      if (write(fd, &id, sizeof id) != sizeof id) _exit(4);
    }
  } catch (...) {
    _exit(5);
  }
}

// Reads the ids the child reported committed.
std::vector<int64_t> read_ids(int fd) {
  std::vector<int64_t> ids;
  int64_t id;
  while (read(fd, &id, sizeof id) == sizeof id) ids.push_back(id);
  return ids;
}

void expect_consistent_with(const std::string& path, const std::vector<int64_t>& committed,
                            size_t clips_before) {
  const CheckReport report = check_database(path);
  EXPECT_TRUE(report.ok()) << (report.problems.empty() ? "" : report.problems[0]);
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok) << err.message;
  std::vector<ClothClip> clips;
  ASSERT_EQ(r.cloth_clips(&clips, &err), Status::Ok);
  // Every reported commit is there; at most one more (committed but killed before reporting).
  EXPECT_GE(clips.size(), clips_before + committed.size());
  EXPECT_LE(clips.size(), clips_before + committed.size() + 1);
  codec::DecodeScratch scratch;
  std::vector<uint8_t> blob;
  std::vector<float> out;
  const auto expected = sheet_frames(40, 0.5);
  for (int64_t id : committed) {
    ASSERT_EQ(r.clip_blob(id, &blob, &err), Status::Ok) << "clip " << id;
    ASSERT_EQ(codec::decode_all(blob.data(), blob.size(), out, scratch, &err), Status::Ok);
    EXPECT_LE(max_diff(out.data(), expected.data(), out.size()), r.codec().position_bound);
  }
}

TEST(Database, WriterExitingMidTransactionLeavesCommittedClips) {
  TempDir dir;
  const std::string path = dir.file("k.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    close(fds[0]);
    child_writer(path, fds[1], 3);
  }
  close(fds[1]);
  const auto ids = read_ids(fds[0]);
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
  ASSERT_EQ(ids.size(), 3u);
  expect_consistent_with(path, ids, 2);
}

TEST(Database, WriterKilledAtRandomMomentsLeavesCommittedClips) {
  TempDir dir;
  const std::string path = dir.file("kill.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  std::mt19937 rng(11);
  size_t clips_before = 2;
  size_t committed = 0;
  std::vector<int64_t> reported;
  for (int round = 0; round < 4; ++round) {
    int fds[2];
    ASSERT_EQ(pipe(fds), 0);
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      close(fds[0]);
      child_writer(path, fds[1], -1);
    }
    close(fds[1]);
    // Kill once the child has reported a number of commits (no sleep decides where the kill
    // lands: it keeps writing, so the kill comes in the middle of its next transactions).
    const size_t wait_for = 1 + rng() % 6;
    for (size_t seen = 0; seen < wait_for;) {
      int64_t id = 0;
      ASSERT_EQ(read(fds[0], &id, sizeof id), static_cast<ssize_t>(sizeof id))
          << "the writer stopped before its commit " << seen + 1;
      ++seen;
      ++committed;
      reported.push_back(id);
    }
    kill(pid, SIGKILL);
    int status = 0;
    waitpid(pid, &status, 0);
    EXPECT_TRUE(WIFSIGNALED(status));
    const auto rest = read_ids(fds[0]);
    close(fds[0]);
    committed += rest.size();
    reported.insert(reported.end(), rest.begin(), rest.end());
    expect_consistent_with(path, reported, clips_before);
    reported.clear();
    Reader r;
    Error err;
    ASSERT_EQ(r.open(path, &err), Status::Ok);
    std::vector<ClothClip> clips;
    ASSERT_EQ(r.cloth_clips(&clips, &err), Status::Ok);
    clips_before = clips.size();
  }
  // The kills landed while the writer was working, after at least one commit each.
  EXPECT_GE(committed, 4u);
  std::printf("writer killed 4 times after %zu committed clips in all\n", committed);
}

TEST(Database, QualityMetricsRoundTripWithUnknownAsNull) {
  TempDir dir;
  const std::string path = dir.file("metrics.clothdb");
  Fixture f;
  {
    Writer w = Writer::create(path);
    f = populate(w);
    ClipMetrics m;
    m.max_strain = 0.031;
    m.max_penetration = 0.002;
    m.mean_penetration = 0.0007;
    m.jitter = 0.00012;
    m.halved_steps = 3;
    m.worst_frame = 17;
    w.set_clip_metrics(f.clip0, m);
    w.set_edge_pop(f.edge, 0.0042);
    m.worst_frame = 40;  // clip 0 has frames 0..39
    EXPECT_THROW(w.set_clip_metrics(f.clip0, m), ClothdbError);
    EXPECT_THROW(w.set_clip_metrics(12345, ClipMetrics{}), ClothdbError);
    EXPECT_THROW(w.set_edge_pop(12345, 0.0), ClothdbError);
  }
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok) << err.message;
  std::vector<ClothClip> clips;
  ASSERT_EQ(r.cloth_clips(&clips, &err), Status::Ok);
  ASSERT_EQ(clips.size(), 2u);
  EXPECT_DOUBLE_EQ(clips[0].max_strain, 0.031);
  EXPECT_DOUBLE_EQ(clips[0].mean_penetration, 0.0007);
  EXPECT_DOUBLE_EQ(clips[0].jitter, 0.00012);
  EXPECT_EQ(clips[0].halved_steps, 3);
  EXPECT_EQ(clips[0].worst_frame, 17);
  // Written without them: unknown, not 0.
  EXPECT_TRUE(std::isnan(clips[1].mean_penetration));
  EXPECT_TRUE(std::isnan(clips[1].jitter));
  EXPECT_EQ(clips[1].halved_steps, -1);
  EXPECT_EQ(clips[1].worst_frame, -1);
  std::vector<ClothEdge> edges;
  ASSERT_EQ(r.cloth_edges(&edges, &err), Status::Ok);
  EXPECT_DOUBLE_EQ(edges[0].pop, 0.0042);
  EXPECT_TRUE(std::isnan(edges[1].pop));
  r.close();
  EXPECT_TRUE(check_database(path).ok());
  {
    Writer w = Writer::open(path);
    ClipMetrics bad = clips[1].metrics();
    bad.jitter = -0.001;
    w.set_clip_metrics(f.clip1, bad);
    w.set_edge_pop(f.edge, -1.0);
  }
  const CheckReport check = check_database(path);
  EXPECT_TRUE(mentions(check, "cloth clip " + std::to_string(f.clip1) + ": negative quality"));
  EXPECT_TRUE(mentions(check, "cloth edge " + std::to_string(f.edge) + ": negative pop"));
}

// ---- db check verifies what the runtime relies on (docs/DATABASE.md#clothdb-db-check-file) ----

std::string file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// The fixture database damaged by `sql`: check must fail naming `words`, the runtime must refuse
// to open it (`runtime_words` in its message; empty: the runtime plays it, e.g. by falling back),
// and neither may change the file.
void expect_refused(const std::string& sql, const std::string& words,
                    const std::string& runtime_words) {
  TempDir dir;
  const std::string path = dir.file("x.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  ASSERT_TRUE(check_database(path).ok()) << check_database(path).problems[0];
  exec_raw(path, "PRAGMA foreign_keys = OFF; " + sql);
  const std::string before = file_bytes(path);
  const CheckReport report = check_database(path);
  EXPECT_FALSE(report.ok()) << sql;
  EXPECT_TRUE(mentions(report, words))
      << sql << ": " << (report.problems.empty() ? "" : report.problems[0]);
  clothrt_db* db = nullptr;
  const int rc = clothrt_db_open(path.c_str(), nullptr, &db);
  if (!runtime_words.empty()) {
    EXPECT_NE(rc, CLOTHRT_OK) << sql;
    EXPECT_NE(std::string(clothrt_last_open_errmsg()).find(runtime_words), std::string::npos)
        << clothrt_last_open_errmsg();
  } else {
    EXPECT_EQ(rc, CLOTHRT_OK) << clothrt_last_open_errmsg();
  }
  clothrt_db_close(db);
  EXPECT_EQ(file_bytes(path), before) << "check or the runtime changed the file";
}

TEST(DatabaseCheck, DeletedGarmentRow) {
  expect_refused(
      "DELETE FROM garment;",
      "no garment row: the runtime cannot open this file (a file holding only a motion graph",
      "no garment");
}

TEST(DatabaseCheck, TruncatedTriangleArray) {
  expect_refused("UPDATE garment SET triangles = substr(triangles, 1, 100);",
                 "triangle array holds 100 bytes", "garment arrays do not match");
}

TEST(DatabaseCheck, TriangleIndexOutOfRange) {
  expect_refused("UPDATE garment SET triangles = x'ffffff7f' || substr(triangles, 5);",
                 "triangle 0: vertex index 2147483647 is out of range", "vertex index 2147483647");
}

TEST(DatabaseCheck, DeletedPrimaryTransition) {
  // walk -> run -> walk: without run -> walk, clip1's edge no longer lands at run's end node.
  expect_refused("DELETE FROM primary_transition WHERE from_frame = 29;",
                 "which is not at the end node of clip", "which is not at the end node of clip");
}

TEST(DatabaseCheck, TransitionNotAtTheClipsEnds) {
  expect_refused("UPDATE primary_transition SET from_frame = 5 WHERE from_frame = 39;",
                 "joins frame 5 of clip", "joins frame 5 of clip");
}

TEST(DatabaseCheck, EdgeNotLandingAtItsClipsEndNode) {
  // clip0 (along walk) ends where run starts; state0 is at walk's start.
  expect_refused(
      "UPDATE cloth_edge SET to_state = (SELECT start_state FROM cloth_clip WHERE id = "
      "cloth_edge.from_clip) WHERE blend_error = 0.004;",
      "which is not at the end node of clip", "which is not at the end node of clip");
}

TEST(DatabaseCheck, ClipWithoutAnEdgeOut) {
  expect_refused("DELETE FROM cloth_edge WHERE blend_error = 0.004;", "has no cloth edge out", "");
}

TEST(DatabaseCheck, UnknownMetaVersions) {
  for (const std::string& v :
       {std::to_string(kSchemaVersion + 1), std::string("abc"), std::string("-1"), std::string("")})
    expect_refused("UPDATE meta SET value = '" + v + "' WHERE key = 'format_version';",
                   "meta format_version is", "meta format_version is");
  // What a build that reads up to version N does with a file holding a version N + 1 blob (a
  // version 2 build with a version 3 file): refused at open, naming the key.
  const std::string newer = std::to_string(codec::kNewestFormatVersion + 1);
  expect_refused("UPDATE meta SET value = '" + newer + "' WHERE key = 'codec.format_version';",
                 "meta codec.format_version is " + newer + ", newer than this build reads",
                 "codec.format_version");
}

TEST(DatabaseCheck, StartClipNamingNothing) {
  expect_refused("INSERT INTO meta VALUES('start_clip', '4242');", "start_clip '4242'", "");
}

// The bound a clip was coded within is checked on every blob
// (docs/DATABASE.md#clothdb-db-check-file). A blob coded on a grid coarser than its row's recorded
// bound, or a measured encode error above it, fails the check (the runtime still plays such a file:
// the bound is a promise to the artist, not to the decoder).
TEST(DatabaseCheck, ClipCodedBeyondItsRecordedBound) {
  expect_refused("UPDATE cloth_clip SET error_bound = error_bound / 4;", "blob bound", "");
  expect_refused("UPDATE cloth_clip SET max_error = 2 * error_bound;", "measured error", "");
}

TEST(DatabaseCheck, MissingTransitionAtANodeAndUnexploredStates) {
  TempDir dir;
  const std::string path = dir.file("demo.clothdb");
  const synthetic::Built built = synthetic::build(path, synthetic::demo_spec(6));
  // The demo leaves one (state, way out) pair unexplored: a warning, not a problem.
  CheckReport report = check_database(path);
  EXPECT_TRUE(report.ok()) << report.problems[0];
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_NE(report.warnings[0].find("unexplored: state " + std::to_string(built.states[4]) +
                                    " has no clip along primary clip " +
                                    std::to_string(built.primary[2])),
            std::string::npos)
      << report.warnings[0];
  // Node 1 has two clips in (e0, e2) and two out (e1, e2): e0 -> e1 lost leaves the node joined
  // through the others, and check names the missing pair.
  exec_raw(path,
           "DELETE FROM primary_transition WHERE from_clip = " + std::to_string(built.primary[0]) +
               " AND to_clip = " + std::to_string(built.primary[1]) + ";");
  report = check_database(path);
  clothrt_db* db = nullptr;
  EXPECT_EQ(clothrt_db_open(path.c_str(), nullptr, &db), CLOTHRT_ERR_CORRUPT);
  // The runtime and check share the rule and its words (database/format/graph_index.hpp).
  EXPECT_NE(std::string(clothrt_last_open_errmsg())
                .find("primary transition missing from clip " + std::to_string(built.primary[0]) +
                      " to clip " + std::to_string(built.primary[1])),
            std::string::npos)
      << clothrt_last_open_errmsg();
  clothrt_db_close(db);
  EXPECT_TRUE(mentions(report, "primary transition: missing from clip " +
                                   std::to_string(built.primary[0]) + " to clip " +
                                   std::to_string(built.primary[1])))
      << (report.problems.empty() ? "" : report.problems[0]);
}

// ---- one writer per database (docs/DATABASE.md#durability-and-concurrency) --------------------

TEST(WriterLock, SecondProcessIsRefusedNamingTheHolder) {
  TempDir dir;
  const std::string path = dir.file("locked.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  EXPECT_FALSE(fs::exists(WriterLock::lock_path(path))) << "removed when the writer closes";
  int ready[2], done[2];
  ASSERT_EQ(pipe(ready), 0);
  ASSERT_EQ(pipe(done), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // Another process writing: holds a Writer until told to stop.
    try {
      Writer w = Writer::open(path);
      char c = 1;
      if (write(ready[1], &c, 1) != 1) _exit(3);
      if (read(done[0], &c, 1) != 1) _exit(4);
    } catch (...) {
      _exit(5);
    }
    _exit(0);
  }
  char c = 0;
  ASSERT_EQ(read(ready[0], &c, 1), 1);
  const std::string before = file_bytes(path);
  try {
    Writer w = Writer::open(path);
    ADD_FAILURE() << "a second writer was let in";
  } catch (const ClothdbError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(path + " is being written by another clothdb process (pid " +
                       std::to_string(child) + " on host "),
              std::string::npos)
        << msg;
    EXPECT_NE(msg.find(" since 20"), std::string::npos) << msg;
  }
  EXPECT_THROW(Writer::create(path), ClothdbError);
  EXPECT_EQ(file_bytes(path), before) << "the refused writer changed the file";
  // Readers are not writers: they still read.
  Reader r;
  Error err;
  EXPECT_EQ(r.open(path, &err), Status::Ok) << err.message;
  ASSERT_EQ(write(done[1], &c, 1), 1);
  int status = 0;
  waitpid(child, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  // Released with its holder: the next writer gets in.
  Writer w = Writer::open(path);
  EXPECT_TRUE(w.path() == path);
}

TEST(WriterLock, StaleLockOfAKilledRunIsTakenOver) {
  TempDir dir;
  const std::string path = dir.file("stale.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  // A run killed with SIGKILL while writing: its lock file stays, its lock does not.
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    try {
      Writer w = Writer::open(path);
      raise(SIGKILL);
    } catch (...) {
    }
    _exit(5);
  }
  int status = 0;
  waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status));
  ASSERT_TRUE(fs::exists(WriterLock::lock_path(path)));
  EXPECT_NE(WriterLock::holder(path).find("pid " + std::to_string(child)), std::string::npos);
  {
    Writer w = Writer::open(path);  // not refused
    EXPECT_NE(WriterLock::holder(path).find("pid " + std::to_string(getpid())), std::string::npos);
  }
  EXPECT_FALSE(fs::exists(WriterLock::lock_path(path)));
  EXPECT_TRUE(check_database(path).ok());
}

TEST(WriterLock, WritersInOneProcessShareTheLock) {
  TempDir dir;
  const std::string path = dir.file("shared.clothdb");
  Writer a = Writer::create(path);
  populate(a);
  {
    Writer b = Writer::open(path);
    b.set_meta("note", "second writer of the same process");
  }
  EXPECT_TRUE(fs::exists(WriterLock::lock_path(path))) << "still held by the first writer";
  a.set_meta("note", "first writer again");
}

// ---- one owner per fact (docs/DATABASE.md#who-owns-what) ----------------------------------------

// Storing a version 2 blob raises meta codec.format_version in the same transaction, so a runtime
// that reads only version 1 refuses the file at open (UnknownMetaVersions pins that refusal)
// instead of failing clip by clip.
TEST(Database, StoringAVersion2BlobRaisesTheFilesCodecVersion) {
  TempDir dir;
  const std::string path = dir.file("v2.clothdb");
  Writer w = Writer::create(path);
  const Fixture f = populate(w);
  auto codec_version = [&] {
    Reader r;
    Error err;
    EXPECT_EQ(r.open_borrowed(w.handle(), path, &err), Status::Ok) << err.message;
    return meta_text(r, meta::kCodecFormatVersion).value_or("");
  };
  EXPECT_EQ(codec_version(), "1");
  // A two-mode basis around the clip's first frame.
  std::vector<float> modes(2 * kVertices * 3, 0.0f);
  for (size_t i = 0; i < kVertices * 3; ++i) {
    modes[i] = float(std::sin(0.1 * double(i)));
    modes[kVertices * 3 + i] = float(std::cos(0.07 * double(i)));
  }
  codec::Basis basis = codec::make_basis(0, kVertices, f.frames0.data(), modes.data(), 2);
  basis.id = store_basis(w, basis, "test");
  codec::EncodeSettings settings = encode_settings(w.codec(), w.codec().position_bound);
  const std::vector<uint8_t> blob =
      codec::encode_v2(f.frames0.data(), 40, kVertices, basis, settings);
  codec::BlobInfo info;
  ASSERT_EQ(codec::read_info(blob.data(), blob.size(), &info, nullptr), Status::Ok);
  ASSERT_EQ(info.version, codec::kFormatVersionV2);
  w.add_cloth_clip_blob({f.state0, f.walk, 0, 0.02, 0.001, ClipStatus::Ok, 0}, blob, 0.0);
  EXPECT_EQ(codec_version(), "2");
  // A version 1 blob stored later does not lower it: the file still holds a version 2 blob.
  w.add_cloth_clip({f.state1, f.run_clip, 0, 0.03, 0.0, ClipStatus::Ok, 0}, f.frames1.data(), 30,
                   kVertices);
  EXPECT_EQ(codec_version(), "2");
  // A version 3 blob raises it to 3 (what an older build refuses, UnknownMetaVersions).
  codec::V3Settings v3;
  v3.contract = {0.002, 0.006, 0.0001};
  const std::vector<uint8_t> blob3 = codec::encode_v3(f.frames0.data(), 40, kVertices, basis, v3);
  w.add_cloth_clip_blob({f.state0, f.walk, 0, 0.02, 0.001, ClipStatus::Ok, 0}, blob3, 0.0);
  EXPECT_EQ(codec_version(), "3");
}

std::string dump_text(const std::string& path, const DumpOptions& options) {
  std::FILE* out = std::tmpfile();
  dump_database(path, options, out);
  std::string text(size_t(std::ftell(out)), '\0');
  std::rewind(out);
  const size_t n = std::fread(text.data(), 1, text.size(), out);
  std::fclose(out);
  text.resize(n);
  return text;
}

// db dump prints every table of the registry that the file has, by default, and masks exactly
// the columns and meta values it is told to.
TEST(Dump, CoversEveryTableOfTheRegistryAndMasksByName) {
  TempDir dir;
  const std::string path = dir.file("dump.clothdb");
  {
    Writer w = Writer::create(path);
    const Fixture f = populate(w);
    std::vector<float> mean(kVertices * 3, 0.0f), modes(kVertices * 3, 1.0f);
    store_basis(w, codec::make_basis(0, kVertices, mean.data(), modes.data(), 1), "test");
    store_clip_contract(w, f.clip0, {0.0005, 0.001, 0.00005}, {0.001, 0.003, 0.0001});
  }
  const std::string all = dump_text(path, {});
  for (const TableInfo& t : tables()) {
    std::string header = t.name;
    header.insert(header.begin(), '[');
    header.push_back(']');
    EXPECT_NE(all.find(header), std::string::npos) << t.name;
  }
  EXPECT_NE(all.find("'test-host'"), std::string::npos);
  EXPECT_NE(all.find("'created' '20"), std::string::npos);
  const std::string masked = dump_text(path, {{}, {"run.host", "meta.created"}});
  EXPECT_EQ(masked.find("'test-host'"), std::string::npos);
  EXPECT_NE(masked.find("'created' masked"), std::string::npos);
  EXPECT_NE(masked.find("'format' 'clothdb'"), std::string::npos) << "only the named key";
  EXPECT_THROW(dump_text(path, {{}, {"nosuchtable.x"}}), ClothdbError);
  EXPECT_THROW(dump_text(path, {{"nosuchtable"}, {}}), ClothdbError);
}

// The graph's rules have one owner: built from the same rows, the runtime's use (stop at the
// first finding) and check's (collect them all) see the same index and the same findings.
TEST(GraphIndex, StopsAtTheFirstFindingOrCollectsThemAll) {
  TempDir dir;
  const std::string path = dir.file("graph.clothdb");
  {
    Writer w = Writer::create(path);
    populate(w);
  }
  Reader r;
  Error err;
  ASSERT_EQ(r.open(path, &err), Status::Ok) << err.message;
  GraphRows rows;
  ASSERT_EQ(rows.read(r, &err), Status::Ok) << err.message;
  std::vector<std::string> found;
  auto collect = [&](const GraphFinding& f) {
    found.push_back(std::string(f.kind) + ": " + f.message);
    return true;
  };
  GraphIndex index;
  ASSERT_TRUE(index.build(rows, collect));
  EXPECT_TRUE(found.empty()) << found[0];
  EXPECT_EQ(index.nodes, 2);  // walk -> run -> walk
  ASSERT_EQ(index.primaries.size(), 2u);
  EXPECT_EQ(index.primaries[0].tgt_node, index.primaries[1].src_node);
  EXPECT_EQ(index.primaries[1].tgt_node, index.primaries[0].src_node);
  EXPECT_EQ(index.primaries[0].successors, std::vector<int>{1});
  EXPECT_EQ(index.clips[0].to_state, 1);
  // Two broken rules: a clip that does not span its primary clip (it is left out of the index,
  // so its edge then names a clip the index lacks: a third, dangling finding), and an edge that
  // lands away from its clip's end node.
  rows.clips[0].first_frame = 1;
  rows.edges[1].to_state = rows.states[1].id;  // clip1 ends at walk's start, state1 is at run's
  found.clear();
  std::vector<bool> dangling;
  EXPECT_TRUE(index.build(rows, [&](const GraphFinding& f) {
    found.push_back(std::string(f.kind) + ": " + f.message);
    dangling.push_back(f.dangling);
    return true;
  }));
  ASSERT_EQ(found.size(), 3u);
  EXPECT_NE(found[0].find("cloth clip: " + std::to_string(rows.clips[0].id) + ": covers frames 1"),
            std::string::npos)
      << found[0];
  EXPECT_TRUE(dangling[1]) << found[1];
  EXPECT_NE(found[2].find("which is not at the end node of clip"), std::string::npos) << found[2];
  EXPECT_FALSE(dangling[0] || dangling[2]);
  int seen = 0;
  EXPECT_FALSE(index.build(rows, [&](const GraphFinding&) { return ++seen, false; }));
  EXPECT_EQ(seen, 1);
}

}  // namespace
}  // namespace clothdb::db
