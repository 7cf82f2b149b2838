#include "database/check.hpp"

#include <sqlite3.h>

#include <cstdarg>
#include <cstdio>
#include <filesystem>

#include "database/codec.hpp"

namespace clothdb::db {
namespace {

std::string format(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
std::string format(const char* fmt, ...) {
  char buf[512];
  va_list args;
  va_start(args, fmt);
  std::vsnprintf(buf, sizeof buf, fmt, args);
  va_end(args);
  return buf;
}

// Runs a query whose rows each describe one problem (first column text) or a count.
void collect(sqlite3* db, const char* sql, CheckReport& report, const char* prefix) {
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db, sql, -1, &s, nullptr) != SQLITE_OK) {
    report.problems.push_back(format("%s: cannot run check: %s", prefix, sqlite3_errmsg(db)));
    return;
  }
  int rc;
  while ((rc = sqlite3_step(s)) == SQLITE_ROW) {
    const unsigned char* t = sqlite3_column_text(s, 0);
    report.problems.push_back(std::string(prefix) + ": " +
                              (t ? reinterpret_cast<const char*>(t) : "?"));
  }
  if (rc != SQLITE_DONE)
    report.problems.push_back(format("%s: check failed: %s", prefix, sqlite3_errmsg(db)));
  sqlite3_finalize(s);
}

// One check of a blob against its row. `frames`/`vertices`: what the row says (0: unknown).
// Returns the blob's header (version 0 if it could not be read).
codec::BlobInfo check_blob(const void* data, size_t size, const std::string& what, int64_t frames,
                           int64_t vertices, Reader& reader, codec::DecodeScratch& scratch,
                           CheckReport& report) {
  ++report.blobs_checked;
  const uint8_t* p = static_cast<const uint8_t*>(data);
  Error err;
  codec::BlobInfo info;
  const codec::Basis* basis = nullptr;  // codec version 2: the basis the blob names
  if (codec::read_info(p, size, &info, &err) != Status::Ok ||
      reader.basis_for(p, size, &basis, &err) != Status::Ok ||
      codec::verify(p, size, scratch, &err, basis) != Status::Ok) {
    report.problems.push_back(what + ": " + err.message);
    return codec::BlobInfo{};
  }
  if (frames > 0 && info.frame_count != frames)
    report.problems.push_back(format("%s: blob holds %u frames, the row says %lld", what.c_str(),
                                     info.frame_count, (long long)frames));
  if (vertices > 0 && info.vertex_count != vertices)
    report.problems.push_back(format("%s: blob holds %u vertices, expected %lld", what.c_str(),
                                     info.vertex_count, (long long)vertices));
  return info;
}

uint64_t count(sqlite3* db, const char* sql) {
  sqlite3_stmt* s = nullptr;
  uint64_t n = 0;
  if (sqlite3_prepare_v2(db, sql, -1, &s, nullptr) == SQLITE_OK && sqlite3_step(s) == SQLITE_ROW)
    n = uint64_t(sqlite3_column_int64(s, 0));
  sqlite3_finalize(s);
  return n;
}

}  // namespace

CheckReport check_database(const std::string& path) {
  CheckReport report;
  Reader reader;
  Error err;
  if (reader.open(path, &err) != Status::Ok) {
    report.problems.push_back(err.message);
    // A damaged file may still answer SQLite's own check, which says more than "cannot read".
    sqlite3* db = nullptr;
    if (err.status != Status::NotClothdb && err.status != Status::NewerVersion &&
        sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
      sqlite3_stmt* s = nullptr;
      if (sqlite3_prepare_v2(db, "PRAGMA integrity_check(20)", -1, &s, nullptr) == SQLITE_OK) {
        while (sqlite3_step(s) == SQLITE_ROW) {
          const std::string row = reinterpret_cast<const char*>(sqlite3_column_text(s, 0));
          if (row != "ok") report.problems.push_back("sqlite integrity_check: " + row);
        }
      }
      sqlite3_finalize(s);
    }
    sqlite3_close_v2(db);
    return report;
  }
  sqlite3* db = reader.handle();
  // Everything below reads one consistent snapshot even while a writer commits.
  sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr);

  sqlite3_stmt* ic = nullptr;
  if (sqlite3_prepare_v2(db, "PRAGMA integrity_check(100)", -1, &ic, nullptr) == SQLITE_OK) {
    while (sqlite3_step(ic) == SQLITE_ROW) {
      const unsigned char* t = sqlite3_column_text(ic, 0);
      const std::string row = t ? reinterpret_cast<const char*>(t) : "?";
      if (row != "ok") report.problems.push_back("sqlite integrity_check: " + row);
    }
  } else {
    report.problems.push_back(std::string("sqlite integrity_check: ") + sqlite3_errmsg(db));
  }
  sqlite3_finalize(ic);

  collect(db,
          "SELECT printf('%s row %d: %s references a missing row', \"table\", rowid, parent) "
          "FROM pragma_foreign_key_check",
          report, "foreign key");
  // Explicit graph checks (the same as the foreign keys for the graph, with clearer messages,
  // and they do not depend on the tables having been created with those constraints).
  collect(db,
          "SELECT printf('cloth edge %d: from clip %d does not exist', e.id, e.from_clip) "
          "FROM cloth_edge e LEFT JOIN cloth_clip c ON c.id = e.from_clip WHERE c.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth edge %d: to state %d does not exist', e.id, e.to_state) "
          "FROM cloth_edge e LEFT JOIN cloth_state s ON s.id = e.to_state WHERE s.id IS NULL",
          report, "graph");
  collect(db,
          "SELECT printf('cloth clip %d: start state %d does not exist', c.id, c.start_state) "
          "FROM cloth_clip c LEFT JOIN cloth_state s ON s.id = c.start_state WHERE s.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth clip %d: primary clip %d does not exist', c.id, c.primary_clip) "
          "FROM cloth_clip c LEFT JOIN primary_clip p ON p.id = c.primary_clip WHERE p.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth state %d: primary clip %d does not exist', s.id, s.primary_clip) "
          "FROM cloth_state s LEFT JOIN primary_clip p ON p.id = s.primary_clip "
          "WHERE p.id IS NULL "
          "UNION ALL "
          "SELECT printf('cloth state %d: frame %d outside primary clip %d (%d frames)', s.id, "
          "s.frame, p.id, p.frame_count) FROM cloth_state s JOIN primary_clip p "
          "ON p.id = s.primary_clip WHERE s.frame < 0 OR s.frame > p.frame_count "
          "UNION ALL "
          "SELECT printf('primary transition %d: clip %d or %d does not exist', t.id, "
          "t.from_clip, t.to_clip) FROM primary_transition t "
          "WHERE t.from_clip NOT IN (SELECT id FROM primary_clip) "
          "OR t.to_clip NOT IN (SELECT id FROM primary_clip) "
          "UNION ALL "
          "SELECT printf('cloth clip %d: status ''%s'' is not ok, flagged or edited', id, status) "
          "FROM cloth_clip WHERE status NOT IN ('ok', 'flagged', 'edited')",
          report, "graph");
  // Quality metrics are lengths and counts: never negative (NULL: not measured). Version 1 files
  // have only the first two.
  collect(db,
          reader.schema_version() >= 2
              ? "SELECT printf('cloth clip %d: negative quality metric (strain %g, penetration "
                "%g, mean penetration %g, jitter %g)', id, max_strain, max_penetration, "
                "mean_penetration, jitter) FROM cloth_clip WHERE max_strain < 0 OR "
                "max_penetration < 0 OR mean_penetration < 0 OR jitter < 0 "
                "UNION ALL SELECT printf('cloth edge %d: negative pop %g', id, pop) FROM "
                "cloth_edge WHERE pop < 0"
              : "SELECT printf('cloth clip %d: negative quality metric (strain %g, penetration "
                "%g)', id, max_strain, max_penetration) FROM cloth_clip WHERE max_strain < 0 OR "
                "max_penetration < 0",
          report, "metrics");
  report.rows_checked = count(db,
                              "SELECT (SELECT count(*) FROM cloth_edge) + "
                              "(SELECT count(*) FROM cloth_clip) + "
                              "(SELECT count(*) FROM cloth_state) + "
                              "(SELECT count(*) FROM primary_transition)");

  const int64_t garment_vertices = int64_t(count(db, "SELECT vertex_count FROM garment"));
  codec::DecodeScratch scratch;
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "SELECT id, frame_count, vertex_count, frames, error_bound, max_error "
                         "FROM cloth_clip",
                         -1, &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      const int64_t id = sqlite3_column_int64(s, 0);
      const int64_t vertices = sqlite3_column_int64(s, 2);
      const std::string what = format("cloth clip %lld", (long long)id);
      if (garment_vertices > 0 && vertices != garment_vertices)
        report.problems.push_back(format("%s: %lld vertices, the garment has %lld", what.c_str(),
                                         (long long)vertices, (long long)garment_vertices));
      const codec::BlobInfo info =
          check_blob(sqlite3_column_blob(s, 3), size_t(sqlite3_column_bytes(s, 3)), what,
                     sqlite3_column_int64(s, 1), vertices, reader, scratch, report);
      // The bound: the blob's codec bound and the error measured when it was encoded must lie
      // within the clip's recorded bound (after `db recode`, the old bound plus the new one).
      // Without the simulation's own frames this is what can be checked; the decoder itself
      // range-checks every value against the blob's grid.
      const double bound = sqlite3_column_double(s, 4), max_error = sqlite3_column_double(s, 5);
      const double slack = 1 + 1e-9;
      if (info.version != 0 && sqlite3_column_type(s, 4) != SQLITE_NULL &&
          info.bound > bound * slack)
        report.problems.push_back(format("%s: blob bound %g m exceeds the recorded bound %g m",
                                         what.c_str(), info.bound, bound));
      if (sqlite3_column_type(s, 4) != SQLITE_NULL && sqlite3_column_type(s, 5) != SQLITE_NULL &&
          !(max_error <= bound * slack))
        report.problems.push_back(format("%s: measured error %g m exceeds the recorded bound %g m",
                                         what.c_str(), max_error, bound));
    }
  }
  sqlite3_finalize(s);
  if (sqlite3_prepare_v2(db, "SELECT id, vertex_count, positions, velocities FROM cloth_state", -1,
                         &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      const int64_t id = sqlite3_column_int64(s, 0);
      const int64_t vertices = sqlite3_column_int64(s, 1);
      if (garment_vertices > 0 && vertices != garment_vertices)
        report.problems.push_back(format("cloth state %lld: %lld vertices, the garment has %lld",
                                         (long long)id, (long long)vertices,
                                         (long long)garment_vertices));
      for (int col : {2, 3}) {
        const std::string what =
            format("cloth state %lld %s", (long long)id, col == 2 ? "positions" : "velocities");
        check_blob(sqlite3_column_blob(s, col), size_t(sqlite3_column_bytes(s, col)), what, 1,
                   vertices, reader, scratch, report);
      }
    }
  }
  sqlite3_finalize(s);
  if (sqlite3_prepare_v2(db, "SELECT id, old_frames FROM edit_log WHERE old_frames IS NOT NULL", -1,
                         &s, nullptr) == SQLITE_OK) {
    while (sqlite3_step(s) == SQLITE_ROW) {
      check_blob(sqlite3_column_blob(s, 1), size_t(sqlite3_column_bytes(s, 1)),
                 format("edit %lld old frames", (long long)sqlite3_column_int64(s, 0)), 0,
                 garment_vertices, reader, scratch, report);
    }
  }
  sqlite3_finalize(s);
  sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  return report;
}

DatabaseInfo read_database_info(const std::string& path) {
  Reader reader;
  Error err;
  if (reader.open(path, &err) != Status::Ok) throw ClothdbError(err.status, err.message);
  DatabaseInfo info;
  info.path = path;
  std::error_code ec;
  info.file_bytes = std::filesystem::file_size(path, ec);
  const auto wal = std::filesystem::file_size(path + "-wal", ec);
  if (!ec) info.file_bytes += wal;
  info.schema_version = reader.schema_version();
  info.codec = reader.codec();
  if (reader.all_meta(&info.meta, &err) != Status::Ok) throw ClothdbError(err.status, err.message);
  sqlite3* db = reader.handle();
  sqlite3_exec(db, "BEGIN", nullptr, nullptr, nullptr);
  info.garment_vertices = uint32_t(count(db, "SELECT vertex_count FROM garment"));
  info.garment_triangles = uint32_t(count(db, "SELECT triangle_count FROM garment"));
  info.motion_files = count(db, "SELECT count(*) FROM motion_file");
  info.primary_clips = count(db, "SELECT count(*) FROM primary_clip");
  info.primary_transitions = count(db, "SELECT count(*) FROM primary_transition");
  info.cloth_states = count(db, "SELECT count(*) FROM cloth_state");
  info.cloth_clips = count(db, "SELECT count(*) FROM cloth_clip");
  info.cloth_edges = count(db, "SELECT count(*) FROM cloth_edge");
  info.runs = count(db, "SELECT count(*) FROM run");
  info.edits = count(db, "SELECT count(*) FROM edit_log");
  info.clips_ok = count(db, "SELECT count(*) FROM cloth_clip WHERE status = 'ok'");
  info.clips_flagged = count(db, "SELECT count(*) FROM cloth_clip WHERE status = 'flagged'");
  info.clips_edited = count(db, "SELECT count(*) FROM cloth_clip WHERE status = 'edited'");
  info.cloth_frames = count(db, "SELECT total(frame_count) FROM cloth_clip");
  info.clip_blob_bytes = count(db, "SELECT total(length(frames)) FROM cloth_clip");
  info.clip_raw_bytes = count(db, "SELECT total(frame_count * vertex_count * 12) FROM cloth_clip");
  info.state_blob_bytes =
      count(db, "SELECT total(length(positions) + length(velocities)) FROM cloth_state");
  info.clips_v2 = count(db, "SELECT count(*) FROM cloth_clip WHERE substr(frames, 5, 1) = x'02'");
  info.clips_v1 = info.cloth_clips - info.clips_v2;
  info.states_v2 =
      count(db, "SELECT count(*) FROM cloth_state WHERE substr(positions, 5, 1) = x'02'");
  info.states_v1 = info.cloth_states - info.states_v2;
  if (list_bases(db, path, &info.bases, &err) != Status::Ok)
    throw ClothdbError(err.status, err.message);
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "SELECT (SELECT max(max_error) FROM cloth_clip), "
                         "(SELECT total(cpu_seconds) FROM run)",
                         -1, &s, nullptr) == SQLITE_OK &&
      sqlite3_step(s) == SQLITE_ROW) {
    info.max_clip_error = sqlite3_column_double(s, 0);
    info.run_cpu_seconds = sqlite3_column_double(s, 1);
  }
  sqlite3_finalize(s);
  sqlite3_exec(db, "COMMIT", nullptr, nullptr, nullptr);
  return info;
}

}  // namespace clothdb::db
