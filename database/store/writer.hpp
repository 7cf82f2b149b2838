// Writing a clothdb file (docs/DATABASE.md): creation, migration, rows, blobs, the edit log.
// Throws ClothdbError (its message names the file and what is wrong). The `clothdb_store` target;
// the runtime never links it.
//
// Durability: WAL journal, every write in a transaction, synchronous=FULL; a writer killed at any
// moment leaves the last committed state, and readers (game players) read while it writes. One
// writer per file (writer_lock.hpp).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "database/codec/codec.hpp"
#include "database/codec/settings.hpp"
#include "database/format/cloth_graph.hpp"
#include "database/format/meta_keys.hpp"
#include "database/format/reader.hpp"
#include "database/format/rows.hpp"
#include "database/format/status.hpp"
#include "database/format/tables.hpp"

struct sqlite3;
struct sqlite3_session;

namespace clothdb::db {

class WriterLock;

class Writer {
 public:
  // Creates a new database; refuses to overwrite an existing file.
  static Writer create(const std::string& path, const CodecSettings& codec = {});
  // Opens an existing clothdb database for writing (checks it is one and not newer).
  static Writer open(const std::string& path);
  // Opens `path`, or creates it with the default codec and, when position_bound > 0, that
  // position bound (m). A file's codec is fixed when it is made: an existing file with another
  // bound is refused (naming the file, the field and both values) before anything is written.
  static Writer open_or_create(const std::string& path, double position_bound);

  Writer(Writer&& other) noexcept;
  Writer& operator=(Writer&& other) noexcept;
  Writer(const Writer&) = delete;
  Writer& operator=(const Writer&) = delete;
  ~Writer();

  const std::string& path() const { return path_; }
  const CodecSettings& codec() const { return codec_; }

  // Sets a meta key (database/format/meta_keys.hpp; the typed set_meta_* below are the usual way).
  void set_meta(const std::string& key, const std::string& value);
  void put_garment(const Garment& garment);  // once; clips must match its vertex count
  // Once, after put_garment, for a garment made from an artist's file (a procedural garment stores
  // none: it reads back as db::identity_artist_mesh). Checked by db::check_artist_mesh first.
  void put_artist_mesh(const ArtistMesh& mesh);
  int64_t add_motion_file(const std::string& path, const std::string& content_hash);
  int64_t add_source_file(const SourceFile& file);  // its id; the file's id is not used
  int64_t add_primary_clip(const PrimaryClip& clip);
  int64_t add_primary_transition(const PrimaryTransition& transition);

  int64_t begin_run(const std::string& settings, const std::string& host = "");
  void finish_run(int64_t run, double cpu_seconds, const std::string& notes = "");

  // positions and velocities: vertex_count * 3 floats each, encoded with the file's bounds.
  int64_t add_cloth_state(int64_t primary_clip, int32_t frame, const float* positions,
                          const float* velocities, uint32_t vertex_count, int64_t run = 0,
                          int64_t source_clip = 0);
  // The same with the two one-frame blobs already encoded (e.g. by a worker process with this
  // file's codec settings); their vertex counts are checked.
  int64_t add_cloth_state_blobs(int64_t primary_clip, int32_t frame,
                                const std::vector<uint8_t>& positions,
                                const std::vector<uint8_t>& velocities, int64_t run = 0,
                                int64_t source_clip = 0);
  // frames: frame_count * vertex_count * 3 floats, encoded with the file's codec settings.
  int64_t add_cloth_clip(const NewClothClip& clip, const float* frames, uint32_t frame_count,
                         uint32_t vertex_count);
  // Encodes clip frames with the file's codec settings, exactly as add_cloth_clip would; touches
  // no SQLite state, so worker threads may call it concurrently. max_error: measured after
  // decoding.
  std::vector<uint8_t> encode_clip(const float* frames, uint32_t frame_count, uint32_t vertex_count,
                                   double* max_error) const;
  // The same with a blob already encoded (e.g. on worker threads outside the write lock).
  int64_t add_cloth_clip_blob(const NewClothClip& clip, const std::vector<uint8_t>& blob,
                              double max_error);
  int64_t add_cloth_edge(int64_t from_clip, int64_t to_state, double blend_error,
                         double pop = kUnknownMetric);
  // Replaces every cloth link (one transaction; ClothLink::id is ignored).
  void replace_cloth_links(const std::vector<ClothLink>& links);
  int64_t add_cloth_link(const ClothLink& link);  // ClothLink::id is ignored
  void set_clip_steering(const ClipSteering& steering);
  // Replaces a clip's quality metrics (e.g. after its frames were edited or re-simulated) and an
  // edge's pop. Not logged: an edit that changes frames records the change itself.
  void set_clip_metrics(int64_t clip, const ClipMetrics& metrics);
  void set_edge_pop(int64_t edge, double pop);

  // Reverts the newest edit that is not an undo and not yet undone, exactly (its changeset
  // inverted), and logs the undo. Throws
  // NotFound when there is nothing to undo, and InvalidArgument (changing nothing) when rows it
  // changed were changed again outside the log since (e.g. by a resumed precompute).
  EditLogEntry undo_last(const std::string& author);

  // Plain row writes for the edit tools (inside an Edit, so they are logged and undoable).
  void replace_clip_blob(int64_t clip, const std::vector<uint8_t>& blob, double max_error,
                         ClipStatus status);
  void set_clip_status_unlogged(int64_t clip, ClipStatus status);
  void set_edge(int64_t edge, int64_t to_state, double blend_error, double pop);
  // Removes a clip and its out edges; the states it made keep their data, source_clip cleared.
  void remove_clip(int64_t clip);

  // Groups writes into one transaction: commit() makes them durable together; destroying an
  // uncommitted Transaction rolls back. Without one, each call is its own transaction.
  class Transaction {
   public:
    explicit Transaction(Writer& writer);
    ~Transaction();
    Transaction(const Transaction&) = delete;
    Transaction& operator=(const Transaction&) = delete;
    void commit();

   private:
    Writer* writer_;
    bool done_ = false;
  };

  // One logged change of the cloth graph that may touch many rows (import, resim, delete, flag):
  // a transaction in which SQLite's session extension records every row changed in the undoable
  // tables (TableInfo::undoable). Defined in edit_log.cpp, the only unit that needs the session
  // extension. commit() stores that changeset in the edit log with the
  // entry, in the same transaction, so undo_last() can put back exactly the rows it changed.
  // Destroying an uncommitted Edit rolls everything back: nothing half-written.
  class Edit {
   public:
    Edit(Writer& writer, int64_t clip, const std::string& action, const std::string& author);
    ~Edit();
    Edit(const Edit&) = delete;
    Edit& operator=(const Edit&) = delete;
    int64_t commit(const std::string& description);  // the edit_log id

   private:
    Writer* writer_;
    int64_t clip_;
    std::string action_, author_;
    sqlite3_session* session_ = nullptr;
    Transaction tx_;
  };

  // Creates an on-demand table (TableInfo::on_demand, e.g. codec_basis) if the file lacks it.
  void ensure_table(const char* name);
  // Raises meta codec.format_version to the blob's format version when it is newer, so a runtime
  // that cannot decode it refuses the file at open. Called for every blob stored (inside the
  // caller's transaction, if any).
  void note_blob_version(const std::vector<uint8_t>& blob);
  // Throws ClothdbError for the connection's last SQLite error: `what` and SQLite's message,
  // the status from sql::status_of.
  [[noreturn]] void throw_sql(const char* what);

  sqlite3* handle() { return db_; }

 private:
  Writer(sqlite3* db, std::string path);
  void exec(const char* sql);
  void migrate(int from_version);
  std::vector<uint8_t> encode_frames(const float* frames, uint32_t frame_count,
                                     uint32_t vertex_count, double bound, double* max_error) const;
  uint32_t garment_vertices();  // 0 if no garment yet
  void check_vertex_count(uint32_t vertex_count, const char* what);

  std::shared_ptr<WriterLock> lock_;  // one writer per database (writer_lock.hpp)
  sqlite3* db_ = nullptr;
  std::string path_;
  CodecSettings codec_;
  int transaction_depth_ = 0;
};

// Typed writes of meta keys (database/format/meta_keys.hpp), inside the caller's transaction if
// any; the typed reads are in database/format/cloth_graph.hpp.
void set_meta_text(Writer& writer, const char* key, const std::string& value);
void set_meta_integer(Writer& writer, const char* key, int64_t value);
// Written with 17 significant digits: meta_number reads back the same double.
void set_meta_number(Writer& writer, const char* key, double value);

}  // namespace clothdb::db
