#include "database/store/writer.hpp"

#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <utility>

#include "database/codec/codec.hpp"
#include "database/format/artist_mesh.hpp"
#include "database/sqlite/statement.hpp"
#include "database/store/writer_lock.hpp"

namespace clothdb::db {
namespace {

using sql::Stmt;

// The edit log's columns, shared by new files (Writer::create) and the version 3 migration.
constexpr const char* kEditLogColumns = R"sql(
  id INTEGER PRIMARY KEY,
  time TEXT NOT NULL,
  author TEXT NOT NULL,
  clip INTEGER NOT NULL,
  action TEXT NOT NULL CHECK (action IN ('set-status', 'replace-frames', 'undo', 'flag',
    'unflag', 'import', 'resim', 'delete')),
  description TEXT NOT NULL,
  old_status TEXT,
  new_status TEXT,
  old_frames BLOB,
  old_max_error REAL,
  undoes INTEGER REFERENCES edit_log(id),
  changeset BLOB
))sql";

// Version 1 -> 2: the quality metrics, as the columns kSchemaSql ends its tables with (NULL:
// unknown). ADD COLUMN keeps every row and id as it is; the CHECKs are the same as for new files.
constexpr const char* kMigrateTo2Sql = R"sql(
ALTER TABLE cloth_clip ADD COLUMN mean_penetration REAL;
ALTER TABLE cloth_clip ADD COLUMN jitter REAL;
ALTER TABLE cloth_clip ADD COLUMN halved_steps INTEGER CHECK (halved_steps >= 0);
ALTER TABLE cloth_clip ADD COLUMN worst_frame INTEGER
  CHECK (worst_frame >= 0 AND worst_frame < frame_count);
ALTER TABLE cloth_edge ADD COLUMN pop REAL;
)sql";

// Version 4 -> 5: the most edge-triangle crossings in one frame of a clip (NULL: not measured, as
// for every clip written before).
constexpr const char* kMigrateTo5Sql = R"sql(
ALTER TABLE cloth_clip ADD COLUMN self_intersections INTEGER CHECK (self_intersections >= 0);
)sql";

// Version 2 -> 3: the edit log records every edit as a changeset (SQLite's session extension) and
// takes the new actions; its clip is no longer a foreign key, since a deleted clip's edits stay
// in the log. A CHECK cannot be altered in place, so the table is rebuilt (ids kept); foreign
// keys are deferred to the commit while it has no edit_log.
constexpr const char* kMigrateTo3Sql = R"sql(
INSERT INTO edit_log_v3(id, time, author, clip, action, description, old_status, new_status,
  old_frames, old_max_error, undoes)
  SELECT id, time, author, clip, action, description, old_status, new_status, old_frames,
    old_max_error, undoes FROM edit_log;
DROP TABLE edit_log;
ALTER TABLE edit_log_v3 RENAME TO edit_log;
CREATE INDEX edit_log_clip ON edit_log(clip);
)sql";

// The columns of each table (database/format/tables.hpp lists them; docs/DATABASE.md says what
// they mean), as run by Writer::create, the migrations and Writer::ensure_table. CHECK
// constraints keep statuses and counts sane even when another tool writes the file; foreign keys
// are enforced by the writer (PRAGMA foreign_keys=ON) and re-verified by `clothdb db check`.
std::string table_sql(std::string_view name) {
  if (name == "meta")
    return R"sql(CREATE TABLE IF NOT EXISTS meta(
  key TEXT PRIMARY KEY NOT NULL,
  value NOT NULL
) WITHOUT ROWID;)sql";
  if (name == "garment")
    return R"sql(CREATE TABLE IF NOT EXISTS garment(
  id INTEGER PRIMARY KEY CHECK (id = 1),
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  triangle_count INTEGER NOT NULL CHECK (triangle_count >= 0),
  triangles BLOB NOT NULL,
  rest_positions BLOB NOT NULL,
  material TEXT NOT NULL,
  solver TEXT NOT NULL
);)sql";
  if (name == "garment_mesh")
    // Arrays as little-endian uint32 / float32 blobs (db::ArtistMesh in rows.hpp); UVs and
    // normals are NULL when the mesh has none.
    return R"sql(CREATE TABLE IF NOT EXISTS garment_mesh(
  id INTEGER PRIMARY KEY CHECK (id = 1),
  source TEXT NOT NULL,
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  face_count INTEGER NOT NULL CHECK (face_count >= 0),
  render_vertex_count INTEGER NOT NULL CHECK (render_vertex_count >= vertex_count),
  render_triangle_count INTEGER NOT NULL CHECK (render_triangle_count >= 0),
  positions BLOB NOT NULL,
  face_sizes BLOB NOT NULL,
  corners BLOB NOT NULL,
  uvs BLOB,
  corner_uvs BLOB,
  normals BLOB,
  corner_normals BLOB,
  render_vertices BLOB NOT NULL,
  render_triangles BLOB NOT NULL,
  map_vertices BLOB NOT NULL,
  map_weights BLOB NOT NULL
);)sql";
  if (name == "garment_group")
    return R"sql(CREATE TABLE IF NOT EXISTS garment_group(
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL,
  material TEXT NOT NULL,
  faces BLOB NOT NULL
);)sql";
  if (name == "motion_file")
    return R"sql(CREATE TABLE IF NOT EXISTS motion_file(
  id INTEGER PRIMARY KEY,
  path TEXT NOT NULL,
  content_hash TEXT NOT NULL
);)sql";
  if (name == "source_file")
    return R"sql(CREATE TABLE IF NOT EXISTS source_file(
  id INTEGER PRIMARY KEY,
  role TEXT NOT NULL CHECK (role IN ('manifest', 'garment_mesh', 'garment_mesh_part')),
  path TEXT NOT NULL,
  content_hash TEXT NOT NULL,
  bytes BLOB NOT NULL
);)sql";
  if (name == "primary_clip")
    return R"sql(CREATE TABLE IF NOT EXISTS primary_clip(
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL UNIQUE,
  motion_file INTEGER REFERENCES motion_file(id),
  first_frame INTEGER NOT NULL CHECK (first_frame >= 0),
  frame_count INTEGER NOT NULL CHECK (frame_count > 0),
  frame_rate REAL NOT NULL CHECK (frame_rate > 0)
);)sql";
  if (name == "primary_transition")
    return R"sql(CREATE TABLE IF NOT EXISTS primary_transition(
  id INTEGER PRIMARY KEY,
  from_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  from_frame INTEGER NOT NULL,
  to_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  to_frame INTEGER NOT NULL,
  blend_frames INTEGER NOT NULL CHECK (blend_frames >= 0),
  cost REAL NOT NULL
);)sql";
  if (name == "run")
    return R"sql(CREATE TABLE IF NOT EXISTS run(
  id INTEGER PRIMARY KEY,
  started TEXT NOT NULL,
  finished TEXT,
  settings TEXT NOT NULL,
  cpu_seconds REAL,
  host TEXT NOT NULL,
  notes TEXT NOT NULL DEFAULT ''
);)sql";
  if (name == "cloth_state")
    return R"sql(CREATE TABLE IF NOT EXISTS cloth_state(
  id INTEGER PRIMARY KEY,
  primary_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  frame INTEGER NOT NULL,
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  positions BLOB NOT NULL,
  velocities BLOB NOT NULL,
  source_clip INTEGER REFERENCES cloth_clip(id) DEFERRABLE INITIALLY DEFERRED,
  run INTEGER REFERENCES run(id)
);
CREATE INDEX IF NOT EXISTS cloth_state_at ON cloth_state(primary_clip, frame);)sql";
  if (name == "cloth_clip")
    return R"sql(CREATE TABLE IF NOT EXISTS cloth_clip(
  id INTEGER PRIMARY KEY,
  start_state INTEGER NOT NULL REFERENCES cloth_state(id),
  primary_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  first_frame INTEGER NOT NULL,
  frame_count INTEGER NOT NULL CHECK (frame_count > 0),
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  frames BLOB NOT NULL,
  error_bound REAL NOT NULL,
  max_error REAL NOT NULL,
  max_strain REAL NOT NULL,
  max_penetration REAL NOT NULL,
  status TEXT NOT NULL CHECK (status IN ('ok', 'flagged', 'edited')),
  run INTEGER REFERENCES run(id),
  mean_penetration REAL,
  jitter REAL,
  halved_steps INTEGER CHECK (halved_steps >= 0),
  worst_frame INTEGER CHECK (worst_frame >= 0 AND worst_frame < frame_count),
  self_intersections INTEGER CHECK (self_intersections >= 0)
);
CREATE INDEX IF NOT EXISTS cloth_clip_from ON cloth_clip(start_state);)sql";
  if (name == "cloth_edge")
    return R"sql(CREATE TABLE IF NOT EXISTS cloth_edge(
  id INTEGER PRIMARY KEY,
  from_clip INTEGER NOT NULL REFERENCES cloth_clip(id),
  to_state INTEGER NOT NULL REFERENCES cloth_state(id),
  blend_error REAL NOT NULL,
  pop REAL
);
CREATE INDEX IF NOT EXISTS cloth_edge_from ON cloth_edge(from_clip);)sql";
  if (name == "cloth_link")
    return R"sql(CREATE TABLE IF NOT EXISTS cloth_link(
  id INTEGER PRIMARY KEY,
  from_state INTEGER NOT NULL REFERENCES cloth_state(id),
  primary_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  to_clip INTEGER NOT NULL REFERENCES cloth_clip(id),
  blend_error REAL NOT NULL CHECK (blend_error >= 0),
  run INTEGER REFERENCES run(id),
  UNIQUE (from_state, primary_clip)
);
CREATE INDEX IF NOT EXISTS cloth_link_to ON cloth_link(to_clip);)sql";
  if (name == "cloth_clip_steering")
    return R"sql(CREATE TABLE IF NOT EXISTS cloth_clip_steering(
  clip INTEGER PRIMARY KEY REFERENCES cloth_clip(id),
  target_state INTEGER NOT NULL REFERENCES cloth_state(id),
  distance REAL NOT NULL CHECK (distance >= 0),
  displacement REAL NOT NULL CHECK (displacement >= 0),
  acceleration REAL NOT NULL CHECK (acceleration >= 0)
);)sql";
  if (name == "edit_log")
    return std::string("CREATE TABLE IF NOT EXISTS edit_log(") + kEditLogColumns +
           ";\nCREATE INDEX IF NOT EXISTS edit_log_clip ON edit_log(clip);";
  if (name == "codec_basis")
    return R"sql(CREATE TABLE IF NOT EXISTS codec_basis(
  id INTEGER PRIMARY KEY,
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  mode_count INTEGER NOT NULL CHECK (mode_count >= 0),
  data BLOB NOT NULL,
  created TEXT NOT NULL,
  source TEXT NOT NULL
);)sql";
  if (name == "codec_contract")
    return R"sql(CREATE TABLE IF NOT EXISTS codec_contract(
  clip INTEGER PRIMARY KEY REFERENCES cloth_clip(id) ON DELETE CASCADE,
  rms REAL NOT NULL CHECK (rms >= 0),
  max REAL NOT NULL CHECK (max >= 0),
  jitter REAL NOT NULL CHECK (jitter >= 0),
  rms_cap REAL NOT NULL CHECK (rms_cap > 0),
  max_cap REAL NOT NULL CHECK (max_cap > 0),
  jitter_cap REAL NOT NULL CHECK (jitter_cap > 0)
);)sql";
  throw ClothdbError(Status::InvalidArgument,
                     "no columns defined for table " + std::string(name) + " (writer.cpp)");
}

}  // namespace

// ----------------------------------------------------------------------------------- Writer

Writer::Writer(sqlite3* db, std::string path) : db_(db), path_(std::move(path)) {}

Writer::Writer(Writer&& other) noexcept
    : lock_(std::move(other.lock_)),
      db_(std::exchange(other.db_, nullptr)),
      path_(std::move(other.path_)),
      codec_(other.codec_),
      transaction_depth_(other.transaction_depth_) {}

Writer& Writer::operator=(Writer&& other) noexcept {
  if (this != &other) {
    sqlite3_close_v2(db_);
    db_ = std::exchange(other.db_, nullptr);
    lock_ = std::move(other.lock_);
    path_ = std::move(other.path_);
    codec_ = other.codec_;
    transaction_depth_ = other.transaction_depth_;
  }
  return *this;
}

Writer::~Writer() {
  sqlite3_close_v2(db_);
}

void Writer::throw_sql(const char* what) {
  throw ClothdbError(sql::status_of(sqlite3_extended_errcode(db_)),
                     path_ + ": " + what + ": " + sqlite3_errmsg(db_));
}

void Writer::exec(const char* sql) {
  if (sqlite3_exec(db_, sql, nullptr, nullptr, nullptr) != SQLITE_OK) throw_sql(sql);
}

static sqlite3* open_connection(const std::string& path, int flags) {
  sqlite3* db = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &db, flags, nullptr);
  if (rc != SQLITE_OK) {
    const std::string msg = db ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
    sqlite3_close_v2(db);
    throw ClothdbError(Status::IoError, "cannot open " + path + ": " + msg);
  }
  sqlite3_extended_result_codes(db, 1);
  // Readers and the writer wait for each other's brief locks instead of failing at once.
  sqlite3_busy_timeout(db, 10000);
  return db;
}

Writer Writer::open_or_create(const std::string& path, double position_bound) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    CodecSettings codec;
    if (position_bound > 0) codec.position_bound = position_bound;
    return create(path, codec);
  }
  Writer w = open(path);
  if (position_bound > 0 && std::fabs(w.codec().position_bound - position_bound) >
                                1e-9 * std::max(position_bound, w.codec().position_bound)) {
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  ": codec.position_bound is %g mm, fixed when the file was made; a bound of %g mm "
                  "needs a new file",
                  1e3 * w.codec().position_bound, 1e3 * position_bound);
    throw ClothdbError(Status::InvalidArgument, path + buf);
  }
  return w;
}

Writer Writer::create(const std::string& path, const CodecSettings& codec) {
  std::error_code ec;
  if (std::filesystem::exists(path, ec))
    throw ClothdbError(Status::InvalidArgument,
                       path + " already exists; clothdb does not overwrite databases");
  if (!(codec.position_bound > 0) || !(codec.velocity_bound > 0) || codec.zstd_level < 1 ||
      codec.zstd_level > 22)
    throw ClothdbError(Status::InvalidArgument,
                       path + ": codec settings need positive bounds and zstd level 1..22");
  auto lock = WriterLock::acquire(path);
  if (std::filesystem::exists(path, ec))  // created by the lock's previous holder meanwhile
    throw ClothdbError(Status::InvalidArgument,
                       path + " already exists; clothdb does not overwrite databases");
  Writer w(open_connection(path, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE), path);
  w.lock_ = std::move(lock);
  w.codec_ = codec;
  // WAL must be chosen outside a transaction; it is persistent in the file.
  w.exec("PRAGMA journal_mode=WAL");
  w.exec("PRAGMA synchronous=FULL");
  w.exec("PRAGMA foreign_keys=ON");
  // Tables, identity and version in one transaction: a process killed during creation leaves a
  // file with user_version 0 that every opener rejects as unfinished.
  w.exec("BEGIN IMMEDIATE");
  for (const TableInfo& t : tables())
    if (!t.on_demand) w.exec(table_sql(t.name).c_str());
  w.exec(("PRAGMA application_id=" + std::to_string(kApplicationId)).c_str());
  w.exec(("PRAGMA user_version=" + std::to_string(kSchemaVersion)).c_str());
  const std::pair<const char*, std::string> initial_meta[] = {
      {meta::kFormat, meta::kFormatName},
      {meta::kFormatVersion, std::to_string(kSchemaVersion)},
      {meta::kUnits, "length m, time s, mass kg; frame: docs/SECONDARY_GRAPH.md"},
      {meta::kCodecPositionBound, sql::to_text(codec.position_bound)},
      {meta::kCodecVelocityBound, sql::to_text(codec.velocity_bound)},
      {meta::kCodecKeyInterval, std::to_string(codec.key_interval)},
      {meta::kCodecZstdLevel, std::to_string(codec.zstd_level)},
      {meta::kCodecFormatVersion, std::to_string(codec::kFormatVersion)},
  };
  for (const auto& [key, value] : initial_meta) w.set_meta(key, value);
  {
    Stmt s(w.db_, std::string("INSERT INTO meta VALUES(?, ") + sql::kNow + ")");
    s.bind(1, meta::kCreated);
    if (!s.ok() || s.step() != SQLITE_DONE) w.throw_sql("recording the creation time");
  }
  w.exec("COMMIT");
  return w;
}

Writer Writer::open(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec))
    throw ClothdbError(Status::IoError, "cannot open " + path + ": no such file");
  auto lock = WriterLock::acquire(path);
  Writer w(open_connection(path, SQLITE_OPEN_READWRITE), path);
  w.lock_ = std::move(lock);
  Error err;
  int version = 0;
  if (recognise(w.db_, path, &version, &w.codec_, &err) != Status::Ok)
    throw ClothdbError(err.status, err.message);
  w.exec("PRAGMA journal_mode=WAL");
  w.exec("PRAGMA synchronous=FULL");
  w.exec("PRAGMA foreign_keys=ON");
  if (version < kSchemaVersion) w.migrate(version);
  return w;
}

void Writer::migrate(int from_version) {
  // One transaction: a process killed here leaves the file at the old version, which both the
  // reader and the next Writer::open still accept. The version is re-read under the write lock in
  // case another writer migrated it meanwhile.
  Transaction t(*this);
  {
    // Finalized before the migration: an open statement would lock the tables it drops.
    Stmt v(db_, "PRAGMA user_version");
    if (!v.ok() || v.step() != SQLITE_ROW) throw_sql("reading the schema version");
    if (v.i64(0) != from_version) return;  // rolled back by t's destructor: nothing to do
  }
  if (from_version < 2) exec(kMigrateTo2Sql);
  if (from_version < 3)
    exec(("PRAGMA defer_foreign_keys = ON; CREATE TABLE edit_log_v3(" +
          std::string(kEditLogColumns) + ";" + kMigrateTo3Sql)
             .c_str());
  if (from_version < 5) exec(kMigrateTo5Sql);
  // Tables added since (cloth_link and cloth_clip_steering in version 4), from the registry.
  for (const TableInfo& t : tables())
    if (t.since_version > from_version && !t.on_demand) exec(table_sql(t.name).c_str());
  exec(("PRAGMA user_version=" + std::to_string(kSchemaVersion)).c_str());
  set_meta(meta::kFormatVersion, std::to_string(kSchemaVersion));
  t.commit();
}

Writer::Transaction::Transaction(Writer& writer) : writer_(&writer) {
  // The outermost level takes the write lock at once (IMMEDIATE) so a long transaction never
  // fails half-way on a lock upgrade; nested levels are savepoints.
  writer_->exec(writer_->transaction_depth_ == 0 ? "BEGIN IMMEDIATE" : "SAVEPOINT nested");
  ++writer_->transaction_depth_;
}

void Writer::Transaction::commit() {
  if (done_) return;
  --writer_->transaction_depth_;
  done_ = true;
  writer_->exec(writer_->transaction_depth_ == 0 ? "COMMIT" : "RELEASE nested");
}

Writer::Transaction::~Transaction() {
  if (done_) return;
  --writer_->transaction_depth_;
  const char* sql =
      writer_->transaction_depth_ == 0 ? "ROLLBACK" : "ROLLBACK TO nested; RELEASE nested";
  sqlite3_exec(writer_->db_, sql, nullptr, nullptr, nullptr);
}

void Writer::set_meta(const std::string& key, const std::string& value) {
  Stmt s(db_,
         "INSERT INTO meta(key, value) VALUES(?, ?) "
         "ON CONFLICT(key) DO UPDATE SET value = excluded.value");
  if (!s.ok() || s.bind(1, key).bind(2, value).step() != SQLITE_DONE)
    throw_sql(("setting meta " + key).c_str());
}

uint32_t Writer::garment_vertices() {
  Stmt s(db_, "SELECT vertex_count FROM garment WHERE id = 1");
  const int rc = s.ok() ? s.step() : s.rc();
  if (rc == SQLITE_ROW) return uint32_t(s.i64(0));
  if (rc != SQLITE_DONE) throw_sql("reading the garment");
  return 0;
}

void Writer::check_vertex_count(uint32_t vertex_count, const char* what) {
  uint32_t expected = garment_vertices();
  if (expected == 0) {
    // No garment yet: cloth already stored fixes the vertex count.
    Stmt s(db_,
           "SELECT vertex_count FROM cloth_clip UNION ALL SELECT vertex_count FROM "
           "cloth_state LIMIT 1");
    if (s.ok() && s.step() == SQLITE_ROW) expected = uint32_t(s.i64(0));
  }
  if (expected != 0 && vertex_count != expected)
    throw ClothdbError(Status::InvalidArgument,
                       path_ + ": " + what + " has " + std::to_string(vertex_count) +
                           " vertices, the garment has " + std::to_string(expected));
}

void Writer::put_garment(const Garment& g) {
  const uint32_t v = g.vertex_count();
  if (v == 0 || g.rest_positions.size() != size_t(v) * 3 || g.triangles.size() % 3 != 0)
    throw ClothdbError(Status::InvalidArgument,
                       path_ + ": garment needs 3 floats per vertex and 3 indices per triangle");
  for (uint32_t idx : g.triangles)
    if (idx >= v)
      throw ClothdbError(Status::InvalidArgument, path_ + ": garment triangle index " +
                                                      std::to_string(idx) + " >= vertex count " +
                                                      std::to_string(v));
  check_vertex_count(v, "the garment");
  Stmt s(db_, "INSERT INTO garment VALUES(1, ?, ?, ?, ?, ?, ?)");
  s.bind(1, int64_t(v)).bind(2, int64_t(g.triangles.size() / 3));
  // Stored as little-endian arrays (the host order on every platform clothdb targets).
  s.bind_blob(3, g.triangles.data(), g.triangles.size() * sizeof(uint32_t));
  s.bind_blob(4, g.rest_positions.data(), g.rest_positions.size() * sizeof(float));
  s.bind(5, g.material).bind(6, g.solver);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("storing the garment");
}

void Writer::put_artist_mesh(const ArtistMesh& m) {
  Error err;
  if (check_artist_mesh(m, garment_vertices(), path_, &err) != Status::Ok)
    throw ClothdbError(Status::InvalidArgument, err.message);
  Transaction tx(*this);
  Stmt s(db_, "INSERT INTO garment_mesh VALUES(1, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  s.bind(1, m.source).bind(2, int64_t(m.vertex_count())).bind(3, int64_t(m.face_count()));
  s.bind(4, int64_t(m.render_vertex_count())).bind(5, int64_t(m.render_triangle_count()));
  int i = 6;
  auto blob = [&](const auto& v, bool nullable) {
    if (nullable && v.empty())
      s.bind_null(i++);
    else  // a non-null pointer even when empty: SQLite binds a null pointer as NULL
      s.bind_blob(i++, v.empty() ? static_cast<const void*>(&i) : v.data(),
                  v.size() * sizeof(v[0]));
  };
  blob(m.positions, false);
  blob(m.face_sizes, false);
  blob(m.corners, false);
  blob(m.uvs, true);
  blob(m.corner_uvs, true);
  blob(m.normals, true);
  blob(m.corner_normals, true);
  blob(m.render_vertices, false);
  blob(m.render_triangles, false);
  blob(m.map_vertices, false);
  blob(m.map_weights, false);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("storing the artist's garment mesh");
  for (const ArtistGroup& g : m.groups) {
    Stmt gs(db_, "INSERT INTO garment_group(name, material, faces) VALUES(?, ?, ?)");
    gs.bind(1, g.name).bind(2, g.material);
    gs.bind_blob(3, g.faces.empty() ? static_cast<const void*>(&i) : g.faces.data(),
                 g.faces.size() * sizeof(uint32_t));
    if (!gs.ok() || gs.step() != SQLITE_DONE) throw_sql("storing a garment group");
  }
  tx.commit();
}

int64_t Writer::add_motion_file(const std::string& path, const std::string& content_hash) {
  Stmt s(db_, "INSERT INTO motion_file(path, content_hash) VALUES(?, ?)");
  if (!s.ok() || s.bind(1, path).bind(2, content_hash).step() != SQLITE_DONE)
    throw_sql(("adding motion file " + path).c_str());
  return sqlite3_last_insert_rowid(db_);
}

int64_t Writer::add_source_file(const SourceFile& f) {
  Stmt s(db_, "INSERT INTO source_file(role, path, content_hash, bytes) VALUES(?, ?, ?, ?)");
  s.bind(1, f.role).bind(2, f.path).bind(3, f.content_hash);
  s.bind_blob(4, f.bytes.data(), f.bytes.size());
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql(("storing source file " + f.path).c_str());
  return sqlite3_last_insert_rowid(db_);
}

int64_t Writer::add_primary_clip(const PrimaryClip& c) {
  Stmt s(db_,
         "INSERT INTO primary_clip(name, motion_file, first_frame, frame_count, frame_rate) "
         "VALUES(?, ?, ?, ?, ?)");
  s.bind(1, c.name).bind_id_or_null(2, c.motion_file).bind(3, int64_t(c.first_frame));
  s.bind(4, int64_t(c.frame_count)).bind(5, c.frame_rate);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql(("adding primary clip " + c.name).c_str());
  return sqlite3_last_insert_rowid(db_);
}

int64_t Writer::add_primary_transition(const PrimaryTransition& t) {
  Stmt s(db_,
         "INSERT INTO primary_transition(from_clip, from_frame, to_clip, to_frame, "
         "blend_frames, cost) VALUES(?, ?, ?, ?, ?, ?)");
  s.bind(1, t.from_clip).bind(2, int64_t(t.from_frame)).bind(3, t.to_clip);
  s.bind(4, int64_t(t.to_frame)).bind(5, int64_t(t.blend_frames)).bind(6, t.cost);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("adding a primary transition");
  return sqlite3_last_insert_rowid(db_);
}

int64_t Writer::begin_run(const std::string& settings, const std::string& host) {
  Stmt s(db_,
         std::string("INSERT INTO run(started, settings, host) VALUES(") + sql::kNow + ", ?, ?)");
  if (!s.ok() || s.bind(1, settings).bind(2, host).step() != SQLITE_DONE)
    throw_sql("starting a run");
  return sqlite3_last_insert_rowid(db_);
}

void Writer::finish_run(int64_t run, double cpu_seconds, const std::string& notes) {
  Stmt s(db_, (std::string("UPDATE run SET finished = ") + sql::kNow +
               ", cpu_seconds = ?, notes = ? WHERE id = ?")
                  .c_str());
  if (!s.ok() || s.bind(1, cpu_seconds).bind(2, notes).bind(3, run).step() != SQLITE_DONE)
    throw_sql("finishing a run");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no run " + std::to_string(run));
}

std::vector<uint8_t> Writer::encode_frames(const float* frames, uint32_t frame_count,
                                           uint32_t vertex_count, double bound,
                                           double* max_error) const {
  codec::EncodeStats stats;
  try {
    std::vector<uint8_t> blob =
        codec::encode(frames, frame_count, vertex_count, encode_settings(codec_, bound), &stats);
    if (max_error) *max_error = stats.max_error;
    return blob;
  } catch (const ClothdbError& e) {
    throw ClothdbError(e.status(), path_ + ": " + e.what());
  }
}

int64_t Writer::add_cloth_state(int64_t primary_clip, int32_t frame, const float* positions,
                                const float* velocities, uint32_t vertex_count, int64_t run,
                                int64_t source_clip) {
  check_vertex_count(vertex_count, "the cloth state");
  const auto pos = encode_frames(positions, 1, vertex_count, codec_.position_bound, nullptr);
  const auto vel = encode_frames(velocities, 1, vertex_count, codec_.velocity_bound, nullptr);
  return add_cloth_state_blobs(primary_clip, frame, pos, vel, run, source_clip);
}

int64_t Writer::add_cloth_state_blobs(int64_t primary_clip, int32_t frame,
                                      const std::vector<uint8_t>& pos,
                                      const std::vector<uint8_t>& vel, int64_t run,
                                      int64_t source_clip) {
  uint32_t vertex_count = 0;
  for (const auto* blob : {&pos, &vel}) {
    const double bound = blob == &pos ? codec_.position_bound : codec_.velocity_bound;
    codec::BlobInfo info;
    Error err;
    if (codec::read_info(blob->data(), blob->size(), &info, &err) != Status::Ok)
      throw ClothdbError(err.status, path_ + ": cloth state blob: " + err.message);
    if (info.frame_count != 1 || (vertex_count != 0 && info.vertex_count != vertex_count) ||
        info.bound > bound)
      throw ClothdbError(Status::InvalidArgument,
                         path_ + ": cloth state blobs must hold one frame of the same vertices " +
                             "within the file's bounds (got " + std::to_string(info.frame_count) +
                             " frames of " + std::to_string(info.vertex_count) +
                             " vertices, bound " + std::to_string(info.bound) + ")");
    vertex_count = info.vertex_count;
  }
  check_vertex_count(vertex_count, "the cloth state");
  Transaction t(*this);
  note_blob_version(pos);
  note_blob_version(vel);
  Stmt s(db_,
         "INSERT INTO cloth_state(primary_clip, frame, vertex_count, positions, velocities, "
         "source_clip, run) VALUES(?, ?, ?, ?, ?, ?, ?)");
  s.bind(1, primary_clip).bind(2, int64_t(frame)).bind(3, int64_t(vertex_count));
  s.bind_blob(4, pos.data(), pos.size()).bind_blob(5, vel.data(), vel.size());
  s.bind_id_or_null(6, source_clip).bind_id_or_null(7, run);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("adding a cloth state");
  const int64_t id = sqlite3_last_insert_rowid(db_);
  t.commit();
  return id;
}

std::vector<uint8_t> Writer::encode_clip(const float* frames, uint32_t frame_count,
                                         uint32_t vertex_count, double* max_error) const {
  return encode_frames(frames, frame_count, vertex_count, codec_.position_bound, max_error);
}

int64_t Writer::add_cloth_clip(const NewClothClip& clip, const float* frames, uint32_t frame_count,
                               uint32_t vertex_count) {
  check_vertex_count(vertex_count, "the cloth clip");
  double max_error = 0;
  const auto blob = encode_clip(frames, frame_count, vertex_count, &max_error);
  return add_cloth_clip_blob(clip, blob, max_error);
}

int64_t Writer::add_cloth_clip_blob(const NewClothClip& clip, const std::vector<uint8_t>& blob,
                                    double max_error) {
  codec::BlobInfo info;
  Error err;
  if (codec::read_info(blob.data(), blob.size(), &info, &err) != Status::Ok)
    throw ClothdbError(err.status, path_ + ": cloth clip blob: " + err.message);
  check_vertex_count(info.vertex_count, "the cloth clip");
  Transaction t(*this);
  note_blob_version(blob);
  Stmt s(db_,
         "INSERT INTO cloth_clip(start_state, primary_clip, first_frame, frame_count, "
         "vertex_count, frames, error_bound, max_error, max_strain, max_penetration, status, "
         "run, mean_penetration, jitter, halved_steps, worst_frame, self_intersections) "
         "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  s.bind(1, clip.start_state).bind(2, clip.primary_clip).bind(3, int64_t(clip.first_frame));
  s.bind(4, int64_t(info.frame_count)).bind(5, int64_t(info.vertex_count));
  s.bind_blob(6, blob.data(), blob.size()).bind(7, info.bound).bind(8, max_error);
  s.bind(9, clip.max_strain).bind(10, clip.max_penetration);
  s.bind(11, clip_status_name(clip.status)).bind_id_or_null(12, clip.run);
  s.bind_metric(13, clip.mean_penetration).bind_metric(14, clip.jitter);
  s.bind_count(15, clip.halved_steps).bind_count(16, clip.worst_frame);
  s.bind_count(17, clip.self_intersections);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("adding a cloth clip");
  const int64_t id = sqlite3_last_insert_rowid(db_);
  t.commit();
  return id;
}

int64_t Writer::add_cloth_edge(int64_t from_clip, int64_t to_state, double blend_error,
                               double pop) {
  Stmt s(db_, "INSERT INTO cloth_edge(from_clip, to_state, blend_error, pop) VALUES(?, ?, ?, ?)");
  s.bind(1, from_clip).bind(2, to_state).bind(3, blend_error).bind_metric(4, pop);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("adding a cloth edge");
  return sqlite3_last_insert_rowid(db_);
}

int64_t Writer::add_cloth_link(const ClothLink& l) {
  Stmt s(db_,
         "INSERT INTO cloth_link(from_state, primary_clip, to_clip, blend_error, run) "
         "VALUES(?, ?, ?, ?, ?)");
  if (!s.ok()) throw_sql("adding a cloth link");
  s.bind(1, l.from_state).bind(2, l.primary_clip).bind(3, l.to_clip).bind(4, l.blend_error);
  if (l.run > 0)
    s.bind(5, l.run);
  else
    sqlite3_bind_null(s.get(), 5);
  if (s.step() != SQLITE_DONE) throw_sql("adding a cloth link");
  return sqlite3_last_insert_rowid(db_);
}

void Writer::set_clip_steering(const ClipSteering& st) {
  Stmt s(db_,
         "INSERT OR REPLACE INTO cloth_clip_steering(clip, target_state, distance, displacement, "
         "acceleration) VALUES(?, ?, ?, ?, ?)");
  s.bind(1, st.clip).bind(2, st.target_state).bind(3, st.distance).bind(4, st.displacement);
  if (!s.ok() || s.bind(5, st.acceleration).step() != SQLITE_DONE)
    throw_sql("recording a clip's steering");
}

void Writer::replace_cloth_links(const std::vector<ClothLink>& links) {
  Transaction t(*this);
  exec("DELETE FROM cloth_link");
  for (const ClothLink& l : links) add_cloth_link(l);
  t.commit();
}

void Writer::set_clip_metrics(int64_t clip, const ClipMetrics& m) {
  Stmt s(db_,
         "UPDATE cloth_clip SET max_strain = ?, max_penetration = ?, mean_penetration = ?, "
         "jitter = ?, halved_steps = ?, worst_frame = ?, self_intersections = ? WHERE id = ?");
  s.bind(1, m.max_strain).bind(2, m.max_penetration).bind_metric(3, m.mean_penetration);
  s.bind_metric(4, m.jitter).bind_count(5, m.halved_steps).bind_count(6, m.worst_frame);
  s.bind_count(7, m.self_intersections);
  if (!s.ok() || s.bind(8, clip).step() != SQLITE_DONE) throw_sql("setting clip metrics");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth clip " + std::to_string(clip));
}

void Writer::set_edge_pop(int64_t edge, double pop) {
  Stmt s(db_, "UPDATE cloth_edge SET pop = ? WHERE id = ?");
  if (!s.ok() || s.bind_metric(1, pop).bind(2, edge).step() != SQLITE_DONE)
    throw_sql("setting an edge's pop");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth edge " + std::to_string(edge));
}

void Writer::replace_clip_blob(int64_t clip, const std::vector<uint8_t>& blob, double max_error,
                               ClipStatus status) {
  codec::BlobInfo info;
  Error err;
  if (codec::read_info(blob.data(), blob.size(), &info, &err) != Status::Ok)
    throw ClothdbError(err.status, path_ + ": cloth clip blob: " + err.message);
  check_vertex_count(info.vertex_count, "the cloth clip");
  Transaction t(*this);
  note_blob_version(blob);
  Stmt up(db_,
          "UPDATE cloth_clip SET frames = ?, frame_count = ?, error_bound = ?, max_error = ?, "
          "status = ? WHERE id = ?");
  up.bind_blob(1, blob.data(), blob.size()).bind(2, int64_t(info.frame_count));
  up.bind(3, info.bound).bind(4, max_error).bind(5, clip_status_name(status)).bind(6, clip);
  if (!up.ok() || up.step() != SQLITE_DONE) throw_sql("replacing clip frames");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth clip " + std::to_string(clip));
  t.commit();
}

void Writer::set_clip_status_unlogged(int64_t clip, ClipStatus status) {
  Stmt up(db_, "UPDATE cloth_clip SET status = ? WHERE id = ?");
  if (!up.ok() || up.bind(1, clip_status_name(status)).bind(2, clip).step() != SQLITE_DONE)
    throw_sql("setting a clip status");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth clip " + std::to_string(clip));
}

void Writer::set_edge(int64_t edge, int64_t to_state, double blend_error, double pop) {
  Stmt up(db_, "UPDATE cloth_edge SET to_state = ?, blend_error = ?, pop = ? WHERE id = ?");
  up.bind(1, to_state).bind(2, blend_error).bind_metric(3, pop).bind(4, edge);
  if (!up.ok() || up.step() != SQLITE_DONE) throw_sql("changing a cloth edge");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth edge " + std::to_string(edge));
}

void Writer::remove_clip(int64_t clip) {
  Transaction t(*this);
  for (const char* sql :
       {"DELETE FROM cloth_edge WHERE from_clip = ?", "DELETE FROM cloth_link WHERE to_clip = ?",
        "DELETE FROM cloth_clip_steering WHERE clip = ?",
        "UPDATE cloth_state SET source_clip = NULL WHERE source_clip = ?",
        "DELETE FROM cloth_clip WHERE id = ?"}) {
    Stmt s(db_, sql);
    if (!s.ok() || s.bind(1, clip).step() != SQLITE_DONE) throw_sql("removing a cloth clip");
  }
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth clip " + std::to_string(clip));
  t.commit();
}

void Writer::ensure_table(const char* name) {
  const TableInfo* t = find_table(name);
  if (!t || !t->on_demand)
    throw ClothdbError(Status::InvalidArgument,
                       path_ + ": " + name + " is not a table created on demand");
  exec(table_sql(name).c_str());
}

void Writer::note_blob_version(const std::vector<uint8_t>& blob) {
  codec::BlobInfo info;
  Error err;
  if (codec::read_info(blob.data(), blob.size(), &info, &err) != Status::Ok)
    throw ClothdbError(err.status, path_ + ": " + err.message);
  if (info.version <= codec::kFormatVersion) return;
  Stmt s(db_, "SELECT value FROM meta WHERE key = ?");
  const int rc = s.ok() ? s.bind(1, meta::kCodecFormatVersion).step() : s.rc();
  if (rc != SQLITE_ROW && rc != SQLITE_DONE) throw_sql("reading the codec version");
  const long long stored = rc == SQLITE_ROW ? std::strtoll(s.text(0).c_str(), nullptr, 10) : 0;
  if (stored < (long long)info.version)
    set_meta(meta::kCodecFormatVersion, std::to_string(info.version));
}

void set_meta_text(Writer& writer, const char* key, const std::string& value) {
  writer.set_meta(key, value);
}

void set_meta_integer(Writer& writer, const char* key, int64_t value) {
  writer.set_meta(key, std::to_string(value));
}

void set_meta_number(Writer& writer, const char* key, double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%.17g", value);
  writer.set_meta(key, text);
}

}  // namespace clothdb::db
