#include "database/format/reader.hpp"

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <type_traits>
#include <utility>

#include "database/format/artist_mesh.hpp"
#include "database/format/meta_keys.hpp"
#include "database/sqlite/statement.hpp"

namespace clothdb::db {

using sql::Stmt;

// How much of a file a Reader maps (Reader::open): 1 GiB of address space, not of memory.
constexpr int64_t kMmapBytes = int64_t(1) << 30;

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
  if (app_id != kApplicationId) {
    // SQLite reads an empty file, or one cut inside its 100-byte header, as an empty database:
    // "a SQLite database but not a clothdb one" would send the user looking for the wrong file.
    std::error_code ec;
    const auto bytes = std::filesystem::file_size(path, ec);
    if (!ec && bytes < 512)  // SQLite's smallest page
      return fail(err, Status::NotClothdb,
                  "%s is not a clothdb database: %s (%llu bytes, less than one SQLite page)",
                  path.c_str(), bytes == 0 ? "an empty file" : "truncated, or not a database",
                  (unsigned long long)bytes);
    return fail(err, Status::NotClothdb,
                "%s is a SQLite database but not a clothdb one (application_id 0x%08x, expected "
                "0x%08x)",
                path.c_str(), uint32_t(app_id), uint32_t(kApplicationId));
  }
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
  // Only the keys recognition needs: the scene and graph texts can be large.
  const char* const keys[] = {meta::kFormat,
                              meta::kFormatVersion,
                              meta::kCodecFormatVersion,
                              meta::kCodecPositionBound,
                              meta::kCodecVelocityBound,
                              meta::kCodecKeyInterval,
                              meta::kCodecZstdLevel};
  Stmt m(db, "SELECT key, value FROM meta WHERE key IN (?, ?, ?, ?, ?, ?, ?)");
  if (!m.ok())
    return fail(err, Status::Corrupt, "%s: no meta table: %s", path.c_str(), sqlite3_errmsg(db));
  for (int i = 0; i < 7; ++i) m.bind(i + 1, keys[i]);
  bool format = false;
  CodecSettings c;
  int found = 0;
  while (m.step() == SQLITE_ROW) {
    const std::string key = m.text(0);
    if (key == meta::kFormat) format = m.text(1) == meta::kFormatName;
    // Version keys must be versions this build knows: a newer one is refused like a newer
    // schema, anything else (text, negative) as damage.
    const int known = key == meta::kFormatVersion        ? kSchemaVersion
                      : key == meta::kCodecFormatVersion ? int(codec::kNewestFormatVersion)
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
    if (key == meta::kCodecPositionBound) {
      c.position_bound = m.f64(1);
      ++found;
    } else if (key == meta::kCodecVelocityBound) {
      c.velocity_bound = m.f64(1);
      ++found;
    } else if (key == meta::kCodecKeyInterval) {
      c.key_interval = uint32_t(m.i64(1));
      ++found;
    } else if (key == meta::kCodecZstdLevel) {
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

Status Reader::open_borrowed(sqlite3* connection, const std::string& path, Error* err) {
  close();
  path_ = path;
  db_ = connection;
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
  // Pages read through a memory map of the file (up to kMmapBytes of it; SQLite clamps to its own
  // limit and falls back to read() where it cannot map) instead of a read() call and a copy per
  // page: a cloth clip's blob spans hundreds of overflow pages (750 KB at 10,000 vertices in codec
  // v3), and the runtime reads one per clip it plays. Measured: 4x less time reading the clips of
  // the runtime bench's 10,000-vertex file (docs/notebook/codec_v3.md, "Seventh session"). The map
  // is of the file, so its pages are the page cache's, shared by every reader of the file; what a
  // player owns is unchanged.
  {
    Stmt mmap(db_, "PRAGMA mmap_size = " + std::to_string(kMmapBytes));
    if (mmap.ok()) mmap.step();  // without a map SQLite reads as before: nothing to report
  }
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
  if (sql::prepare_persistent(db_, sql, cache) != SQLITE_OK)
    return step_error("preparing a query", err);
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
  return sql::for_each_row(db_, path_, "SELECT key, value FROM meta ORDER BY key", err,
                           [&](Stmt& s) { out->emplace_back(s.text(0), s.text(1)); });
}

Status Reader::garment(Garment* out, Error* err) {
  bool found = false;
  bool bad = false;
  const Status st = sql::for_each_row(
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

Status Reader::artist_mesh(ArtistMesh* out, Error* err) {
  Garment g;
  if (Status st = garment(&g, err); st != Status::Ok) return st;
  bool found = false, bad = false;
  if (schema_version_ >= 5) {
    ArtistMesh m;
    const Status st = sql::for_each_row(
        db_, path_,
        "SELECT source, vertex_count, face_count, render_vertex_count, render_triangle_count, "
        "positions, face_sizes, corners, uvs, corner_uvs, normals, corner_normals, "
        "render_vertices, render_triangles, map_vertices, map_weights FROM garment_mesh",
        err, [&](Stmt& s) {
          found = true;
          m.source = s.text(0);
          int c = 5;
          auto read = [&](auto* v) {
            using T = typename std::remove_pointer_t<decltype(v)>::value_type;
            const size_t bytes = s.bytes(c);
            if (bytes % sizeof(T) != 0) bad = true;
            v->resize(bytes / sizeof(T));
            if (!v->empty()) std::memcpy(v->data(), s.blob(c), v->size() * sizeof(T));
            ++c;
          };
          read(&m.positions);
          read(&m.face_sizes);
          read(&m.corners);
          read(&m.uvs);
          read(&m.corner_uvs);
          read(&m.normals);
          read(&m.corner_normals);
          read(&m.render_vertices);
          read(&m.render_triangles);
          read(&m.map_vertices);
          read(&m.map_weights);
          if (uint64_t(s.i64(1)) != m.vertex_count() || uint64_t(s.i64(2)) != m.face_count() ||
              uint64_t(s.i64(3)) != m.render_vertex_count() ||
              uint64_t(s.i64(4)) != m.render_triangle_count())
            bad = true;
        });
    if (st != Status::Ok) return st;
    if (bad)
      return fail(err, Status::Corrupt, "%s: garment_mesh arrays do not match its counts",
                  path_.c_str());
    if (found) {
      const Status gs = sql::for_each_row(
          db_, path_, "SELECT name, material, faces FROM garment_group ORDER BY id", err,
          [&](Stmt& s) {
            ArtistGroup group{s.text(0), s.text(1), {}};
            group.faces.resize(s.bytes(2) / sizeof(uint32_t));
            if (!group.faces.empty())
              std::memcpy(group.faces.data(), s.blob(2), group.faces.size() * sizeof(uint32_t));
            m.groups.push_back(std::move(group));
          });
      if (gs != Status::Ok) return gs;
      if (Status cs = check_artist_mesh(m, g.vertex_count(), path_, err); cs != Status::Ok)
        return cs;
      *out = std::move(m);
      return Status::Ok;
    }
  }
  *out = identity_artist_mesh(g);
  return Status::Ok;
}

Status Reader::motion_files(std::vector<MotionFile>* out, Error* err) {
  out->clear();
  return sql::for_each_row(db_, path_, "SELECT id, path, content_hash FROM motion_file ORDER BY id",
                           err, [&](Stmt& s) {
                             out->push_back({s.i64(0), s.text(1), s.text(2)});
                           });
}

Status Reader::source_files(std::vector<SourceFile>* out, Error* err) {
  out->clear();
  if (schema_version_ < 5) return Status::Ok;  // not stored before version 5
  return sql::for_each_row(
      db_, path_, "SELECT id, role, path, content_hash, bytes FROM source_file ORDER BY id", err,
      [&](Stmt& s) {
        SourceFile f{s.i64(0), s.text(1), s.text(2), s.text(3), {}};
        const auto* p = static_cast<const uint8_t*>(s.blob(4));
        f.bytes.assign(p, p + s.bytes(4));
        out->push_back(std::move(f));
      });
}

Status Reader::primary_clips(std::vector<PrimaryClip>* out, Error* err) {
  out->clear();
  return sql::for_each_row(db_, path_,
                           "SELECT id, name, motion_file, first_frame, frame_count, frame_rate "
                           "FROM primary_clip ORDER BY id",
                           err, [&](Stmt& s) {
                             out->push_back({s.i64(0), s.text(1), s.i64(2), int32_t(s.i64(3)),
                                             int32_t(s.i64(4)), s.f64(5)});
                           });
}

Status Reader::primary_transitions(std::vector<PrimaryTransition>* out, Error* err) {
  out->clear();
  return sql::for_each_row(
      db_, path_,
      "SELECT id, from_clip, from_frame, to_clip, to_frame, blend_frames, cost "
      "FROM primary_transition ORDER BY id",
      err, [&](Stmt& s) {
        out->push_back({s.i64(0), s.i64(1), int32_t(s.i64(2)), s.i64(3), int32_t(s.i64(4)),
                        int32_t(s.i64(5)), s.f64(6)});
      });
}

Status Reader::cloth_states(std::vector<StoredState>* out, Error* err) {
  out->clear();
  return sql::for_each_row(db_, path_,
                           "SELECT id, primary_clip, frame, source_clip, run, length(positions), "
                           "length(velocities) FROM cloth_state ORDER BY id",
                           err, [&](Stmt& s) {
                             out->push_back({s.i64(0), s.i64(1), int32_t(s.i64(2)), s.i64(3),
                                             s.i64(4), size_t(s.i64(5)), size_t(s.i64(6))});
                           });
}

// Version 1 files have no metric columns, files before version 5 no self_intersections: they read
// as NULL (unknown).
static std::string clip_columns(int schema_version) {
  return std::string(
             "SELECT id, start_state, primary_clip, first_frame, frame_count, error_bound, "
             "max_error, max_strain, max_penetration, status, run, length(frames), ") +
         (schema_version >= 2 ? "mean_penetration, jitter, halved_steps, worst_frame"
                              : "NULL, NULL, NULL, NULL") +
         (schema_version >= 5 ? ", self_intersections" : ", NULL") + " FROM cloth_clip";
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
  c.self_intersections = s.count(16);
  return c;
}

Status Reader::cloth_clips(std::vector<ClothClip>* out, Error* err) {
  out->clear();
  const std::string sql = clip_columns(schema_version_) + " ORDER BY id";
  return sql::for_each_row(db_, path_, sql.c_str(), err,
                           [&](Stmt& s) { out->push_back(clip_from_row(s)); });
}

Status Reader::cloth_clip(int64_t id, ClothClip* out, Error* err) {
  const std::string sql = clip_columns(schema_version_) + " WHERE id = " + std::to_string(id);
  bool found = false;
  const Status st = sql::for_each_row(db_, path_, sql.c_str(), err, [&](Stmt& s) {
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
  return sql::for_each_row(db_, path_, sql, err, [&](Stmt& s) {
    out->push_back({s.i64(0), s.i64(1), s.i64(2), s.f64(3), s.metric(4)});
  });
}

Status Reader::cloth_links(std::vector<ClothLink>* out, Error* err) {
  out->clear();
  if (schema_version_ < 4) return Status::Ok;  // no links before version 4
  return sql::for_each_row(
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
  return sql::for_each_row(db_, path_,
                           "SELECT clip, target_state, distance, displacement, acceleration FROM "
                           "cloth_clip_steering ORDER BY clip",
                           err, [&](Stmt& s) {
                             out->push_back({s.i64(0), s.i64(1), s.f64(2), s.f64(3), s.f64(4)});
                           });
}

Status Reader::runs(std::vector<Run>* out, Error* err) {
  out->clear();
  return sql::for_each_row(
      db_, path_,
      "SELECT id, started, finished, settings, cpu_seconds, host, notes FROM run "
      "ORDER BY id",
      err, [&](Stmt& s) {
        out->push_back({s.i64(0), s.text(1), s.text(2), s.text(3), s.f64(4), s.text(5), s.text(6)});
      });
}

Status Reader::edit_log(std::vector<EditLogEntry>* out, Error* err) {
  out->clear();
  return sql::for_each_row(
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
static void copy_blob(sqlite3_stmt* s, int col, std::vector<uint8_t>* blob) {
  const uint8_t* p = static_cast<const uint8_t*>(sqlite3_column_blob(s, col));
  const size_t n = size_t(sqlite3_column_bytes(s, col));
  if (p)
    blob->assign(p, p + n);
  else
    blob->clear();
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
