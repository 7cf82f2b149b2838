// Hand-editing clips (docs/GUIDE.md#fixing-a-bad-clip, precompute/edit/clip_edit.hpp): export and
// import, the continuity checks at both ends, re-simulation carried forward, delete with
// re-routing, and an undo that puts back every row. The database is a converged precompute of the
// small skirt of tests/data/mpi_small.json (CMU 01_01, 192 vertices, 10 nodes, 14 edges), made once
// by the `clothdb` executable and copied for each test.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "clothrt.h"
#include "database/format/checksum.hpp"
#include "database/store/check.hpp"
#include "database/store/writer.hpp"
#include "edit/clip_edit.hpp"
#include "exchange/point_cache.hpp"
#include "support/cli.hpp"
#include "support/db_rows.hpp"

namespace clothdb {
namespace {

const std::string kSource = CLOTHDB_SOURCE_DIR;

std::string work(const std::string& name) {
  // One folder per process: CTest runs each test in its own process, two at a time.
  const std::filesystem::path dir =
      std::filesystem::path(testing::TempDir()) / ("clothdb_edit_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  return (dir / name).string();
}

// Removes this process's folder when the tests are done.
class RemoveWorkFolder : public testing::Environment {
 public:
  void TearDown() override {
    std::error_code ec;
    std::filesystem::remove_all(std::filesystem::path(work("x")).parent_path(), ec);
  }
};
const testing::Environment* const kRemoveWorkFolder =
    testing::AddGlobalTestEnvironment(new RemoveWorkFolder);

// `clothdb args` (split at spaces); its output into *output.
int run_cli(const std::string& args, std::string* output = nullptr) {
  const test::CliResult r = test::run_clothdb(args, work("cli.log"));
  if (output) *output = r.output;
  return r.code;
}

// The converged base database, made once (--no-floor: the edits do not depend on the garment's
// error floor, which for this flared skirt is above the 10 mm used here).
const std::string& base_db() {
  static const std::string path = [] {
    const std::string p = work("base.db");
    test::remove_database(p);
    std::string out;
    const int rc = run_cli("precompute " + kSource + "/tests/data/mpi_small.json --db " + p +
                               " --epsilon 10 --batch 4 --threads 1 --quiet --no-floor",
                           &out);
    EXPECT_EQ(rc, 0) << out;
    EXPECT_NE(out.find("converged"), std::string::npos) << out;
    return p;
  }();
  return path;
}

std::string copy_db(const std::string& name) {
  const std::string to = work(name + ".db");
  for (const char* s : {"", "-wal", "-shm"}) {
    std::filesystem::remove(to + s);
    if (std::filesystem::exists(base_db() + s)) std::filesystem::copy_file(base_db() + s, to + s);
  }
  return to;
}

// Every row of every table but the edit log, blobs by checksum: what "the database content" is
// (tests/support/db_rows.hpp; nothing else left out: an edit and its undo run in one process).
std::vector<std::string> rows(const std::string& path) {
  test::RowsLeftOut left_out;
  left_out.tables = {"edit_log"};
  return test::every_row(path, left_out);
}

// The clip with the most frames (the one the tests edit): long enough to ramp.
int64_t long_clip(const std::string& path) {
  db::Reader r;
  db::Error err;
  EXPECT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::ClothClip> clips;
  EXPECT_EQ(r.cloth_clips(&clips, &err), clothdb::Status::Ok);
  int64_t best = 0;
  int frames = 0;
  for (const auto& c : clips)
    if (c.frame_count > frames && c.start_state != 1) frames = c.frame_count, best = c.id;
  return best;
}

std::vector<float> clip_frames(const std::string& path, int64_t clip) {
  db::Reader r;
  db::Error err;
  EXPECT_EQ(r.open(path, &err), db::Status::Ok);
  db::ClothClip row;
  return read_clip_frames(r, clip, &row);
}

// Plays every primary transition (each primary clip with cloth, into each successor with cloth)
// and a long random walk: every frame must have finite positions, no error, no fallback.
void expect_every_path_plays(const std::string& path) {
  clothrt_db* db = nullptr;
  ASSERT_EQ(clothrt_db_open(path.c_str(), nullptr, &db), CLOTHRT_OK) << clothrt_last_open_errmsg();
  const uint32_t n = clothrt_db_vertex_count(db);
  std::vector<float> x(size_t(n) * 3);
  clothrt_player* p = nullptr;
  ASSERT_EQ(clothrt_player_create(db, &p), CLOTHRT_OK);
  auto play = [&](double seconds, const std::string& what) {
    for (int k = 0; k < int(seconds * 30); ++k) {
      ASSERT_EQ(clothrt_player_advance(p, 1.0 / 30), CLOTHRT_OK)
          << what << clothrt_player_errmsg(p);
      ASSERT_EQ(clothrt_player_get_positions(p, x.data(), 12, nullptr), CLOTHRT_OK) << what;
      for (float v : x) ASSERT_TRUE(std::isfinite(v)) << what;
      clothrt_frame_info info;
      clothrt_player_info(p, &info);
      ASSERT_FALSE(info.holding) << what;
      ASSERT_EQ(info.fallbacks, 0u) << what << ": a state without cloth along the way taken";
    }
  };
  int transitions = 0;
  for (size_t i = 0; i < clothrt_db_clip_count(db); ++i) {
    clothrt_clip_info a;
    ASSERT_EQ(clothrt_db_clip_info(db, i, &a), CLOTHRT_OK);
    if (!a.has_cloth) continue;
    int64_t next[16];
    size_t count = 0;
    ASSERT_EQ(clothrt_db_successors(db, a.id, next, 16, &count), CLOTHRT_OK);
    for (size_t k = 0; k < std::min<size_t>(count, 16); ++k) {
      ASSERT_EQ(clothrt_player_start(p, a.id), CLOTHRT_OK);
      if (clothrt_player_set_next(p, next[k]) != CLOTHRT_OK) continue;  // no cloth along it
      play((a.frame_count + 12) / 30.0, std::string(a.name) + " -> " + std::to_string(next[k]));
      ++transitions;
    }
  }
  EXPECT_GT(transitions, 5);
  ASSERT_EQ(clothrt_player_start(p, 0), CLOTHRT_OK);
  ASSERT_EQ(clothrt_player_set_random(p, 1, 7), CLOTHRT_OK);
  play(60, "random walk");
  clothrt_player_destroy(p);
  clothrt_db_close(db);
}

void expect_consistent(const std::string& path) {
  const db::CheckReport check = db::check_database(path);
  EXPECT_TRUE(check.problems.empty()) << check.problems.front();
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  const DatabaseScene scene = load_database_scene(r);
  const std::vector<std::string> gaps = coverage_gaps(r, scene.graph);
  EXPECT_TRUE(gaps.empty()) << gaps.front();
  expect_every_path_plays(path);
}

TEST(Edit, TheBaseDatabaseIsConsistentAndCovered) {
  expect_consistent(base_db());
}

TEST(Edit, ExportThenImportUnchangedKeepsTheClipWithinTheCodecBound) {
  const std::string path = copy_db("roundtrip");
  const int64_t clip = long_clip(path);
  const std::vector<float> before = clip_frames(path, clip);
  std::string out;
  ASSERT_EQ(run_cli("clip export " + path + " " + std::to_string(clip) + " --out " +
                        work("roundtrip_export"),
                    &out),
            0)
      << out;
  EXPECT_TRUE(std::filesystem::exists(work("roundtrip_export") + "/body.pc2")) << out;
  ASSERT_EQ(
      run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("roundtrip_export"),
              &out),
      0)
      << out;
  const std::vector<float> after = clip_frames(path, clip);
  ASSERT_EQ(after.size(), before.size());
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  double worst = 0;
  for (size_t i = 0; i < before.size(); ++i)
    worst = std::max(worst, double(std::abs(after[i] - before[i])));
  EXPECT_LE(worst, r.codec().position_bound * (1 + 1e-6));
  db::ClothClip row;
  ASSERT_EQ(r.cloth_clip(clip, &row, &err), db::Status::Ok);
  EXPECT_EQ(row.status, db::ClipStatus::Edited);
  expect_consistent(path);
}

TEST(Edit, AnEditThatMovesTheEndBeyondEpsilonIsReportedWithItsEdgeAndChangesNothing) {
  const std::string path = copy_db("break");
  const int64_t clip = long_clip(path);
  const std::vector<std::string> before = rows(path);
  EditContext ctx = open_edit(path, "", 0, "test");
  std::vector<float> frames = clip_frames(path, clip);
  const size_t per_frame = size_t(ctx.scene.scene.model.vertex_count()) * 3;
  const int n = int(frames.size() / per_frame);
  // The last two frames 30 mm sideways: the end's position moves by 30 mm, its velocity not.
  for (int f = n - 2; f < n; ++f)
    for (size_t i = 0; i < per_frame; i += 3) frames[per_frame * f + i] += 0.030f;
  const ImportReport refused = import_clip(ctx, clip, frames, {});
  EXPECT_EQ(refused.edit, 0);
  EXPECT_NEAR(refused.end_move, 0.030, 1e-5);
  EXPECT_NEAR(refused.start_move, 0.0, 1e-9);
  bool reported = false;
  for (const EdgeCheck& e : refused.edges)
    if (!e.into_start) {
      EXPECT_EQ(e.from_clip, clip);
      EXPECT_TRUE(e.broken);
      EXPECT_NEAR(e.blend_after, e.blend_before + 0.030, 1e-5);
      EXPECT_GT(e.pop, 0.025);
      reported = true;
    } else {
      EXPECT_FALSE(e.broken);
    }
  EXPECT_TRUE(reported);
  EXPECT_EQ(rows(path), before);

  // Ramped back, the end is the original's and nothing breaks.
  ImportOptions ramp;
  ramp.on_break = OnBreak::Ramp;
  const ImportReport ramped = import_clip(ctx, clip, frames, ramp);
  EXPECT_GT(ramped.edit, 0);
  EXPECT_TRUE(ramped.ramped_end);
  EXPECT_FALSE(ramped.ramped_start);
  EXPECT_LT(ramped.end_move, 1e-6);
  for (const EdgeCheck& e : ramped.edges) EXPECT_FALSE(e.broken);
}

TEST(Edit, ImportWithTheWrongVertexOrFrameCountIsRefusedAndChangesNothing) {
  const std::string path = copy_db("wrong");
  const int64_t clip = long_clip(path);
  const std::vector<std::string> before = rows(path);
  const std::vector<float> frames = clip_frames(path, clip);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  db::Garment g;
  ASSERT_EQ(r.garment(&g, &err), db::Status::Ok);
  const int v = int(g.vertex_count()), n = int(frames.size()) / (3 * v);
  PointCache short_clip;
  short_clip.vertex_count = v;
  short_clip.frame_count = n - 1;
  short_clip.positions.assign(frames.begin(), frames.end() - 3 * v);
  write_pc2(work("short.pc2"), short_clip);
  PointCache fewer_vertices;
  fewer_vertices.vertex_count = v - 1;
  fewer_vertices.frame_count = n;
  fewer_vertices.positions.assign(size_t(3 * (v - 1) * n), 0.0f);
  write_pc2(work("fewer.pc2"), fewer_vertices);
  std::string out;
  EXPECT_NE(
      run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("short.pc2"), &out),
      0);
  EXPECT_NE(
      out.find("samples: " + std::to_string(n - 1) + " frames, the clip has " + std::to_string(n)),
      std::string::npos)
      << out;
  EXPECT_NE(
      run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("fewer.pc2"), &out),
      0);
  EXPECT_NE(
      out.find("points: " + std::to_string(v - 1) + " vertices, the clip has " + std::to_string(v)),
      std::string::npos)
      << out;
  EXPECT_NE(
      run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("none.pc2"), &out),
      0);
  EXPECT_NE(out.find("none.pc2: no such file"), std::string::npos) << out;
  EXPECT_EQ(rows(path), before);
}

// Blender's PC2 export with "Convert to Y-up" writes the clip rotated by 90 degrees about X; that
// and a change far beyond any edit are refused even with --on-break ramp, naming the setting.
TEST(Edit, ImportOfARotatedOrForeignCacheIsRefusedWhateverOnBreakSays) {
  const std::string path = copy_db("foreign");
  const int64_t clip = long_clip(path);
  const std::vector<std::string> before = rows(path);
  const std::vector<float> frames = clip_frames(path, clip);
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  db::Garment g;
  ASSERT_EQ(r.garment(&g, &err), db::Status::Ok);
  const int v = int(g.vertex_count()), n = int(frames.size()) / (3 * v);
  PointCache rotated;
  rotated.vertex_count = v;
  rotated.frame_count = n;
  for (size_t i = 0; i < frames.size(); i += 3)
    rotated.positions.insert(rotated.positions.end(), {frames[i], frames[i + 2], -frames[i + 1]});
  write_pc2(work("rotated.pc2"), rotated);
  PointCache moved = rotated;
  moved.positions = frames;
  for (size_t i = 0; i < moved.positions.size(); i += 3) moved.positions[i] += 25.0f;
  write_pc2(work("moved.pc2"), moved);
  std::string out;
  EXPECT_NE(run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("rotated.pc2") +
                        " --on-break ramp",
                    &out),
            0);
  EXPECT_NE(out.find("the frames are the clip rotated by 90 degrees about "), std::string::npos)
      << out;
  EXPECT_NE(out.find("turn off \"Convert to Y-up\""), std::string::npos) << out;
  EXPECT_NE(run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("moved.pc2") +
                        " --on-break ramp",
                    &out),
            0);
  EXPECT_NE(out.find("vertices are farther than the garment's size"), std::string::npos) << out;
  EXPECT_NE(out.find("refused whatever --on-break says"), std::string::npos) << out;
  EXPECT_EQ(rows(path), before);
}

TEST(Edit, UndoRestoresEveryRowAfterEachKindOfEdit) {
  const std::string path = copy_db("undo");
  const int64_t clip = long_clip(path);
  std::vector<std::vector<std::string>> snapshots{rows(path)};
  {
    EditContext ctx = open_edit(path, "", 0, "test");
    ASSERT_GT(set_clip_flag(ctx, clip, true), 0);
    snapshots.push_back(rows(path));
    std::vector<float> frames = clip_frames(path, clip);
    for (size_t i = 0; i < frames.size(); i += 3) frames[i + 1] += 0.002f;  // 2 mm up throughout
    ASSERT_GT(import_clip(ctx, clip, frames, {}).edit, 0);
    snapshots.push_back(rows(path));
    ResimOptions o;
    o.solver = ctx.scene.scene.file.solver;
    o.settings = ctx.scene.scene.file.settings;
    o.settings.substeps *= 4;  // a different end: carried forward or relinked
    const ResimReport resim = resim_clip(ctx, clip, o);
    ASSERT_GT(resim.edit, 0);
    snapshots.push_back(rows(path));
  }
  {
    // Delete the first clip that can be (its start state has another complete state at its node);
    // a refused delete must change nothing.
    db::Reader r;
    db::Error err;
    ASSERT_EQ(r.open(path, &err), db::Status::Ok);
    std::vector<db::ClothClip> clips;
    ASSERT_EQ(r.cloth_clips(&clips, &err), db::Status::Ok);
    bool deleted = false;
    for (const auto& c : clips) {
      if (c.start_state == 1 || c.id == clip) continue;
      if (run_cli("clip delete " + path + " " + std::to_string(c.id)) == 0) {
        deleted = true;
        break;
      }
      ASSERT_EQ(rows(path), snapshots.back()) << "a refused delete of clip " << c.id;
    }
    ASSERT_TRUE(deleted);
  }
  for (size_t k = snapshots.size() - 1; k > 0; --k) {
    EXPECT_NE(rows(path), snapshots[k]) << "edit " << k << " changed nothing";
    ASSERT_EQ(run_cli("undo " + path), 0);
    EXPECT_EQ(rows(path), snapshots[k]) << "undo back to after edit " << k;
  }
  ASSERT_EQ(run_cli("undo " + path), 0);
  EXPECT_EQ(rows(path), snapshots.front());
  std::string out;
  EXPECT_NE(run_cli("undo " + path, &out), 0);
  EXPECT_NE(out.find("nothing left to undo"), std::string::npos) << out;
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  std::vector<db::EditLogEntry> log;
  ASSERT_EQ(r.edit_log(&log, &err), db::Status::Ok);
  EXPECT_EQ(log.size(), 8u);  // four edits, four undos
}

TEST(Edit, AfterResimTheDatabaseChecksAndEveryPathPlays) {
  const std::string path = copy_db("resim");
  const int64_t clip = long_clip(path);
  EditContext ctx = open_edit(path, "", 0, "test");
  ResimOptions o;
  o.solver = ctx.scene.scene.file.solver;
  o.settings = ctx.scene.scene.file.settings;
  o.settings.substeps = 20;
  const ResimReport r = resim_clip(ctx, clip, o);
  ASSERT_GT(r.edit, 0);
  EXPECT_EQ(r.dead_ends_left, 0);
  if (r.new_state) {
    EXPECT_GT(r.end_move, ctx.epsilon);
    EXPECT_GT(r.clips_added, 0);
    EXPECT_GE(r.depth, 1);
  } else {
    EXPECT_LE(r.blend_error, ctx.epsilon);
  }
  db::ClothClip row;
  db::Error err;
  ASSERT_EQ(ctx.reader.cloth_clip(clip, &row, &err), db::Status::Ok);
  EXPECT_EQ(row.status, db::ClipStatus::Edited);
  // Every edge the explorer or the edit made stays within epsilon.
  std::vector<db::ClothEdge> edges;
  ASSERT_EQ(ctx.reader.cloth_edges(&edges, &err), db::Status::Ok);
  for (const auto& e : edges) EXPECT_LE(e.blend_error, ctx.epsilon) << "edge " << e.id;
  expect_consistent(path);
}

TEST(Edit, DeleteReroutesTheEdgesIntoItsStartStateAndEveryPathStillPlays) {
  const std::string path = copy_db("delete");
  EditContext ctx = open_edit(path, "", 0, "test");
  // A clip whose start state has edges leading into it.
  std::vector<db::ClothClip> clips;
  std::vector<db::ClothEdge> edges;
  db::Error err;
  ASSERT_EQ(ctx.reader.cloth_clips(&clips, &err), db::Status::Ok);
  ASSERT_EQ(ctx.reader.cloth_edges(&edges, &err), db::Status::Ok);
  DeleteReport report;
  bool deleted = false;
  for (const auto& c : clips) {
    size_t into = 0;
    for (const auto& e : edges) into += e.to_state == c.start_state;
    if (into == 0 || c.start_state == 1) continue;
    try {
      report = delete_clip(ctx, c.id);
    } catch (const std::exception&) {
      continue;  // no complete state to re-route to at that node
    }
    EXPECT_EQ(report.rerouted.size(), into);
    deleted = true;
    db::ClothClip gone;
    EXPECT_NE(ctx.reader.cloth_clip(c.id, &gone, &err), db::Status::Ok);
    break;
  }
  ASSERT_TRUE(deleted);
  EXPECT_NE(report.replacement, report.start_state);
  ASSERT_EQ(ctx.reader.cloth_edges(&edges, &err), db::Status::Ok);
  for (const auto& e : edges) EXPECT_NE(e.to_state, report.start_state);
  expect_consistent(path);
  // The start state's clips begin every path: deleting one is refused, and changes nothing.
  const std::vector<std::string> before = rows(path);
  EXPECT_THROW(delete_clip(ctx, 1), std::runtime_error);
  EXPECT_EQ(rows(path), before);
}

TEST(Edit, AVersion2FileIsMigratedWithItsEditLogAndItsOldEditsAreKeptNotUndone) {
  const std::string path = copy_db("v2");
  const int64_t clip = long_clip(path);
  {
    // A version 2 file: the old edit_log (clip a foreign key, three actions, no changeset) with
    // one set-status edit in it, made as the version 2 writer made it.
    sqlite3* h = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &h), SQLITE_OK);
    const std::string sql =
        "ALTER TABLE cloth_clip DROP COLUMN self_intersections; "
        "DROP TABLE edit_log; CREATE TABLE edit_log(id INTEGER PRIMARY KEY, time TEXT NOT NULL, "
        "author TEXT NOT NULL, clip INTEGER NOT NULL REFERENCES cloth_clip(id), action TEXT NOT "
        "NULL CHECK (action IN ('set-status', 'replace-frames', 'undo')), description TEXT NOT "
        "NULL, old_status TEXT, new_status TEXT, old_frames BLOB, old_max_error REAL, undoes "
        "INTEGER REFERENCES edit_log(id)); CREATE INDEX edit_log_clip ON edit_log(clip); "
        "INSERT INTO edit_log(time, author, clip, action, description, old_status, new_status) "
        "VALUES('2026-11-01T00:00:00Z', 'v2', " +
        std::to_string(clip) +
        ", 'set-status', 'flagged by a v2 tool', 'ok', 'flagged'); "
        "UPDATE cloth_clip SET status = 'flagged' WHERE id = " +
        std::to_string(clip) + "; PRAGMA user_version = 2;";
    char* msg = nullptr;
    ASSERT_EQ(sqlite3_exec(h, sql.c_str(), nullptr, nullptr, &msg), SQLITE_OK) << msg;
    sqlite3_close(h);
  }
  db::Writer w = db::Writer::open(path);  // migrates
  db::Reader r;
  db::Error err;
  ASSERT_EQ(r.open(path, &err), db::Status::Ok);
  EXPECT_EQ(r.schema_version(), db::kSchemaVersion);
  std::vector<db::EditLogEntry> log;
  ASSERT_EQ(r.edit_log(&log, &err), db::Status::Ok);
  ASSERT_EQ(log.size(), 1u);
  EXPECT_EQ(log[0].description, "flagged by a v2 tool");
  EXPECT_FALSE(log[0].has_changeset);
  // Edits logged without a changeset (by builds before schema 3) are kept in the log, but the
  // column-based undo that restored them is gone (docs/DATABASE.md#editing-version-3): undo
  // refuses, naming the edit, and changes nothing.
  try {
    w.undo_last("test");
    ADD_FAILURE() << "an edit without a changeset was undone";
  } catch (const ClothdbError& e) {
    EXPECT_NE(std::string(e.what()).find("without a changeset"), std::string::npos) << e.what();
  }
  db::ClothClip row;
  ASSERT_EQ(r.cloth_clip(clip, &row, &err), db::Status::Ok);
  EXPECT_EQ(row.status, db::ClipStatus::Flagged);
  ASSERT_EQ(r.edit_log(&log, &err), db::Status::Ok);
  EXPECT_EQ(log.size(), 1u);
  EXPECT_TRUE(db::check_database(path).ok());
}

}  // namespace
}  // namespace clothdb
