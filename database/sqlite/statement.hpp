// The one place clothdb prepares SQL: a statement that finalizes itself, the mapping from SQLite's
// result codes to clothdb's Status, and the one timestamp format. Internal to database/: nothing
// outside it includes <sqlite3.h> to prepare a statement (the runtime and the tools go through the
// Reader and the Writer).
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <string>

#include "database/format/rows.hpp"  // kUnknownMetric
#include "database/format/status.hpp"

namespace clothdb::db::sql {

// The SQL expression every stored time uses: ISO 8601 UTC with milliseconds.
inline constexpr const char* kNow = "strftime('%Y-%m-%dT%H:%M:%fZ', 'now')";

// What a failed SQLite call means for the caller: a constraint is a bad argument, a damaged page
// is corruption, everything else is I/O (busy, disk full, cannot open).
Status status_of(int sqlite_code);

// A prepared statement that finalizes itself. Errors are SQLite codes; the writer turns them into
// exceptions, the reader into Status values (both through status_of).
class Stmt {
 public:
  Stmt(sqlite3* db, const char* sql);
  Stmt(sqlite3* db, const std::string& sql) : Stmt(db, sql.c_str()) {}
  ~Stmt() { sqlite3_finalize(s_); }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;
  // Whether the statement was prepared (what step() returned since is step()'s own result).
  bool ok() const { return s_ != nullptr; }
  // The last SQLite result: of preparing, then of the last step().
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
  // The caller keeps the bytes alive until the statement has stepped.
  Stmt& bind_blob(int i, const void* data, size_t size) {
    sqlite3_bind_blob64(s_, i, data, sqlite3_uint64(size), SQLITE_STATIC);
    return *this;
  }
  Stmt& bind_null(int i) {
    sqlite3_bind_null(s_, i);
    return *this;
  }
  // Unknown metrics (NaN, or a negative count) are stored as NULL.
  Stmt& bind_metric(int i, double v) { return v != v ? bind_null(i) : bind(i, v); }
  Stmt& bind_count(int i, int64_t v) { return v < 0 ? bind_null(i) : bind(i, v); }
  Stmt& bind_id_or_null(int i, int64_t id) { return id == 0 ? bind_null(i) : bind(i, id); }
  // SQLITE_ROW, SQLITE_DONE or an error code.
  int step() { return rc_ = s_ ? sqlite3_step(s_) : rc_; }
  // Ready to step again with new bindings (a cached statement).
  void reset() {
    sqlite3_reset(s_);
    sqlite3_clear_bindings(s_);
  }
  int64_t i64(int c) { return sqlite3_column_int64(s_, c); }
  double f64(int c) { return sqlite3_column_double(s_, c); }
  std::string text(int c);
  bool is_null(int c) { return sqlite3_column_type(s_, c) == SQLITE_NULL; }
  double metric(int c) { return is_null(c) ? kUnknownMetric : f64(c); }
  int32_t count(int c) { return is_null(c) ? -1 : int32_t(i64(c)); }
  size_t bytes(int c) { return size_t(sqlite3_column_bytes(s_, c)); }
  const void* blob(int c) { return sqlite3_column_blob(s_, c); }

 private:
  sqlite3_stmt* s_ = nullptr;
  int rc_ = SQLITE_OK;
};

// A statement prepared once and kept (SQLITE_PREPARE_PERSISTENT) for a Reader's hot paths (blob
// reads per frame): prepared on first use, finalized by the owner.
int prepare_persistent(sqlite3* db, const char* sql, sqlite3_stmt** out);

// Runs `sql` and calls row(stmt) for each row. Errors name `path` and the statement.
template <typename F>
Status for_each_row(sqlite3* db, const std::string& path, const char* sql, Error* err, F&& row) {
  if (!db) return fail(err, Status::InvalidArgument, "reader is not open");
  Stmt s(db, sql);
  if (!s.ok())
    return fail(err, status_of(s.rc()), "%s: %s: %s", path.c_str(), sql, sqlite3_errmsg(db));
  int rc;
  while ((rc = s.step()) == SQLITE_ROW) row(s);
  if (rc != SQLITE_DONE)
    return fail(err, status_of(rc), "%s: %s: %s", path.c_str(), sql, sqlite3_errmsg(db));
  return Status::Ok;
}

// Shortest decimal text that reads back as the same double (meta values are read by people too).
std::string to_text(double v);

}  // namespace clothdb::db::sql
