#include "database/format/contracts.hpp"

#include "database/sqlite/statement.hpp"

namespace clothdb::db {

using sql::Stmt;

Status clip_contracts(sqlite3* db, const std::string& path, std::vector<ClipContract>* out,
                      Error* err) {
  out->clear();
  Stmt t(db, "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'codec_contract'");
  if (!t.ok() || t.step() != SQLITE_ROW) return Status::Ok;
  Stmt s(db,
         "SELECT clip, rms, max, jitter, rms_cap, max_cap, jitter_cap FROM codec_contract "
         "ORDER BY clip");
  if (!s.ok())
    return fail(err, Status::Corrupt, "%s: table codec_contract: %s", path.c_str(),
                sqlite3_errmsg(db));
  int rc;
  while ((rc = s.step()) == SQLITE_ROW) {
    ClipContract c;
    c.clip = s.i64(0);
    c.measured = {s.f64(1), s.f64(2), s.f64(3)};
    c.caps = {s.f64(4), s.f64(5), s.f64(6)};
    out->push_back(c);
  }
  if (rc != SQLITE_DONE)
    return fail(err, Status::Corrupt, "%s: reading codec_contract: %s", path.c_str(),
                sqlite3_errmsg(db));
  return Status::Ok;
}

}  // namespace clothdb::db
