// Hand-editing clips (docs/GUIDE.md#fixing-a-bad-clip, precompute/edit/clip_edit.hpp): export and
// import, the continuity checks at both ends, re-simulation carried forward, delete with
// re-routing, and an undo that puts back every row. The database is a converged precompute of the
// small skirt of tests/data/mpi_small.json (CMU 01_01, 192 vertices, 10 nodes, 14 edges), made once
// by the `clothdb` executable and copied for each test.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "character/manifest.hpp"
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

// An unchanged round trip is "no change": its own exit status, nothing written, nothing logged.
TEST(Edit, ExportThenImportUnchangedIsNoChangeWithItsOwnExitStatusAndNotLogged) {
  const std::string path = copy_db("roundtrip");
  const int64_t clip = long_clip(path);
  const std::vector<std::string> before = rows(path);
  std::string out;
  ASSERT_EQ(run_cli("clip export " + path + " " + std::to_string(clip) + " --out " +
                        work("roundtrip_export"),
                    &out),
            0)
      << out;
  EXPECT_TRUE(std::filesystem::exists(work("roundtrip_export") + "/body.pc2")) << out;
  EXPECT_NE(out.find(" fps"), std::string::npos) << out;  // the rate is printed
  std::ifstream info(work("roundtrip_export") + "/clip.json");
  const nlohmann::json j = nlohmann::json::parse(info);
  EXPECT_GT(j["frame_rate"].get<double>(), 0);
  EXPECT_EQ(j["frame_start"].get<int>(), 0);
  EXPECT_EQ(
      run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("roundtrip_export"),
              &out),
      kNoChangeExitStatus)
      << out;
  EXPECT_NE(out.find("no change"), std::string::npos) << out;
  EXPECT_EQ(rows(path), before);
  ASSERT_EQ(run_cli("clip log " + path, &out), 0);
  EXPECT_NE(out.find("0 edits"), std::string::npos) << out;
  // Exported again into the same folder without the body: the first export's body is not left
  // beside this export's cloth to be loaded as its own.
  ASSERT_EQ(run_cli("clip export " + path + " " + std::to_string(clip) + " --out " +
                        work("roundtrip_export") + " --no-body",
                    &out),
            0)
      << out;
  EXPECT_TRUE(std::filesystem::exists(work("roundtrip_export") + "/cloth.pc2")) << out;
  EXPECT_FALSE(std::filesystem::exists(work("roundtrip_export") + "/body.pc2")) << out;
  EXPECT_FALSE(std::filesystem::exists(work("roundtrip_export") + "/body.obj")) << out;
  // An --out that is a file: named, with what is wrong.
  std::ofstream(work("export_is_a_file")) << "x";
  EXPECT_EQ(run_cli("clip export " + path + " " + std::to_string(clip) + " --out " +
                        work("export_is_a_file"),
                    &out),
            1);
  EXPECT_NE(out.find(work("export_is_a_file") + ": cannot create directory"), std::string::npos)
      << out;
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
  // Two vertices in three 25 m away: no rigid move, no edit.
  for (size_t i = 0; i < moved.positions.size(); i += 3)
    if (i / 3 % 3 != 0) moved.positions[i] += 25.0f;
  write_pc2(work("moved.pc2"), moved);
  std::string out;
  EXPECT_NE(run_cli("clip import " + path + " " + std::to_string(clip) + " " + work("rotated.pc2") +
                        " --on-break ramp",
                    &out),
            0);
  EXPECT_NE(out.find("the frames are the clip rotated by 90 degrees about "), std::string::npos)
      << out;
  EXPECT_NE(out.find("turn off \"Convert to Y-up\""), std::string::npos) << out;
  EXPECT_NE(out.find("docs/guide/blender.md"), std::string::npos) << out;
  EXPECT_EQ(out.find("README"), std::string::npos) << out;
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

// ---- import checks that name the cause (docs/guide/blender.md#what-clip-import-checks)
// ------------

struct ImportFixture {
  std::string path;
  int64_t clip = 0;
  std::vector<float> frames;
  int v = 0, n = 0;
  std::vector<std::string> before;
};

ImportFixture import_fixture(const std::string& name) {
  ImportFixture f;
  f.path = copy_db(name);
  f.clip = long_clip(f.path);
  f.frames = clip_frames(f.path, f.clip);
  f.before = rows(f.path);
  db::Reader r;
  db::Error err;
  EXPECT_EQ(r.open(f.path, &err), db::Status::Ok);
  db::Garment g;
  EXPECT_EQ(r.garment(&g, &err), db::Status::Ok);
  f.v = int(g.vertex_count());
  f.n = int(f.frames.size()) / (3 * f.v);
  return f;
}

// Writes `positions` as a PC2 and imports it (with --on-break ramp: the cause must be named
// whatever --on-break says); returns the exit status, the output in *out.
int import_pc2(const ImportFixture& f, const std::string& name, const std::vector<float>& positions,
               std::string* out, float start_frame = 0, float sample_rate = 1, int frames = 0) {
  PointCache c;
  c.vertex_count = f.v;
  c.frame_count = frames > 0 ? frames : f.n;
  c.start_frame = start_frame;
  c.sample_rate = sample_rate;
  c.positions = positions;
  write_pc2(work(name + ".pc2"), c);
  return run_cli("clip import " + f.path + " " + std::to_string(f.clip) + " " +
                     work(name + ".pc2") + " --on-break ramp",
                 out);
}

// The clip at time t (linear between frames, held at either end).
std::vector<float> clip_at(const ImportFixture& f, const std::function<double(int)>& time) {
  std::vector<float> out(f.frames.size());
  const size_t per = size_t(3 * f.v);
  for (int k = 0; k < f.n; ++k) {
    const double t = std::clamp(time(k), 0.0, double(f.n - 1));
    const int a = int(t), b = std::min(a + 1, f.n - 1);
    const float w = float(t - a);
    for (size_t i = 0; i < per; ++i)
      out[per * k + i] =
          f.frames[per * a + i] + w * (f.frames[per * b + i] - f.frames[per * a + i]);
  }
  return out;
}

TEST(EditImportChecks, TheHeaderFrameRangeAndSampleRateAreCheckedAgainstTheClip) {
  const ImportFixture f = import_fixture("header");
  std::string out;
  // Blender's default scene range, 1-250.
  std::vector<float> many(size_t(3 * f.v) * 250, 0.0f);
  EXPECT_EQ(import_pc2(f, "range", many, &out, 1, 1, 250), 1);
  EXPECT_NE(out.find("samples: 250 frames, the clip has " + std::to_string(f.n)), std::string::npos)
      << out;
  EXPECT_NE(out.find("header says frames 1-250"), std::string::npos) << out;
  EXPECT_NE(out.find("frames 0-" + std::to_string(f.n - 1) + " at 30 fps"), std::string::npos)
      << out;
  EXPECT_EQ(import_pc2(f, "rate", f.frames, &out, 0, 0.8f), 1);
  EXPECT_NE(out.find("header sample rate 0.8"), std::string::npos) << out;
  EXPECT_EQ(rows(f.path), f.before);
  // Another start frame with the clip's frames frame by frame: taken as frames 0-N, with a note.
  std::vector<float> edited = f.frames;
  for (int v = 0; v < f.v; ++v) edited[size_t(3 * f.v) * size_t(f.n / 2) + 3 * v + 1] += 0.002f;
  EXPECT_EQ(import_pc2(f, "start1", edited, &out, 1), 0) << out;
  EXPECT_NE(out.find("note: the PC2 header's start frame is 1"), std::string::npos) << out;
}

TEST(EditImportChecks, ARetimedCacheIsRefusedNamingTheFactor) {
  const ImportFixture f = import_fixture("retimed");
  std::string out;
  EXPECT_EQ(import_pc2(f, "retimed", clip_at(f, [](int k) { return 1.25 * k; }), &out), 1);
  EXPECT_NE(out.find("retimed by 1.25"), std::string::npos) << out;
  EXPECT_NE(out.find("frame scale"), std::string::npos) << out;
  EXPECT_EQ(rows(f.path), f.before);
}

TEST(EditImportChecks, ACacheShiftedByAFrameIsRefusedEitherWay) {
  const ImportFixture f = import_fixture("shifted");
  std::string out;
  EXPECT_EQ(import_pc2(f, "late", clip_at(f, [](int k) { return k - 1.0; }), &out, 1), 1);
  EXPECT_NE(out.find("shifted by 1 frame (frame k holds the clip's frame k-1"), std::string::npos)
      << out;
  EXPECT_NE(out.find("header start frame 1"), std::string::npos) << out;
  EXPECT_EQ(import_pc2(f, "early", clip_at(f, [](int k) { return k + 1.0; }), &out), 1);
  EXPECT_NE(out.find("shifted by 1 frame (frame k holds the clip's frame k+1"), std::string::npos)
      << out;
  EXPECT_EQ(out.find("--on-break reblend or ramp to accept it"), std::string::npos) << out;
  EXPECT_EQ(rows(f.path), f.before);
}

TEST(EditImportChecks, AFrozenCacheIsRefusedNamingApplyModifiers) {
  const ImportFixture f = import_fixture("frozen");
  std::string out;
  EXPECT_EQ(import_pc2(f, "frozen", clip_at(f, [](int) { return 0.0; }), &out), 1);
  EXPECT_NE(out.find("all " + std::to_string(f.n) + " frames are the same"), std::string::npos)
      << out;
  EXPECT_NE(out.find("Apply Modifiers"), std::string::npos) << out;
  EXPECT_EQ(rows(f.path), f.before);
}

TEST(EditImportChecks, WorldSpaceIsToldApartFromAnAxisConversion) {
  const ImportFixture f = import_fixture("world");
  std::vector<float> world(f.frames.size());
  // The object moved to (1, 0, 2) m and turned 30 degrees about +y.
  const double c = std::cos(0.5235987755982988), s = std::sin(0.5235987755982988);
  for (size_t i = 0; i < f.frames.size(); i += 3) {
    const double x = f.frames[i], y = f.frames[i + 1], z = f.frames[i + 2];
    world[i] = float(c * x + s * z + 1.0);
    world[i + 1] = float(y);
    world[i + 2] = float(-s * x + c * z + 2.0);
  }
  std::string out;
  EXPECT_EQ(import_pc2(f, "world", world, &out), 1);
  EXPECT_NE(out.find("moved rigidly (translation 1.000 0.000 2.000 m, rotation 30.0 degrees"),
            std::string::npos)
      << out;
  EXPECT_NE(out.find("world space"), std::string::npos) << out;
  EXPECT_EQ(out.find("Y-up"), std::string::npos) << out;
  EXPECT_EQ(rows(f.path), f.before);
}

// Strain before and after on the same decoded footing, and a warning for a stretched edit.
TEST(EditImportChecks, StrainBeforeAndAfterAreShownAndAStretchWarns) {
  const ImportFixture f = import_fixture("stretch");
  std::vector<float> stretched = f.frames;
  const size_t per = size_t(3 * f.v);
  // The middle frames (the ends untouched: continuity holds) stretched 15 % sideways about each
  // frame's centre.
  for (int k = 3; k < f.n - 3; ++k) {
    double cx = 0, cz = 0;
    for (int v = 0; v < f.v; ++v)
      cx += f.frames[per * k + 3 * v], cz += f.frames[per * k + 3 * v + 2];
    cx /= f.v, cz /= f.v;
    for (int v = 0; v < f.v; ++v) {
      float* p = stretched.data() + per * k + 3 * v;
      p[0] = float(cx + 1.15 * (p[0] - cx));
      p[2] = float(cz + 1.15 * (p[2] - cz));
    }
  }
  std::string out;
  ASSERT_EQ(import_pc2(f, "stretch", stretched, &out), 0) << out;
  EXPECT_NE(out.find("before (the stored clip, decoded)"), std::string::npos) << out;
  EXPECT_NE(out.find("after (the edit, re-encoded)"), std::string::npos) << out;
  EXPECT_NE(out.find("warning: max strain"), std::string::npos) << out;
}

// An unchanged import measures the same strain before and after: the same footing.
TEST(EditImportChecks, AnEditMeasuresBeforeAndAfterOnTheSameFooting) {
  const ImportFixture f = import_fixture("footing");
  EditContext ctx = open_edit(f.path, "", 0, "test");
  std::vector<float> frames = f.frames;
  // 2 mm up in one middle frame: a real but small edit.
  const size_t per = size_t(3 * f.v);
  for (int v = 0; v < f.v; ++v) frames[per * (f.n / 2) + 3 * v + 1] += 0.002f;
  const ImportReport r = import_clip(ctx, f.clip, frames, {});
  ASSERT_GT(r.edit, 0);
  // A rigid move of one frame leaves its strain as it was but for the codec's rounding of the
  // re-encoded frame (up to a few points on this 200-vertex skirt's short edges at a 0.5 mm
  // bound); the stored row's figure, measured before quantisation, may differ by more.
  EXPECT_NEAR(r.metrics.max_strain, r.metrics_before.max_strain, 0.05);
  EXPECT_GT(r.metrics_before.max_strain, 0);
  // The same frames once more: no change, and nothing logged.
  db::ClothClip row;
  const std::vector<float> stored = read_clip_frames(ctx.reader, f.clip, &row);
  EXPECT_THROW(import_clip(ctx, f.clip, stored, {}), NoChange);
}

// ---- a self-contained database (docs/DATABASE.md#stored-sources-version-5) ---------------------

namespace fs = std::filesystem;

void write_text(const std::string& path, const std::string& text) {
  fs::create_directories(fs::path(path).parent_path());
  std::ofstream(path) << text;
}

// The test skirt's scene, manifest and motion file (renamed) in `dir`; damping as given.
void write_sources(const std::string& dir, const std::string& damping = "0.001") {
  write_text(dir + "/scene.json",
             R"({"name": "sc", "manifest": "manifest.json", "clips": ["walk"],
  "garment": {"type": "skirt", "bone": "Hips", "vertices": 200, "length": 0.5, "flare": 1.5},
  "material": {"density": 0.15, "youngs_modulus": 1e8, "thickness": 0.0005,
               "bending_stiffness": 1e-5, "damping": )" +
                 damping + R"(},
  "solver": {"name": "xpbd", "substeps": 6, "iterations": 1},
  "colliders": {"bones": ["LowerBack", "LHipJoint", "RHipJoint", "LeftUpLeg", "LeftLeg",
                          "RightUpLeg", "RightLeg"], "margin": 0.004},
  "air_drag": 3.0, "settle_frames": 10})");
  write_text(dir + "/manifest.json", R"({"output_rate": 30, "clips": [{"name": "walk",
  "file": "bvh/walk.bvh", "first_frame": 1, "last_frame": 600, "source_rate": 120,
  "scale": 0.0564444, "up_axis": "y"}]})");
  fs::create_directories(dir + "/bvh");
  fs::copy_file(assimp_testmodels_dir() / "BVH/01_01.bvh", dir + "/bvh/walk.bvh",
                fs::copy_options::overwrite_existing);
}

// A database made in a folder from relative paths; that folder is then removed and its motion
// file kept, renamed, in work("moved_motions").
const std::string& self_contained_db() {
  static const std::string path = [] {
    const std::string src = work("made_here"), db = work("self_contained.db");
    test::remove_database(db);
    write_sources(src);
    const test::CliResult r = test::run_clothdb_in(
        src,
        test::split_arguments("precompute scene.json --db " + db +
                              " --epsilon 10 --batch 4 --threads 1 --frames 150 --quiet "
                              "--no-floor"),
        work("made_here.log"));
    EXPECT_EQ(r.code, 0) << r.output;
    fs::create_directories(work("moved_motions"));
    fs::rename(src + "/bvh/walk.bvh", work("moved_motions") + "/renamed.bvh");
    fs::remove_all(src);
    return db;
  }();
  return path;
}

test::CliResult run_elsewhere(const std::string& args) {
  const std::string dir = work("elsewhere");
  fs::create_directories(dir);
  return test::run_clothdb_in(dir, test::split_arguments(args), work("elsewhere.log"));
}

TEST(SelfContained, ExportImportResimAndBenchPlayedWorkFromAnyDirectory) {
  const std::string db = self_contained_db();
  const std::string motions = work("moved_motions");
  // The motion file is gone from its recorded path: the error names it and --motions.
  test::CliResult r = run_elsewhere("clip export " + db + " 2 --out exp_missing");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("walk.bvh (xxh64:"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("give --motions DIR"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(work("elsewhere/exp_missing/cloth.pc2")));  // nothing half-written
  // Found by content hash under --motions, although renamed.
  r = run_elsewhere("clip export " + db + " 2 --out exp --motions " + motions);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(fs::exists(work("elsewhere/exp/body.pc2"))) << r.output;
  r = run_elsewhere("clip import " + db + " 2 exp --motions " + motions);
  EXPECT_EQ(r.code, kNoChangeExitStatus) << r.output;
  r = run_elsewhere("clip resim " + db + " 2 --max-frames 20 --quiet --motions " + motions);
  EXPECT_EQ(r.code, 0) << r.output;
  r = run_elsewhere("bench played " + db +
                    " --paths 1 --seconds 0.5 --threads 1 --quiet --out "
                    "played --motions " +
                    motions);
  EXPECT_EQ(r.code, 0) << r.output;
  r = run_elsewhere("play " + db + " --seconds 0.5 --out played_walk");
  EXPECT_EQ(r.code, 0) << r.output;
}

TEST(SelfContained, AnOlderFileAsksForTheSceneAndADifferentSceneIsRefusedByField) {
  const std::string db = work("older.db");
  test::remove_database(db);
  fs::copy_file(self_contained_db(), db);
  {
    // What a file made before the sources were stored looks like (schema 4: none of version 5's
    // tables and columns).
    sqlite3* h = nullptr;
    ASSERT_EQ(sqlite3_open(db.c_str(), &h), SQLITE_OK);
    char* msg = nullptr;
    ASSERT_EQ(sqlite3_exec(h,
                           "DROP TABLE source_file; DROP TABLE garment_mesh; DROP TABLE "
                           "garment_group; ALTER TABLE cloth_clip DROP COLUMN self_intersections; "
                           "PRAGMA user_version = 4;",
                           nullptr, nullptr, &msg),
              SQLITE_OK)
        << msg;
    sqlite3_close(h);
  }
  const std::string motions = work("moved_motions");
  test::CliResult r = run_elsewhere("clip export " + db + " 2 --out old_exp --motions " + motions);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("made before databases stored their scene"), std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("--scene"), std::string::npos) << r.output;
  // The scene given again: accepted; another damping: refused naming the field.
  write_sources(work("again"));
  write_sources(work("changed"), "0.002");
  r = run_elsewhere("clip export " + db + " 2 --out old_exp --scene " + work("again") +
                    "/scene.json --motions " + motions);
  EXPECT_EQ(r.code, 0) << r.output;
  r = run_elsewhere("clip export " + db + " 2 --out old_exp2 --scene " + work("changed") +
                    "/scene.json");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("material.damping: stored 0.001, given 0.002"), std::string::npos)
      << r.output;
  // Resuming with another scene is refused naming the field, before anything is written.
  const std::vector<std::string> before = rows(self_contained_db());
  r = run_elsewhere("precompute " + work("changed") + "/scene.json --db " + self_contained_db() +
                    " --epsilon 10 --batch 4 --threads 1 --frames 10 --quiet --no-floor");
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("material.damping: stored 0.001, given 0.002"), std::string::npos)
      << r.output;
  EXPECT_EQ(rows(self_contained_db()), before);
}

// A mesh garment: its mesh file is stored with the scene and the scene rebuilt without it.
TEST(SelfContained, AMeshGarmentsFileIsStoredAndTheSceneRebuiltWithoutIt) {
  const std::string src = work("mesh_src"), db = work("mesh.db");
  test::remove_database(db);
  ASSERT_EQ(run_cli("clip export " + base_db() + " 1 --out " + src + " --no-body"), 0);
  // The exported frame is in character space (the floor at y = 0); a garment is modelled on the
  // skeleton's rest pose (Hips at the origin, docs/guide/garment_placement.md): move the waist
  // band to y = 0.06 m, where the demo skirt's is, as an artist would before exporting.
  std::ifstream in(src + "/cloth.obj");
  std::ostringstream moved;
  float top = -1e9f;
  {
    const ObjMesh exported = read_obj(src + "/cloth.obj");
    for (size_t i = 1; i < exported.positions.size(); i += 3)
      top = std::max(top, exported.positions[i]);
  }
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("v ", 0) == 0) {
      float x = 0, y = 0, z = 0;
      std::istringstream(line.substr(2)) >> x >> y >> z;
      moved << "v " << x << " " << y - top + 0.06f << " " << z << "\n";
    } else {
      moved << line << "\n";
    }
  }
  write_text(src + "/skirt.obj", moved.str());
  top = 0.06f;
  write_text(src + "/scene.json",
             R"({"name": "mesh", "manifest": ")" + kSource + R"(/motions/cmu_walk.json",
  "clips": ["01_01"],
  "garment": {"type": "mesh", "file": "skirt.obj", "scale": 1, "bone": "Hips",
              "pins": {"height_band": [)" +
                 std::to_string(top - 0.03) + ", " + std::to_string(top + 0.01) + R"(]}},
  "solver": {"name": "xpbd", "substeps": 6, "iterations": 1},
  "colliders": {"bones": ["LowerBack", "LeftUpLeg", "RightUpLeg"]},
  "air_drag": 3.0, "settle_frames": 10})");
  test::CliResult r = test::run_clothdb_in(
      src,
      test::split_arguments("precompute scene.json --db " + db +
                            " --epsilon 10 --batch 4 --threads 1 --frames 40 --quiet --no-floor"),
      work("mesh.log"));
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string obj_bytes = test::read_text(src + "/skirt.obj");
  fs::remove_all(src);
  {
    db::Reader reader;
    db::Error err;
    ASSERT_EQ(reader.open(db, &err), db::Status::Ok);
    std::vector<db::SourceFile> sources;
    ASSERT_EQ(reader.source_files(&sources, &err), db::Status::Ok);
    bool stored = false;
    for (const auto& f : sources)
      if (f.role == "garment_mesh") {
        EXPECT_EQ(f.path, "skirt.obj");
        EXPECT_EQ(std::string(f.bytes.begin(), f.bytes.end()), obj_bytes);
        stored = true;
      }
    EXPECT_TRUE(stored);
  }
  r = run_elsewhere("clip export " + db + " 1 --out mesh_exp");
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(fs::exists(work("elsewhere/mesh_exp/body.pc2"))) << r.output;
}

}  // namespace
}  // namespace clothdb
