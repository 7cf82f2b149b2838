#include "database/schema.hpp"

// The session extension (changesets for the edit log's exact undo); Debian's libsqlite3 is built
// with it (SQLITE_ENABLE_SESSION and SQLITE_ENABLE_PREUPDATE_HOOK).
#define SQLITE_ENABLE_SESSION 1
#define SQLITE_ENABLE_PREUPDATE_HOOK 1
#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <utility>

#include "database/codec.hpp"
#include "database/writer_lock.hpp"

namespace clothdb::db {
namespace {

// Tables, in dependency order. CHECK constraints keep statuses and counts sane even when another
// tool writes the file; foreign keys are enforced by the writer (PRAGMA foreign_keys=ON) and
// re-verified by `clothdb db check`.
// Version 4 (issue 16): steered clip ends are recorded (cloth_clip_steering: ClipSteering), and a
// dead end (a state and a way out of its node with no clip) links to the clip that
// the nearest state at that node has along the same way out, with the state distance recorded as
// the blend error, so the runtime never searches for a fallback (issue 16). Written by the
// explorer when its budget ends; a clip removed by an edit takes its links with it.
#define CLOTHDB_CLOTH_LINK_SQL                                         \
  "CREATE TABLE IF NOT EXISTS cloth_link(\n"                           \
  "  id INTEGER PRIMARY KEY,\n"                                        \
  "  from_state INTEGER NOT NULL REFERENCES cloth_state(id),\n"        \
  "  primary_clip INTEGER NOT NULL REFERENCES primary_clip(id),\n"     \
  "  to_clip INTEGER NOT NULL REFERENCES cloth_clip(id),\n"            \
  "  blend_error REAL NOT NULL CHECK (blend_error >= 0),\n"            \
  "  run INTEGER REFERENCES run(id),\n"                                \
  "  UNIQUE (from_state, primary_clip)\n"                              \
  ");\n"                                                               \
  "CREATE INDEX IF NOT EXISTS cloth_link_to ON cloth_link(to_clip);\n" \
  "CREATE TABLE IF NOT EXISTS cloth_clip_steering(\n"                  \
  "  clip INTEGER PRIMARY KEY REFERENCES cloth_clip(id),\n"            \
  "  target_state INTEGER NOT NULL REFERENCES cloth_state(id),\n"      \
  "  distance REAL NOT NULL CHECK (distance >= 0),\n"                  \
  "  displacement REAL NOT NULL CHECK (displacement >= 0),\n"          \
  "  acceleration REAL NOT NULL CHECK (acceleration >= 0)\n"           \
  ");\n"

constexpr const char* kSchemaSql = R"sql(
CREATE TABLE meta(
  key TEXT PRIMARY KEY NOT NULL,
  value NOT NULL
) WITHOUT ROWID;
CREATE TABLE garment(
  id INTEGER PRIMARY KEY CHECK (id = 1),
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  triangle_count INTEGER NOT NULL CHECK (triangle_count >= 0),
  triangles BLOB NOT NULL,
  rest_positions BLOB NOT NULL,
  material TEXT NOT NULL,
  solver TEXT NOT NULL
);
CREATE TABLE motion_file(
  id INTEGER PRIMARY KEY,
  path TEXT NOT NULL,
  content_hash TEXT NOT NULL
);
CREATE TABLE primary_clip(
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL UNIQUE,
  motion_file INTEGER REFERENCES motion_file(id),
  first_frame INTEGER NOT NULL CHECK (first_frame >= 0),
  frame_count INTEGER NOT NULL CHECK (frame_count > 0),
  frame_rate REAL NOT NULL CHECK (frame_rate > 0)
);
CREATE TABLE primary_transition(
  id INTEGER PRIMARY KEY,
  from_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  from_frame INTEGER NOT NULL,
  to_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  to_frame INTEGER NOT NULL,
  blend_frames INTEGER NOT NULL CHECK (blend_frames >= 0),
  cost REAL NOT NULL
);
CREATE TABLE run(
  id INTEGER PRIMARY KEY,
  started TEXT NOT NULL,
  finished TEXT,
  settings TEXT NOT NULL,
  cpu_seconds REAL,
  host TEXT NOT NULL,
  notes TEXT NOT NULL DEFAULT ''
);
CREATE TABLE cloth_state(
  id INTEGER PRIMARY KEY,
  primary_clip INTEGER NOT NULL REFERENCES primary_clip(id),
  frame INTEGER NOT NULL,
  vertex_count INTEGER NOT NULL CHECK (vertex_count > 0),
  positions BLOB NOT NULL,
  velocities BLOB NOT NULL,
  source_clip INTEGER REFERENCES cloth_clip(id) DEFERRABLE INITIALLY DEFERRED,
  run INTEGER REFERENCES run(id)
);
CREATE TABLE cloth_clip(
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
  worst_frame INTEGER CHECK (worst_frame >= 0 AND worst_frame < frame_count)
);
CREATE TABLE cloth_edge(
  id INTEGER PRIMARY KEY,
  from_clip INTEGER NOT NULL REFERENCES cloth_clip(id),
  to_state INTEGER NOT NULL REFERENCES cloth_state(id),
  blend_error REAL NOT NULL,
  pop REAL
);
CREATE INDEX cloth_state_at ON cloth_state(primary_clip, frame);
CREATE INDEX cloth_clip_from ON cloth_clip(start_state);
CREATE INDEX cloth_edge_from ON cloth_edge(from_clip);
)sql" CLOTHDB_CLOTH_LINK_SQL;

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

// The tables an edit may change and undo restores (everything but the log itself).
constexpr const char* kEditedTables[] = {
    "cloth_state", "cloth_clip", "cloth_edge", "cloth_link", "cloth_clip_steering", "run", "meta"};

constexpr const char* kNow = "strftime('%Y-%m-%dT%H:%M:%fZ', 'now')";

// A prepared statement that finalizes itself. Errors are returned as SQLite codes; the writer
// turns them into exceptions, the reader into Status values.
class Stmt {
 public:
  Stmt(sqlite3* db, const char* sql) { rc_ = sqlite3_prepare_v2(db, sql, -1, &s_, nullptr); }
  ~Stmt() { sqlite3_finalize(s_); }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;
  bool ok() const { return rc_ == SQLITE_OK; }
  int rc() const { return rc_; }
  sqlite3_stmt* get() { return s_; }
  Stmt& bind(int i, int64_t v) {
    sqlite3_bind_int64(s_, i, v);
    return *this;
  }
  Stmt& bind(int i, double v) {
    sqlite3_bind_double(s_, i, v);
    return *this;
  }
  Stmt& bind(int i, const std::string& v) {
    sqlite3_bind_text(s_, i, v.data(), int(v.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Stmt& bind(int i, const char* v) {
    sqlite3_bind_text(s_, i, v, -1, SQLITE_TRANSIENT);
    return *this;
  }
  Stmt& bind_blob(int i, const void* data, size_t size) {
    sqlite3_bind_blob64(s_, i, data, sqlite3_uint64(size), SQLITE_STATIC);
    return *this;
  }
  // Unknown metrics (NaN, or a negative count) are stored as NULL.
  Stmt& bind_metric(int i, double v) {
    if (v != v)
      sqlite3_bind_null(s_, i);
    else
      sqlite3_bind_double(s_, i, v);
    return *this;
  }
  Stmt& bind_count(int i, int64_t v) {
    if (v < 0)
      sqlite3_bind_null(s_, i);
    else
      sqlite3_bind_int64(s_, i, v);
    return *this;
  }
  Stmt& bind_id_or_null(int i, int64_t id) {
    if (id == 0)
      sqlite3_bind_null(s_, i);
    else
      sqlite3_bind_int64(s_, i, id);
    return *this;
  }
  // SQLITE_ROW, SQLITE_DONE or an error code.
  int step() { return rc_ = sqlite3_step(s_); }
  int64_t i64(int c) { return sqlite3_column_int64(s_, c); }
  double f64(int c) { return sqlite3_column_double(s_, c); }
  std::string text(int c) {
    const unsigned char* t = sqlite3_column_text(s_, c);
    return t ? std::string(reinterpret_cast<const char*>(t), size_t(sqlite3_column_bytes(s_, c)))
             : std::string();
  }
  bool is_null(int c) { return sqlite3_column_type(s_, c) == SQLITE_NULL; }
  double metric(int c) { return is_null(c) ? kUnknownMetric : f64(c); }
  int32_t count(int c) { return is_null(c) ? -1 : int32_t(i64(c)); }
  size_t bytes(int c) { return size_t(sqlite3_column_bytes(s_, c)); }

 private:
  sqlite3_stmt* s_ = nullptr;
  int rc_ = SQLITE_OK;
};

// Shortest decimal text that reads back as the same double (meta values are read by people too).
std::string to_text(double v) {
  char buf[40];
  for (int precision = 6; precision <= 17; ++precision) {
    std::snprintf(buf, sizeof buf, "%.*g", precision, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

// Checks that an open connection is a finished clothdb database this build can read and loads
// its codec settings. Shared by the reader, the writer and `db check`.
Status recognise(sqlite3* db, const std::string& path, int* version, CodecSettings* codec,
                 Error* err) {
  int32_t app_id = 0;
  {
    Stmt s(db, "PRAGMA application_id");
    const int rc = s.ok() ? s.step() : s.rc();
    if (rc == SQLITE_NOTADB)
      return fail(err, Status::NotClothdb, "%s is not a clothdb database (not even SQLite)",
                  path.c_str());
    if (rc != SQLITE_ROW)
      return fail(err, Status::IoError, "%s: cannot read: %s", path.c_str(), sqlite3_errmsg(db));
    app_id = int32_t(s.i64(0));
  }
  if (app_id != kApplicationId)
    return fail(err, Status::NotClothdb,
                "%s is a SQLite database but not a clothdb one (application_id 0x%08x, expected "
                "0x%08x)",
                path.c_str(), uint32_t(app_id), uint32_t(kApplicationId));
  Stmt v(db, "PRAGMA user_version");
  if (!v.ok() || v.step() != SQLITE_ROW)
    return fail(err, Status::IoError, "%s: cannot read: %s", path.c_str(), sqlite3_errmsg(db));
  const int64_t user_version = v.i64(0);
  if (user_version > kSchemaVersion)
    return fail(err, Status::NewerVersion,
                "%s: clothdb schema version %lld is newer than this build reads (up to %d)",
                path.c_str(), (long long)user_version, kSchemaVersion);
  if (user_version < 1)
    return fail(err, Status::Corrupt, "%s: clothdb schema version %lld: creation never finished",
                path.c_str(), (long long)user_version);
  Stmt m(db,
         "SELECT key, value FROM meta WHERE key IN ('format', 'format_version') OR key LIKE "
         "'codec.%'");
  if (!m.ok())
    return fail(err, Status::Corrupt, "%s: no meta table: %s", path.c_str(), sqlite3_errmsg(db));
  bool format = false;
  CodecSettings c;
  int found = 0;
  while (m.step() == SQLITE_ROW) {
    const std::string key = m.text(0);
    if (key == "format") format = m.text(1) == "clothdb";
    // Version keys must be versions this build knows: a newer one is refused like a newer
    // schema, anything else (text, negative) as damage.
    const int known = key == "format_version"         ? kSchemaVersion
                      : key == "codec.format_version" ? int(codec::kFormatVersionV2)
                                                      : 0;
    if (known > 0) {
      const std::string value = m.text(1);
      char* end = nullptr;
      const long long v = std::strtoll(value.c_str(), &end, 10);
      const bool integer = !value.empty() && end && *end == '\0';
      if (integer && v > known)
        return fail(err, Status::NewerVersion,
                    "%s: meta %s is %lld, newer than this build reads (up to %d)", path.c_str(),
                    key.c_str(), v, known);
      if (!integer || v < 1)
        return fail(err, Status::Corrupt, "%s: meta %s is '%s', not a version (1..%d)",
                    path.c_str(), key.c_str(), value.c_str(), known);
    }
    if (key == "codec.position_bound") {
      c.position_bound = m.f64(1);
      ++found;
    } else if (key == "codec.velocity_bound") {
      c.velocity_bound = m.f64(1);
      ++found;
    } else if (key == "codec.key_interval") {
      c.key_interval = uint32_t(m.i64(1));
      ++found;
    } else if (key == "codec.zstd_level") {
      c.zstd_level = int(m.i64(1));
      ++found;
    }
  }
  if (m.rc() != SQLITE_DONE)
    return fail(err, Status::IoError, "%s: cannot read meta: %s", path.c_str(), sqlite3_errmsg(db));
  if (!format || found != 4 || !(c.position_bound > 0) || !(c.velocity_bound > 0))
    return fail(err, Status::Corrupt, "%s: meta table lacks the clothdb format or codec settings",
                path.c_str());
  if (version) *version = int(user_version);
  if (codec) *codec = c;
  return Status::Ok;
}

}  // namespace

const char* clip_status_name(ClipStatus status) {
  switch (status) {
    case ClipStatus::Ok:
      return "ok";
    case ClipStatus::Flagged:
      return "flagged";
    case ClipStatus::Edited:
      return "edited";
  }
  return "ok";
}

bool parse_clip_status(const std::string& name, ClipStatus* status) {
  for (ClipStatus s : {ClipStatus::Ok, ClipStatus::Flagged, ClipStatus::Edited}) {
    if (name == clip_status_name(s)) {
      *status = s;
      return true;
    }
  }
  return false;
}

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
  const int code = sqlite3_extended_errcode(db_);
  Status st = Status::IoError;
  if ((code & 0xff) == SQLITE_CONSTRAINT) st = Status::InvalidArgument;
  if ((code & 0xff) == SQLITE_CORRUPT || (code & 0xff) == SQLITE_NOTADB) st = Status::Corrupt;
  throw ClothdbError(st, path_ + ": " + what + ": " + sqlite3_errmsg(db_));
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
  w.exec(kSchemaSql);
  w.exec(("CREATE TABLE edit_log(" + std::string(kEditLogColumns) +
          "; CREATE INDEX edit_log_clip ON edit_log(clip);")
             .c_str());
  w.exec(("PRAGMA application_id=" + std::to_string(kApplicationId)).c_str());
  w.exec(("PRAGMA user_version=" + std::to_string(kSchemaVersion)).c_str());
  const std::pair<const char*, std::string> meta[] = {
      {"format", "clothdb"},
      {"format_version", std::to_string(kSchemaVersion)},
      {"units", "length m, time s, mass kg; frame: docs/SECONDARY_GRAPH.md"},
      {"codec.position_bound", to_text(codec.position_bound)},
      {"codec.velocity_bound", to_text(codec.velocity_bound)},
      {"codec.key_interval", std::to_string(codec.key_interval)},
      {"codec.zstd_level", std::to_string(codec.zstd_level)},
      {"codec.format_version", std::to_string(codec::kFormatVersion)},
  };
  for (const auto& [key, value] : meta) w.set_meta(key, value);
  {
    Stmt s(w.db_, (std::string("INSERT INTO meta VALUES('created', ") + kNow + ")").c_str());
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
  if (from_version < 4) exec(CLOTHDB_CLOTH_LINK_SQL);
  exec(("PRAGMA user_version=" + std::to_string(kSchemaVersion)).c_str());
  set_meta("format_version", std::to_string(kSchemaVersion));
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

int64_t Writer::add_motion_file(const std::string& path, const std::string& content_hash) {
  Stmt s(db_, "INSERT INTO motion_file(path, content_hash) VALUES(?, ?)");
  if (!s.ok() || s.bind(1, path).bind(2, content_hash).step() != SQLITE_DONE)
    throw_sql(("adding motion file " + path).c_str());
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
  Stmt s(
      db_,
      (std::string("INSERT INTO run(started, settings, host) VALUES(") + kNow + ", ?, ?)").c_str());
  if (!s.ok() || s.bind(1, settings).bind(2, host).step() != SQLITE_DONE)
    throw_sql("starting a run");
  return sqlite3_last_insert_rowid(db_);
}

void Writer::finish_run(int64_t run, double cpu_seconds, const std::string& notes) {
  Stmt s(db_, (std::string("UPDATE run SET finished = ") + kNow +
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
  Stmt s(db_,
         "INSERT INTO cloth_state(primary_clip, frame, vertex_count, positions, velocities, "
         "source_clip, run) VALUES(?, ?, ?, ?, ?, ?, ?)");
  s.bind(1, primary_clip).bind(2, int64_t(frame)).bind(3, int64_t(vertex_count));
  s.bind_blob(4, pos.data(), pos.size()).bind_blob(5, vel.data(), vel.size());
  s.bind_id_or_null(6, source_clip).bind_id_or_null(7, run);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("adding a cloth state");
  return sqlite3_last_insert_rowid(db_);
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
  Stmt s(db_,
         "INSERT INTO cloth_clip(start_state, primary_clip, first_frame, frame_count, "
         "vertex_count, frames, error_bound, max_error, max_strain, max_penetration, status, "
         "run, mean_penetration, jitter, halved_steps, worst_frame) "
         "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  s.bind(1, clip.start_state).bind(2, clip.primary_clip).bind(3, int64_t(clip.first_frame));
  s.bind(4, int64_t(info.frame_count)).bind(5, int64_t(info.vertex_count));
  s.bind_blob(6, blob.data(), blob.size()).bind(7, info.bound).bind(8, max_error);
  s.bind(9, clip.max_strain).bind(10, clip.max_penetration);
  s.bind(11, clip_status_name(clip.status)).bind_id_or_null(12, clip.run);
  s.bind_metric(13, clip.mean_penetration).bind_metric(14, clip.jitter);
  s.bind_count(15, clip.halved_steps).bind_count(16, clip.worst_frame);
  if (!s.ok() || s.step() != SQLITE_DONE) throw_sql("adding a cloth clip");
  return sqlite3_last_insert_rowid(db_);
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
         "jitter = ?, halved_steps = ?, worst_frame = ? WHERE id = ?");
  s.bind(1, m.max_strain).bind(2, m.max_penetration).bind_metric(3, m.mean_penetration);
  s.bind_metric(4, m.jitter).bind_count(5, m.halved_steps).bind_count(6, m.worst_frame);
  if (!s.ok() || s.bind(7, clip).step() != SQLITE_DONE) throw_sql("setting clip metrics");
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

// ----------------------------------------------------------------------------------- Edits

Writer::Edit::Edit(Writer& writer, int64_t clip, const std::string& action,
                   const std::string& author)
    : writer_(&writer), clip_(clip), action_(action), author_(author), tx_(writer) {
  // Opened inside the transaction, so it records exactly this edit's changes.
  if (sqlite3session_create(writer.db_, "main", &session_) != SQLITE_OK)
    writer.throw_sql("starting an edit's change record (sqlite3session_create)");
  for (const char* table : kEditedTables)
    if (sqlite3session_attach(session_, table) != SQLITE_OK) {
      sqlite3session_delete(session_);
      session_ = nullptr;
      writer.throw_sql("attaching a table to an edit's change record");
    }
}

Writer::Edit::~Edit() {
  if (session_) sqlite3session_delete(session_);
}

int64_t Writer::Edit::commit(const std::string& description) {
  int size = 0;
  void* changes = nullptr;
  if (sqlite3session_changeset(session_, &size, &changes) != SQLITE_OK)
    writer_->throw_sql("reading an edit's changes (sqlite3session_changeset)");
  sqlite3session_delete(session_);  // before the log row: the log is not part of the edit
  session_ = nullptr;
  Stmt log(writer_->db_, (std::string("INSERT INTO edit_log(time, author, clip, action, "
                                      "description, changeset) VALUES(") +
                          kNow + ", ?, ?, ?, ?, ?)")
                             .c_str());
  log.bind(1, author_).bind(2, clip_).bind(3, action_).bind(4, description);
  log.bind_blob(5, changes, size_t(size));
  const int rc = log.ok() ? log.step() : log.rc();
  sqlite3_free(changes);
  if (rc != SQLITE_DONE) writer_->throw_sql("logging an edit");
  const int64_t id = sqlite3_last_insert_rowid(writer_->db_);
  tx_.commit();
  return id;
}

namespace {

// Applying an inverted changeset: any conflict means the rows are not as the edit left them.
struct UndoConflicts {
  int count = 0;
  int kind = 0;
};

int abort_on_conflict(void* context, int kind, sqlite3_changeset_iter*) {
  auto* c = static_cast<UndoConflicts*>(context);
  ++c->count;
  c->kind = kind;
  return SQLITE_CHANGESET_ABORT;
}

const char* conflict_name(int kind) {
  switch (kind) {
    case SQLITE_CHANGESET_DATA:
      return "a row it changed has changed again";
    case SQLITE_CHANGESET_NOTFOUND:
      return "a row it changed is gone";
    case SQLITE_CHANGESET_CONFLICT:
      return "a row it removed has been added again";
    case SQLITE_CHANGESET_CONSTRAINT:
      return "restoring a row breaks a constraint";
    case SQLITE_CHANGESET_FOREIGN_KEY:
      return "newer rows refer to rows it added";
  }
  return "conflict";
}

}  // namespace

EditLogEntry Writer::undo_last(const std::string& author) {
  Transaction t(*this);
  Stmt last(db_,
            "SELECT id, clip, action, description, changeset IS NOT NULL FROM edit_log "
            "WHERE action != 'undo' AND id NOT IN "
            "(SELECT undoes FROM edit_log WHERE undoes IS NOT NULL) ORDER BY id DESC LIMIT 1");
  if (!last.ok()) throw_sql("reading the edit log");
  const int rc = last.step();
  if (rc == SQLITE_DONE)
    throw ClothdbError(Status::NotFound, path_ + ": the edit log has nothing left to undo");
  if (rc != SQLITE_ROW) throw_sql("reading the edit log");
  EditLogEntry undone;
  undone.id = last.i64(0);
  undone.clip = last.i64(1);
  undone.action = last.text(2);
  undone.description = last.text(3);
  undone.has_changeset = last.i64(4) != 0;
  if (!undone.has_changeset)
    throw ClothdbError(Status::InvalidArgument,
                       path_ + ": edit " + std::to_string(undone.id) + " ('" + undone.action +
                           "') was logged without a changeset by an early build; it cannot be "
                           "undone exactly");
  Stmt blob(db_, "SELECT changeset FROM edit_log WHERE id = ?");
  if (!blob.ok() || blob.bind(1, undone.id).step() != SQLITE_ROW)
    throw_sql("reading an edit's changeset");
  int inverse_size = 0;
  void* inverse = nullptr;
  if (sqlite3changeset_invert(int(blob.bytes(0)),
                              const_cast<void*>(sqlite3_column_blob(blob.get(), 0)), &inverse_size,
                              &inverse) != SQLITE_OK)
    throw ClothdbError(Status::Corrupt, path_ + ": edit " + std::to_string(undone.id) +
                                            ": its changeset does not read back");
  UndoConflicts conflicts;
  const int applied =
      sqlite3changeset_apply(db_, inverse_size, inverse, nullptr, abort_on_conflict, &conflicts);
  if (applied != SQLITE_OK) {
    sqlite3_free(inverse);
    if (conflicts.count > 0)
      throw ClothdbError(Status::InvalidArgument,
                         path_ + ": cannot undo edit " + std::to_string(undone.id) + " (" +
                             undone.action + " of clip " + std::to_string(undone.clip) +
                             ") exactly: " + conflict_name(conflicts.kind) +
                             " since (written outside the edit log, e.g. by a precompute run); "
                             "nothing was changed");
    throw_sql("undoing an edit");
  }
  Stmt log(db_, (std::string("INSERT INTO edit_log(time, author, clip, action, description, "
                             "undoes, changeset) VALUES(") +
                 kNow + ", ?, ?, 'undo', ?, ?, ?)")
                    .c_str());
  log.bind(1, author).bind(2, undone.clip);
  log.bind(3, "undo of edit " + std::to_string(undone.id) + " (" + undone.action + ")");
  log.bind(4, undone.id).bind_blob(5, inverse, size_t(inverse_size));
  const int logged = log.ok() ? log.step() : log.rc();
  sqlite3_free(inverse);
  if (logged != SQLITE_DONE) throw_sql("logging an undo");
  t.commit();
  return undone;
}

void Writer::replace_clip_blob(int64_t clip, const std::vector<uint8_t>& blob, double max_error,
                               ClipStatus status) {
  codec::BlobInfo info;
  Error err;
  if (codec::read_info(blob.data(), blob.size(), &info, &err) != Status::Ok)
    throw ClothdbError(err.status, path_ + ": cloth clip blob: " + err.message);
  check_vertex_count(info.vertex_count, "the cloth clip");
  Stmt up(db_,
          "UPDATE cloth_clip SET frames = ?, frame_count = ?, error_bound = ?, max_error = ?, "
          "status = ? WHERE id = ?");
  up.bind_blob(1, blob.data(), blob.size()).bind(2, int64_t(info.frame_count));
  up.bind(3, info.bound).bind(4, max_error).bind(5, clip_status_name(status)).bind(6, clip);
  if (!up.ok() || up.step() != SQLITE_DONE) throw_sql("replacing clip frames");
  if (sqlite3_changes(db_) != 1)
    throw ClothdbError(Status::NotFound, path_ + ": no cloth clip " + std::to_string(clip));
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

// ----------------------------------------------------------------------------------- Reader

Reader::Reader(Reader&& other) noexcept
    : db_(std::exchange(other.db_, nullptr)),
      path_(std::move(other.path_)),
      schema_version_(other.schema_version_),
      codec_(other.codec_),
      clip_blob_stmt_(std::exchange(other.clip_blob_stmt_, nullptr)),
      state_blob_stmt_(std::exchange(other.state_blob_stmt_, nullptr)),
      borrowed_(std::exchange(other.borrowed_, false)),
      bases_(std::move(other.bases_)) {}

Reader& Reader::operator=(Reader&& other) noexcept {
  if (this != &other) {
    close();
    db_ = std::exchange(other.db_, nullptr);
    path_ = std::move(other.path_);
    schema_version_ = other.schema_version_;
    codec_ = other.codec_;
    clip_blob_stmt_ = std::exchange(other.clip_blob_stmt_, nullptr);
    state_blob_stmt_ = std::exchange(other.state_blob_stmt_, nullptr);
    borrowed_ = std::exchange(other.borrowed_, false);
    bases_ = std::move(other.bases_);
  }
  return *this;
}

Reader::~Reader() {
  close();
}

void Reader::close() {
  sqlite3_finalize(clip_blob_stmt_);
  sqlite3_finalize(state_blob_stmt_);
  clip_blob_stmt_ = state_blob_stmt_ = nullptr;
  bases_.clear();
  if (!borrowed_) sqlite3_close_v2(db_);
  db_ = nullptr;
  borrowed_ = false;
}

Status Reader::open_on(Writer& writer, Error* err) {
  close();
  path_ = writer.path();
  db_ = writer.handle();
  borrowed_ = true;
  const Status st = recognise(db_, path_, &schema_version_, &codec_, err);
  if (st != Status::Ok) close();
  return st;
}

Status Reader::open(const std::string& path, Error* err) {
  close();
  path_ = path;
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec))
    return fail(err, Status::IoError, "cannot open %s: is a directory, not a database file",
                path.c_str());
  if (!std::filesystem::is_regular_file(path, ec))
    return fail(err, Status::IoError, "cannot open %s: no such file", path.c_str());
  const int rc = sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READONLY, nullptr);
  if (rc != SQLITE_OK) {
    fail(err, Status::IoError, "cannot open %s: %s", path.c_str(),
         db_ ? sqlite3_errmsg(db_) : sqlite3_errstr(rc));
    close();
    return Status::IoError;
  }
  sqlite3_extended_result_codes(db_, 1);
  sqlite3_busy_timeout(db_, 10000);
  const Status st = recognise(db_, path, &schema_version_, &codec_, err);
  if (st != Status::Ok) close();
  return st;
}

Status Reader::step_error(const char* what, Error* err) {
  return fail(err, Status::IoError, "%s: %s: %s", path_.c_str(), what, sqlite3_errmsg(db_));
}

Status Reader::prepare(sqlite3_stmt** cache, const char* sql, Error* err) {
  if (!db_) return fail(err, Status::InvalidArgument, "reader is not open");
  if (*cache) return Status::Ok;
  if (sqlite3_prepare_v3(db_, sql, -1, SQLITE_PREPARE_PERSISTENT, cache, nullptr) != SQLITE_OK)
    return step_error("preparing a query", err);
  return Status::Ok;
}

// Runs `sql` and calls row(stmt) for each row; shared by the list functions.
template <typename F>
static Status for_each_row(sqlite3* db, const std::string& path, const char* sql, Error* err,
                           F&& row) {
  if (!db) return fail(err, Status::InvalidArgument, "reader is not open");
  Stmt s(db, sql);
  if (!s.ok())
    return fail(err, Status::IoError, "%s: %s: %s", path.c_str(), sql, sqlite3_errmsg(db));
  int rc;
  while ((rc = s.step()) == SQLITE_ROW) row(s);
  if (rc != SQLITE_DONE)
    return fail(err, Status::IoError, "%s: %s: %s", path.c_str(), sql, sqlite3_errmsg(db));
  return Status::Ok;
}

Status Reader::meta(const std::string& key, std::string* value, Error* err) {
  if (!db_) return fail(err, Status::InvalidArgument, "reader is not open");
  Stmt s(db_, "SELECT value FROM meta WHERE key = ?");
  const int rc = s.ok() ? s.bind(1, key).step() : s.rc();
  if (rc == SQLITE_DONE)
    return fail(err, Status::NotFound, "%s: no meta entry '%s'", path_.c_str(), key.c_str());
  if (rc != SQLITE_ROW) return step_error("reading meta", err);
  *value = s.text(0);
  return Status::Ok;
}

Status Reader::all_meta(std::vector<std::pair<std::string, std::string>>* out, Error* err) {
  out->clear();
  return for_each_row(db_, path_, "SELECT key, value FROM meta ORDER BY key", err,
                      [&](Stmt& s) { out->emplace_back(s.text(0), s.text(1)); });
}

Status Reader::garment(Garment* out, Error* err) {
  bool found = false;
  bool bad = false;
  const Status st = for_each_row(
      db_, path_,
      "SELECT vertex_count, triangle_count, triangles, rest_positions, material, solver "
      "FROM garment",
      err, [&](Stmt& s) {
        found = true;
        const size_t v = size_t(s.i64(0)), t = size_t(s.i64(1));
        if (s.bytes(2) != t * 3 * sizeof(uint32_t) || s.bytes(3) != v * 3 * sizeof(float)) {
          bad = true;
          return;
        }
        out->triangles.resize(t * 3);
        out->rest_positions.resize(v * 3);
        if (t) std::memcpy(out->triangles.data(), sqlite3_column_blob(s.get(), 2), s.bytes(2));
        std::memcpy(out->rest_positions.data(), sqlite3_column_blob(s.get(), 3), s.bytes(3));
        out->material = s.text(4);
        out->solver = s.text(5);
      });
  if (st != Status::Ok) return st;
  if (bad)
    return fail(err, Status::Corrupt, "%s: garment arrays do not match its counts", path_.c_str());
  if (!found) return fail(err, Status::NotFound, "%s: no garment stored", path_.c_str());
  return Status::Ok;
}

Status Reader::motion_files(std::vector<MotionFile>* out, Error* err) {
  out->clear();
  return for_each_row(db_, path_, "SELECT id, path, content_hash FROM motion_file ORDER BY id", err,
                      [&](Stmt& s) {
                        out->push_back({s.i64(0), s.text(1), s.text(2)});
                      });
}

Status Reader::primary_clips(std::vector<PrimaryClip>* out, Error* err) {
  out->clear();
  return for_each_row(db_, path_,
                      "SELECT id, name, motion_file, first_frame, frame_count, frame_rate "
                      "FROM primary_clip ORDER BY id",
                      err, [&](Stmt& s) {
                        out->push_back({s.i64(0), s.text(1), s.i64(2), int32_t(s.i64(3)),
                                        int32_t(s.i64(4)), s.f64(5)});
                      });
}

Status Reader::primary_transitions(std::vector<PrimaryTransition>* out, Error* err) {
  out->clear();
  return for_each_row(db_, path_,
                      "SELECT id, from_clip, from_frame, to_clip, to_frame, blend_frames, cost "
                      "FROM primary_transition ORDER BY id",
                      err, [&](Stmt& s) {
                        out->push_back({s.i64(0), s.i64(1), int32_t(s.i64(2)), s.i64(3),
                                        int32_t(s.i64(4)), int32_t(s.i64(5)), s.f64(6)});
                      });
}

Status Reader::cloth_states(std::vector<StoredState>* out, Error* err) {
  out->clear();
  return for_each_row(db_, path_,
                      "SELECT id, primary_clip, frame, source_clip, run, length(positions), "
                      "length(velocities) FROM cloth_state ORDER BY id",
                      err, [&](Stmt& s) {
                        out->push_back({s.i64(0), s.i64(1), int32_t(s.i64(2)), s.i64(3), s.i64(4),
                                        size_t(s.i64(5)), size_t(s.i64(6))});
                      });
}

// Version 1 files have no metric columns: they read as NULL (unknown).
static std::string clip_columns(int schema_version) {
  return std::string(
             "SELECT id, start_state, primary_clip, first_frame, frame_count, error_bound, "
             "max_error, max_strain, max_penetration, status, run, length(frames), ") +
         (schema_version >= 2 ? "mean_penetration, jitter, halved_steps, worst_frame"
                              : "NULL, NULL, NULL, NULL") +
         " FROM cloth_clip";
}

static ClothClip clip_from_row(Stmt& s) {
  ClothClip c;
  c.id = s.i64(0);
  c.start_state = s.i64(1);
  c.primary_clip = s.i64(2);
  c.first_frame = int32_t(s.i64(3));
  c.frame_count = int32_t(s.i64(4));
  c.error_bound = s.f64(5);
  c.max_error = s.f64(6);
  c.max_strain = s.f64(7);
  c.max_penetration = s.f64(8);
  parse_clip_status(s.text(9), &c.status);
  c.run = s.i64(10);
  c.blob_bytes = size_t(s.i64(11));
  c.mean_penetration = s.metric(12);
  c.jitter = s.metric(13);
  c.halved_steps = s.count(14);
  c.worst_frame = s.count(15);
  return c;
}

Status Reader::cloth_clips(std::vector<ClothClip>* out, Error* err) {
  out->clear();
  const std::string sql = clip_columns(schema_version_) + " ORDER BY id";
  return for_each_row(db_, path_, sql.c_str(), err,
                      [&](Stmt& s) { out->push_back(clip_from_row(s)); });
}

Status Reader::cloth_clip(int64_t id, ClothClip* out, Error* err) {
  const std::string sql = clip_columns(schema_version_) + " WHERE id = " + std::to_string(id);
  bool found = false;
  const Status st = for_each_row(db_, path_, sql.c_str(), err, [&](Stmt& s) {
    *out = clip_from_row(s);
    found = true;
  });
  if (st != Status::Ok) return st;
  if (!found)
    return fail(err, Status::NotFound, "%s: no cloth clip %lld", path_.c_str(), (long long)id);
  return Status::Ok;
}

Status Reader::cloth_edges(std::vector<ClothEdge>* out, Error* err) {
  out->clear();
  const char* sql = schema_version_ >= 2
                        ? "SELECT id, from_clip, to_state, blend_error, pop FROM cloth_edge "
                          "ORDER BY id"
                        : "SELECT id, from_clip, to_state, blend_error, NULL FROM cloth_edge "
                          "ORDER BY id";
  return for_each_row(db_, path_, sql, err, [&](Stmt& s) {
    out->push_back({s.i64(0), s.i64(1), s.i64(2), s.f64(3), s.metric(4)});
  });
}

Status Reader::cloth_links(std::vector<ClothLink>* out, Error* err) {
  out->clear();
  if (schema_version_ < 4) return Status::Ok;  // no links before version 4
  return for_each_row(
      db_, path_,
      "SELECT id, from_state, primary_clip, to_clip, blend_error, "
      "coalesce(run, 0) FROM cloth_link ORDER BY id",
      err, [&](Stmt& s) {
        out->push_back({s.i64(0), s.i64(1), s.i64(2), s.i64(3), s.f64(4), s.i64(5)});
      });
}

Status Reader::clip_steering(std::vector<ClipSteering>* out, Error* err) {
  out->clear();
  if (schema_version_ < 4) return Status::Ok;  // no steering before version 4
  return for_each_row(db_, path_,
                      "SELECT clip, target_state, distance, displacement, acceleration FROM "
                      "cloth_clip_steering ORDER BY clip",
                      err, [&](Stmt& s) {
                        out->push_back({s.i64(0), s.i64(1), s.f64(2), s.f64(3), s.f64(4)});
                      });
}

Status Reader::runs(std::vector<Run>* out, Error* err) {
  out->clear();
  return for_each_row(
      db_, path_,
      "SELECT id, started, finished, settings, cpu_seconds, host, notes FROM run "
      "ORDER BY id",
      err, [&](Stmt& s) {
        out->push_back({s.i64(0), s.text(1), s.text(2), s.text(3), s.f64(4), s.text(5), s.text(6)});
      });
}

Status Reader::edit_log(std::vector<EditLogEntry>* out, Error* err) {
  out->clear();
  return for_each_row(
      db_, path_,
      schema_version_ >= 3 ? "SELECT id, time, author, clip, action, description, old_status, "
                             "new_status, old_frames IS NOT NULL, undoes, changeset IS NOT NULL "
                             "FROM edit_log ORDER BY id"
                           : "SELECT id, time, author, clip, action, description, old_status, "
                             "new_status, old_frames IS NOT NULL, undoes, 0 FROM edit_log "
                             "ORDER BY id",
      err, [&](Stmt& s) {
        out->push_back({s.i64(0), s.text(1), s.text(2), s.i64(3), s.text(4), s.text(5), s.text(6),
                        s.text(7), s.i64(8) != 0, s.i64(9), s.i64(10) != 0});
      });
}

// Copies column `col` of the single row the statement yields into `blob`, then resets it so the
// read transaction ends (a reader holding one open would see no newer commits and would stall
// WAL checkpoints).
static Status copy_blob(sqlite3_stmt* s, int col, std::vector<uint8_t>* blob) {
  const uint8_t* p = static_cast<const uint8_t*>(sqlite3_column_blob(s, col));
  const size_t n = size_t(sqlite3_column_bytes(s, col));
  if (p)
    blob->assign(p, p + n);
  else
    blob->clear();
  return Status::Ok;
}

Status Reader::clip_blob(int64_t clip, std::vector<uint8_t>* blob, Error* err) {
  if (Status st = prepare(&clip_blob_stmt_, "SELECT frames FROM cloth_clip WHERE id = ?", err);
      st != Status::Ok)
    return st;
  sqlite3_bind_int64(clip_blob_stmt_, 1, clip);
  const int rc = sqlite3_step(clip_blob_stmt_);
  Status st = Status::Ok;
  if (rc == SQLITE_ROW)
    copy_blob(clip_blob_stmt_, 0, blob);
  else if (rc == SQLITE_DONE)
    st = fail(err, Status::NotFound, "%s: no cloth clip %lld", path_.c_str(), (long long)clip);
  else
    st = step_error("reading a cloth clip", err);
  sqlite3_reset(clip_blob_stmt_);
  return st;
}

Status Reader::state_blobs(int64_t state, std::vector<uint8_t>* positions,
                           std::vector<uint8_t>* velocities, Error* err) {
  if (Status st = prepare(&state_blob_stmt_,
                          "SELECT positions, velocities FROM cloth_state WHERE id = ?", err);
      st != Status::Ok)
    return st;
  sqlite3_bind_int64(state_blob_stmt_, 1, state);
  const int rc = sqlite3_step(state_blob_stmt_);
  Status st = Status::Ok;
  if (rc == SQLITE_ROW) {
    copy_blob(state_blob_stmt_, 0, positions);
    copy_blob(state_blob_stmt_, 1, velocities);
  } else if (rc == SQLITE_DONE) {
    st = fail(err, Status::NotFound, "%s: no cloth state %lld", path_.c_str(), (long long)state);
  } else {
    st = step_error("reading a cloth state", err);
  }
  sqlite3_reset(state_blob_stmt_);
  return st;
}

Status Reader::read_state(int64_t state, std::vector<float>* positions,
                          std::vector<float>* velocities, codec::DecodeScratch& scratch,
                          Error* err) {
  if (Status st = state_blobs(state, &state_pos_, &state_vel_, err); st != Status::Ok) return st;
  if (Status st = decode_all(state_pos_, positions, scratch, err); st != Status::Ok) return st;
  return decode_all(state_vel_, velocities, scratch, err);
}

}  // namespace clothdb::db
