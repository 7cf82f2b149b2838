#include "database/basis_store.hpp"

#include <sqlite3.h>

namespace clothdb::db {
namespace {

[[noreturn]] void throw_sql(sqlite3* db, const std::string& path, const char* what) {
  throw ClothdbError(Status::IoError, path + ": " + what + ": " + sqlite3_errmsg(db));
}

bool has_basis_table(sqlite3* db) {
  sqlite3_stmt* s = nullptr;
  bool found = false;
  if (sqlite3_prepare_v2(db,
                         "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = "
                         "'codec_basis'",
                         -1, &s, nullptr) == SQLITE_OK)
    found = sqlite3_step(s) == SQLITE_ROW;
  sqlite3_finalize(s);
  return found;
}

}  // namespace

int64_t store_basis(Writer& writer, const codec::Basis& basis, const std::string& source) {
  sqlite3* db = writer.handle();
  Writer::Transaction t(writer);
  if (sqlite3_exec(db,
                   "CREATE TABLE IF NOT EXISTS codec_basis("
                   "id INTEGER PRIMARY KEY, "
                   "vertex_count INTEGER NOT NULL CHECK (vertex_count > 0), "
                   "mode_count INTEGER NOT NULL CHECK (mode_count >= 0), "
                   "data BLOB NOT NULL, "
                   "created TEXT NOT NULL, "
                   "source TEXT NOT NULL)",
                   nullptr, nullptr, nullptr) != SQLITE_OK)
    throw_sql(db, writer.path(), "creating table codec_basis");
  const std::vector<uint8_t> data = codec::serialize_basis(basis);
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "INSERT INTO codec_basis(vertex_count, mode_count, data, created, source) "
                         "VALUES(?, ?, ?, strftime('%Y-%m-%dT%H:%M:%SZ', 'now'), ?)",
                         -1, &s, nullptr) != SQLITE_OK)
    throw_sql(db, writer.path(), "storing a basis");
  sqlite3_bind_int64(s, 1, basis.vertex_count);
  sqlite3_bind_int64(s, 2, basis.mode_count);
  sqlite3_bind_blob64(s, 3, data.data(), data.size(), SQLITE_STATIC);
  sqlite3_bind_text(s, 4, source.c_str(), -1, SQLITE_TRANSIENT);
  const int rc = sqlite3_step(s);
  sqlite3_finalize(s);
  if (rc != SQLITE_DONE) throw_sql(db, writer.path(), "storing a basis");
  const int64_t id = sqlite3_last_insert_rowid(db);
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
  sqlite3* db = writer.handle();
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db, "DELETE FROM codec_basis WHERE id = ?", -1, &s, nullptr) != SQLITE_OK)
    throw_sql(db, writer.path(), "removing a basis");
  sqlite3_bind_int64(s, 1, id);
  const int rc = sqlite3_step(s);
  sqlite3_finalize(s);
  if (rc != SQLITE_DONE) throw_sql(db, writer.path(), "removing a basis");
}

Status load_basis(sqlite3* db, const std::string& path, int64_t id, codec::Basis* out, Error* err) {
  if (!has_basis_table(db))
    return fail(err, Status::NotFound, "%s: no basis %lld (the file has no codec_basis table)",
                path.c_str(), (long long)id);
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db, "SELECT data FROM codec_basis WHERE id = ?", -1, &s, nullptr) !=
      SQLITE_OK)
    return fail(err, Status::IoError, "%s: reading basis %lld: %s", path.c_str(), (long long)id,
                sqlite3_errmsg(db));
  sqlite3_bind_int64(s, 1, id);
  Status st;
  const int rc = sqlite3_step(s);
  if (rc == SQLITE_ROW) {
    const auto* p = static_cast<const uint8_t*>(sqlite3_column_blob(s, 0));
    st = codec::parse_basis(p, size_t(sqlite3_column_bytes(s, 0)), id, out, err);
  } else if (rc == SQLITE_DONE) {
    st = fail(err, Status::NotFound, "%s: no basis %lld", path.c_str(), (long long)id);
  } else {
    st = fail(err, Status::IoError, "%s: reading basis %lld: %s", path.c_str(), (long long)id,
              sqlite3_errmsg(db));
  }
  sqlite3_finalize(s);
  return st;
}

Status list_bases(sqlite3* db, const std::string& path, std::vector<BasisRow>* out, Error* err) {
  out->clear();
  if (!has_basis_table(db)) return Status::Ok;
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "SELECT id, vertex_count, mode_count, length(data), created, source FROM "
                         "codec_basis ORDER BY id",
                         -1, &s, nullptr) != SQLITE_OK)
    return fail(err, Status::IoError, "%s: listing bases: %s", path.c_str(), sqlite3_errmsg(db));
  int rc;
  while ((rc = sqlite3_step(s)) == SQLITE_ROW) {
    BasisRow r;
    r.id = sqlite3_column_int64(s, 0);
    r.vertex_count = uint32_t(sqlite3_column_int64(s, 1));
    r.mode_count = uint32_t(sqlite3_column_int64(s, 2));
    r.bytes = uint64_t(sqlite3_column_int64(s, 3));
    const unsigned char* c = sqlite3_column_text(s, 4);
    const unsigned char* src = sqlite3_column_text(s, 5);
    r.created = c ? reinterpret_cast<const char*>(c) : "";
    r.source = src ? reinterpret_cast<const char*>(src) : "";
    out->push_back(std::move(r));
  }
  sqlite3_finalize(s);
  if (rc != SQLITE_DONE)
    return fail(err, Status::IoError, "%s: listing bases: %s", path.c_str(), sqlite3_errmsg(db));
  return Status::Ok;
}

void recode_clip_blob(Writer& writer, int64_t clip, const std::vector<uint8_t>& blob,
                      double error_bound, double max_error) {
  sqlite3* db = writer.handle();
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db,
                         "UPDATE cloth_clip SET frames = ?, error_bound = ?, max_error = ? "
                         "WHERE id = ?",
                         -1, &s, nullptr) != SQLITE_OK)
    throw_sql(db, writer.path(), "recoding a clip");
  sqlite3_bind_blob64(s, 1, blob.data(), blob.size(), SQLITE_STATIC);
  sqlite3_bind_double(s, 2, error_bound);
  sqlite3_bind_double(s, 3, max_error);
  sqlite3_bind_int64(s, 4, clip);
  const int rc = sqlite3_step(s);
  sqlite3_finalize(s);
  if (rc != SQLITE_DONE) throw_sql(db, writer.path(), "recoding a clip");
  if (sqlite3_changes(db) != 1)
    throw ClothdbError(Status::NotFound, writer.path() + ": no cloth clip " + std::to_string(clip));
}

void recode_state_blobs(Writer& writer, int64_t state, const std::vector<uint8_t>& positions,
                        const std::vector<uint8_t>& velocities) {
  sqlite3* db = writer.handle();
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db, "UPDATE cloth_state SET positions = ?, velocities = ? WHERE id = ?",
                         -1, &s, nullptr) != SQLITE_OK)
    throw_sql(db, writer.path(), "recoding a state");
  sqlite3_bind_blob64(s, 1, positions.data(), positions.size(), SQLITE_STATIC);
  sqlite3_bind_blob64(s, 2, velocities.data(), velocities.size(), SQLITE_STATIC);
  sqlite3_bind_int64(s, 3, state);
  const int rc = sqlite3_step(s);
  sqlite3_finalize(s);
  if (rc != SQLITE_DONE) throw_sql(db, writer.path(), "recoding a state");
  if (sqlite3_changes(db) != 1)
    throw ClothdbError(Status::NotFound,
                       writer.path() + ": no cloth state " + std::to_string(state));
}

}  // namespace clothdb::db

namespace clothdb::db {

Status Reader::basis_for(const uint8_t* blob, size_t size, const codec::Basis** out, Error* err) {
  *out = nullptr;
  codec::BlobInfo info;
  if (Status st = codec::read_info(blob, size, &info, err); st != Status::Ok) return st;
  if (info.version < codec::kFormatVersionV2) return Status::Ok;
  for (const auto& b : bases_)
    if (b->id == info.basis_id) {
      *out = b.get();
      return Status::Ok;
    }
  auto b = std::make_unique<codec::Basis>();
  if (Status st = load_basis(db_, path_, info.basis_id, b.get(), err); st != Status::Ok) return st;
  bases_.push_back(std::move(b));
  *out = bases_.back().get();
  return Status::Ok;
}

Status Reader::decode(const std::vector<uint8_t>& blob, uint32_t first, uint32_t count, float* out,
                      size_t out_floats, codec::DecodeScratch& scratch, Error* err) {
  const codec::Basis* basis = nullptr;
  if (Status st = basis_for(blob.data(), blob.size(), &basis, err); st != Status::Ok) return st;
  return codec::decode_frames(blob.data(), blob.size(), first, count, out, out_floats, scratch, err,
                              basis);
}

Status Reader::decode_all(const std::vector<uint8_t>& blob, std::vector<float>* out,
                          codec::DecodeScratch& scratch, Error* err) {
  const codec::Basis* basis = nullptr;
  if (Status st = basis_for(blob.data(), blob.size(), &basis, err); st != Status::Ok) return st;
  return codec::decode_all(blob.data(), blob.size(), *out, scratch, err, basis);
}

size_t Reader::basis_bytes() const {
  size_t bytes = 0;
  for (const auto& b : bases_) bytes += b->memory_bytes();
  return bytes;
}

}  // namespace clothdb::db
