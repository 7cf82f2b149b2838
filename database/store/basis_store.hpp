// Storing codec version 2 bases (table codec_basis, created by the first store_basis, so files
// without one are unchanged and older builds simply ignore it) and recoding blobs in place (`db
// recode`). Reading them is database/format/bases.hpp.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "database/codec/codec.hpp"
#include "database/format/bases.hpp"
#include "database/store/writer.hpp"

namespace clothdb::db {

// Stores a basis (its id is ignored) and returns the new id. `source` says what it was built from.
// Joins the writer's transaction if one is open. Throws ClothdbError.
int64_t store_basis(Writer& writer, const codec::Basis& basis, const std::string& source);

// Removes a basis no blob names (the caller's promise). Throws ClothdbError.
void remove_basis(Writer& writer, int64_t id);

// Gives the pages freed by removed bases or replaced blobs back to the file system (VACUUM, then
// a WAL checkpoint). Outside any transaction. false (and why) when SQLite refuses, e.g. while a
// reader holds the file: the file is unchanged and still valid.
bool compact_file(Writer& writer, std::string* why);

// Replace a clip's frames / a state's blobs with a re-encoded version of the same data (`db
// recode`): the clip keeps its status and metrics; error_bound and max_error are the new ones
// (against the original simulation). A blob of a newer format version raises the file's
// codec.format_version. Throws ClothdbError (NotFound for a missing row).
void recode_clip_blob(Writer& writer, int64_t clip, const std::vector<uint8_t>& blob,
                      double error_bound, double max_error);
void recode_state_blobs(Writer& writer, int64_t state, const std::vector<uint8_t>& positions,
                        const std::vector<uint8_t>& velocities);

}  // namespace clothdb::db
