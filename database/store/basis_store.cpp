#include "database/store/basis_store.hpp"

#include "database/sqlite/statement.hpp"

namespace clothdb::db {

using sql::Stmt;

int64_t store_basis(Writer& writer, const codec::Basis& basis, const std::string& source) {
  Writer::Transaction t(writer);
  writer.ensure_table("codec_basis");
  const std::vector<uint8_t> data = codec::serialize_basis(basis);
  Stmt s(writer.handle(), std::string("INSERT INTO codec_basis(vertex_count, mode_count, data, "
                                      "created, source) VALUES(?, ?, ?, ") +
                              sql::kNow + ", ?)");
  s.bind(1, int64_t(basis.vertex_count)).bind(2, int64_t(basis.mode_count));
  s.bind_blob(3, data.data(), data.size()).bind(4, source);
  if (!s.ok() || s.step() != SQLITE_DONE) writer.throw_sql("storing a basis");
  const int64_t id = sqlite3_last_insert_rowid(writer.handle());
  t.commit();
  return id;
}

bool compact_file(Writer& writer, std::string* why) {
  sqlite3* db = writer.handle();
  if (sqlite3_exec(db, "VACUUM", nullptr, nullptr, nullptr) != SQLITE_OK ||
      sqlite3_exec(db, "PRAGMA wal_checkpoint(TRUNCATE)", nullptr, nullptr, nullptr) != SQLITE_OK) {
    if (why) *why = sqlite3_errmsg(db);
    return false;
  }
  return true;
}

void remove_basis(Writer& writer, int64_t id) {
  Stmt s(writer.handle(), "DELETE FROM codec_basis WHERE id = ?");
  if (!s.ok() || s.bind(1, id).step() != SQLITE_DONE) writer.throw_sql("removing a basis");
}

void recode_clip_blob(Writer& writer, int64_t clip, const std::vector<uint8_t>& blob,
                      double error_bound, double max_error) {
  Writer::Transaction t(writer);
  writer.note_blob_version(blob);
  Stmt s(writer.handle(),
         "UPDATE cloth_clip SET frames = ?, error_bound = ?, max_error = ? WHERE id = ?");
  s.bind_blob(1, blob.data(), blob.size()).bind(2, error_bound).bind(3, max_error).bind(4, clip);
  if (!s.ok() || s.step() != SQLITE_DONE) writer.throw_sql("recoding a clip");
  if (sqlite3_changes(writer.handle()) != 1)
    throw ClothdbError(Status::NotFound, writer.path() + ": no cloth clip " + std::to_string(clip));
  t.commit();
}

void recode_state_blobs(Writer& writer, int64_t state, const std::vector<uint8_t>& positions,
                        const std::vector<uint8_t>& velocities) {
  Writer::Transaction t(writer);
  writer.note_blob_version(positions);
  writer.note_blob_version(velocities);
  Stmt s(writer.handle(), "UPDATE cloth_state SET positions = ?, velocities = ? WHERE id = ?");
  s.bind_blob(1, positions.data(), positions.size());
  s.bind_blob(2, velocities.data(), velocities.size()).bind(3, state);
  if (!s.ok() || s.step() != SQLITE_DONE) writer.throw_sql("recoding a state");
  if (sqlite3_changes(writer.handle()) != 1)
    throw ClothdbError(Status::NotFound,
                       writer.path() + ": no cloth state " + std::to_string(state));
  t.commit();
}

}  // namespace clothdb::db
