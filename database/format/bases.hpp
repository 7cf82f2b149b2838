// Reading codec version 2 bases (table codec_basis, docs/DATABASE.md "version 2"): every version 2
// blob names the basis id it was encoded with; bases are never changed once stored. Writing them
// is database/store/basis_store.hpp.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "database/codec/codec.hpp"
#include "database/format/status.hpp"

struct sqlite3;

namespace clothdb::db {

// Loads basis `id` (NotFound if the file has no such basis or no basis table).
Status load_basis(sqlite3* db, const std::string& path, int64_t id, codec::Basis* out, Error* err);

// Ids and sizes of the stored bases, oldest first (empty if none).
struct BasisRow {
  int64_t id = 0;
  uint32_t vertex_count = 0, mode_count = 0;
  uint64_t bytes = 0;
  std::string created, source;
};
Status list_bases(sqlite3* db, const std::string& path, std::vector<BasisRow>* out, Error* err);

// Whether the file has a codec_basis table yet (it is created by the first basis stored).
bool has_basis_table(sqlite3* db);

}  // namespace clothdb::db
