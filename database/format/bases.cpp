#include "database/format/bases.hpp"

#include <memory>

#include "database/format/reader.hpp"
#include "database/sqlite/statement.hpp"

namespace clothdb::db {

using sql::Stmt;

bool has_basis_table(sqlite3* db) {
  Stmt s(db, "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'codec_basis'");
  return s.ok() && s.step() == SQLITE_ROW;
}

Status load_basis(sqlite3* db, const std::string& path, int64_t id, codec::Basis* out, Error* err) {
  if (!has_basis_table(db))
    return fail(err, Status::NotFound, "%s: no basis %lld (the file has no codec_basis table)",
                path.c_str(), (long long)id);
  Stmt s(db, "SELECT data FROM codec_basis WHERE id = ?");
  const int rc = s.ok() ? s.bind(1, id).step() : s.rc();
  if (rc == SQLITE_ROW)
    return codec::parse_basis(static_cast<const uint8_t*>(s.blob(0)), s.bytes(0), id, out, err);
  if (rc == SQLITE_DONE)
    return fail(err, Status::NotFound, "%s: no basis %lld", path.c_str(), (long long)id);
  return fail(err, sql::status_of(rc), "%s: reading basis %lld: %s", path.c_str(), (long long)id,
              sqlite3_errmsg(db));
}

Status list_bases(sqlite3* db, const std::string& path, std::vector<BasisRow>* out, Error* err) {
  out->clear();
  if (!has_basis_table(db)) return Status::Ok;
  return sql::for_each_row(db, path,
                           "SELECT id, vertex_count, mode_count, length(data), created, source "
                           "FROM codec_basis ORDER BY id",
                           err, [&](Stmt& s) {
                             out->push_back({s.i64(0), uint32_t(s.i64(1)), uint32_t(s.i64(2)),
                                             uint64_t(s.i64(3)), s.text(4), s.text(5)});
                           });
}

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
