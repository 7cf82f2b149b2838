// Reading a clothdb file (docs/DATABASE.md): recognition, rows, blobs and their decoding. The
// reading side never throws: it returns a Status and fills an Error, as the C runtime API needs.
// This is what the runtime links (the `clothdb_format` target); the writer is in database/store/.
//
// Recognition: PRAGMA application_id = 'CLDB' and PRAGMA user_version = schema version
// (database/format/tables.hpp), set in the same transaction that creates the tables, so a
// half-created file is never taken for a finished one. Readers (game players) read while one
// writer writes (WAL).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "database/codec/codec.hpp"
#include "database/codec/settings.hpp"
#include "database/format/rows.hpp"
#include "database/format/status.hpp"
#include "database/format/tables.hpp"

struct sqlite3;
struct sqlite3_stmt;

namespace clothdb::db {

// Checks that an open connection is a finished clothdb database this build can read, and loads
// its schema version and codec settings. Shared by the reader, the writer and `db check`.
Status recognise(sqlite3* db, const std::string& path, int* version, CodecSettings* codec,
                 Error* err);

// One Reader per thread (it caches prepared statements); any number of Readers, in any number of
// processes, may read while one Writer writes.
class Reader {
 public:
  Reader() = default;
  Reader(Reader&& other) noexcept;
  Reader& operator=(Reader&& other) noexcept;
  Reader(const Reader&) = delete;
  Reader& operator=(const Reader&) = delete;
  ~Reader();

  // Opens read-only. Errors: IoError (cannot open), NotClothdb, NewerVersion, Corrupt.
  Status open(const std::string& path, Error* err);
  // Reads through a writer's own connection (`Writer::handle()`; not closed with this Reader, the
  // Writer must outlive it), so it sees the writer's uncommitted changes: tools that read back
  // what their edit has written so far, inside the edit's transaction.
  Status open_borrowed(sqlite3* connection, const std::string& path, Error* err);
  void close();
  bool is_open() const { return db_ != nullptr; }
  const std::string& path() const { return path_; }
  int schema_version() const { return schema_version_; }
  const CodecSettings& codec() const { return codec_; }

  Status meta(const std::string& key, std::string* value, Error* err);
  Status all_meta(std::vector<std::pair<std::string, std::string>>* out, Error* err);
  Status garment(Garment* out, Error* err);  // NotFound if none was stored
  // The artist's mesh (rows.hpp), checked (db::check_artist_mesh); for a file without one (a
  // procedural garment, or schema < 5) the identity mesh of the garment. NotFound if no garment.
  Status artist_mesh(ArtistMesh* out, Error* err);
  Status motion_files(std::vector<MotionFile>* out, Error* err);
  Status source_files(std::vector<SourceFile>* out, Error* err);  // empty before schema 5
  Status primary_clips(std::vector<PrimaryClip>* out, Error* err);
  Status primary_transitions(std::vector<PrimaryTransition>* out, Error* err);
  Status cloth_states(std::vector<StoredState>* out, Error* err);
  Status cloth_clips(std::vector<ClothClip>* out, Error* err);
  Status cloth_clip(int64_t id, ClothClip* out, Error* err);
  Status cloth_edges(std::vector<ClothEdge>* out, Error* err);
  Status cloth_links(std::vector<ClothLink>* out, Error* err);       // empty before schema 4
  Status clip_steering(std::vector<ClipSteering>* out, Error* err);  // empty before schema 4
  Status runs(std::vector<Run>* out, Error* err);
  Status edit_log(std::vector<EditLogEntry>* out, Error* err);

  // Copies a clip's encoded frames into `blob` (reusing its capacity: no allocation once it is
  // large enough). Decode with codec::decode_frames.
  Status clip_blob(int64_t clip, std::vector<uint8_t>* blob, Error* err);
  Status state_blobs(int64_t state, std::vector<uint8_t>* positions,
                     std::vector<uint8_t>* velocities, Error* err);
  // Decoded cloth state (vertex_count * 3 floats each).
  Status read_state(int64_t state, std::vector<float>* positions, std::vector<float>* velocities,
                    codec::DecodeScratch& scratch, Error* err);

  // The basis a codec version 2 blob names (table codec_basis, database/format/bases.hpp),
  // loaded on first use and kept for the Reader's life; null for a version 1 blob. NotFound if
  // the file has no basis with that id.
  Status basis_for(const uint8_t* blob, size_t size, const codec::Basis** out, Error* err);
  // Decodes frames [first, first + count) of one of this file's blobs, version 1 or 2.
  Status decode(const std::vector<uint8_t>& blob, uint32_t first, uint32_t count, float* out,
                size_t out_floats, codec::DecodeScratch& scratch, Error* err);
  // Decodes all frames of one of this file's blobs, version 1 or 2.
  Status decode_all(const std::vector<uint8_t>& blob, std::vector<float>* out,
                    codec::DecodeScratch& scratch, Error* err);
  // Memory held by the bases loaded so far.
  size_t basis_bytes() const;

  sqlite3* handle() { return db_; }

 private:
  [[nodiscard]] Status prepare(sqlite3_stmt** cache, const char* sql, Error* err);
  [[nodiscard]] Status step_error(const char* what, Error* err);

  sqlite3* db_ = nullptr;
  std::string path_;
  int schema_version_ = 0;
  CodecSettings codec_;
  sqlite3_stmt* clip_blob_stmt_ = nullptr;
  sqlite3_stmt* state_blob_stmt_ = nullptr;
  std::vector<uint8_t> state_pos_, state_vel_;
  bool borrowed_ = false;                             // db_ is a Writer's connection
  std::vector<std::unique_ptr<codec::Basis>> bases_;  // loaded by basis_for
};

}  // namespace clothdb::db
