// The clothdb database: one SQLite file holding a garment, the character's primary motion graph
// and the secondary cloth graph of Kim et al. 2013 (cloth states, cloth clips, edges), plus runs
// and an edit log. docs/DATABASE.md describes the tables.
//
// Recognition: PRAGMA application_id = 'CLDB' and PRAGMA user_version = schema version, set in the
// same transaction that creates the tables, so a half-created file is never taken for a finished
// one. Durability: WAL journal, every write in a transaction, synchronous=FULL; a writer killed at
// any moment leaves the last committed state, and readers (game players) read while it writes.
//
// Writer: throws ClothdbError (message names the file and what is wrong). Reader: never throws;
// returns a Status and fills an Error, as the C runtime API needs.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "database/codec.hpp"
#include "database/run_settings.hpp"  // CodecSettings
#include "database/status.hpp"

struct sqlite3;
struct sqlite3_stmt;
struct sqlite3_session;

namespace clothdb::db {

// Version 2 added the quality metrics (cloth_clip: mean_penetration, jitter, halved_steps,
// worst_frame; cloth_edge: pop). Version 3: the edit log keeps each edit's changeset (exact undo
// of edits that touch many rows) and the actions flag, unflag, import, resim, delete. Writer::open
// migrates older files in one transaction; the Reader reads them as they are. Version 4: the
// cloth_link table (a dead end's precomputed continuation, ClothLink).
constexpr int kSchemaVersion = 4;
constexpr int32_t kApplicationId = 0x434C4442;  // "CLDB"

enum class ClipStatus { Ok, Flagged, Edited };
const char* clip_status_name(ClipStatus status);  // "ok", "flagged", "edited"
bool parse_clip_status(const std::string& name, ClipStatus* status);

struct Garment {
  std::vector<uint32_t> triangles;    // 3 vertex indices per triangle
  std::vector<float> rest_positions;  // 3 floats per vertex, m
  std::string material;               // material settings as given (JSON text)
  std::string solver;                 // solver settings as given (JSON text)
  uint32_t vertex_count() const { return uint32_t(rest_positions.size() / 3); }
};

struct MotionFile {
  int64_t id = 0;
  std::string path;          // as given in the scene file
  std::string content_hash;  // e.g. "sha256:..." of the file's bytes
};

struct PrimaryClip {
  int64_t id = 0;
  std::string name;
  int64_t motion_file = 0;  // 0: none
  int32_t first_frame = 0;  // in the motion file
  int32_t frame_count = 0;
  double frame_rate = 30;
};

struct PrimaryTransition {
  int64_t id = 0;
  int64_t from_clip = 0;
  int32_t from_frame = 0;
  int64_t to_clip = 0;
  int32_t to_frame = 0;
  int32_t blend_frames = 0;
  double cost = 0;
};

// A cloth state: positions and velocities of the garment at a point (primary clip, frame).
struct StoredState {
  int64_t id = 0;
  int64_t primary_clip = 0;
  int32_t frame = 0;
  int64_t source_clip = 0;  // the cloth clip whose end produced it; 0: initial / dead-end seed
  int64_t run = 0;          // 0: none
  size_t positions_bytes = 0;
  size_t velocities_bytes = 0;
};

// A metric that was not measured (a file of schema version 1, or a clip written without it) is
// NaN (doubles) or -1 (counts) in memory and NULL in the file.
constexpr double kUnknownMetric = std::numeric_limits<double>::quiet_NaN();

// Quality of a cloth clip; precompute/quality/clip_quality.hpp defines and measures each one
// (docs/DATABASE.md). Lengths in metres.
struct ClipMetrics {
  double max_strain = 0;                     // max (l - l0) / l0 over edges and frames
  double max_penetration = 0;                // m, deepest free vertex inside a body capsule
  double mean_penetration = kUnknownMetric;  // m, mean over penetrating vertex-frames
  double jitter = kUnknownMetric;            // m, RMS high-pass (4th difference) motion
  int32_t halved_steps = -1;                 // times the solver halved its step
  int32_t worst_frame = -1;                  // frame of the clip where it looks worst
};

// A cloth clip: frames simulated from a cloth state along one primary clip.
struct ClothClip {
  int64_t id = 0;
  int64_t start_state = 0;
  int64_t primary_clip = 0;
  int32_t first_frame = 0;  // primary clip frame of the clip's first frame
  int32_t frame_count = 0;
  double error_bound = 0;      // codec bound the frames were stored with, m
  double max_error = 0;        // largest codec error actually measured, m
  double max_strain = 0;       // the quality metrics: ClipMetrics
  double max_penetration = 0;  // m
  ClipStatus status = ClipStatus::Ok;
  int64_t run = 0;
  size_t blob_bytes = 0;
  double mean_penetration = kUnknownMetric;  // m
  double jitter = kUnknownMetric;            // m
  int32_t halved_steps = -1;
  int32_t worst_frame = -1;

  ClipMetrics metrics() const {
    return {max_strain, max_penetration, mean_penetration, jitter, halved_steps, worst_frame};
  }
};

// The end of a cloth clip continues into a cloth state (possibly a blend from a different one).
struct ClothEdge {
  int64_t id = 0;
  int64_t from_clip = 0;
  int64_t to_state = 0;
  double blend_error = 0;  // m, state distance between the clip's end and the state (explorer)
  // m: the jump the runtime's offset blend absorbs at this edge, max over vertices of
  // |clip's last frame - state's positions| (clip_quality.hpp); kUnknownMetric if not measured.
  double pop = kUnknownMetric;
};

// A dead end closed without simulating it: state `from_state` has no clip along `primary_clip`,
// so the game continues with clip `to_clip` (along the same primary clip, from the nearest state
// at the same node that has one), blending away `blend_error` (m, db::state_distance of the two
// states). Written by the explorer when its budget ends; the runtime needs no fallback search.
struct ClothLink {
  int64_t id = 0;
  int64_t from_state = 0;
  int64_t primary_clip = 0;
  int64_t to_clip = 0;
  double blend_error = 0;
  int64_t run = 0;  // 0: none recorded
};

// A clip whose end was steered onto a state (issue 16, SceneFile::steering in the precompute):
// how far its unsteered end was from that state (m, db::state_distance) and how hard the pull was
// (the largest displacement of a vertex in one frame, m, and that over dt^2, m/s^2).
struct ClipSteering {
  int64_t clip = 0;
  int64_t target_state = 0;
  double distance = 0;
  double displacement = 0;
  double acceleration = 0;
};

struct Run {
  int64_t id = 0;
  std::string started;   // ISO 8601 UTC
  std::string finished;  // empty while running (or if the run was killed)
  std::string settings;  // what was simulated and how (JSON text as given)
  double cpu_seconds = 0;
  std::string host;
  std::string notes;
};

struct EditLogEntry {
  int64_t id = 0;
  std::string time;
  std::string author;
  int64_t clip = 0;
  // "set-status", "replace-frames" (early builds, no changeset), "undo", or an Edit's:
  // "flag", "unflag", "import", "resim", "delete"
  std::string action;
  std::string description;
  std::string old_status, new_status;
  bool has_old_frames = false;  // the previous blob is kept, so the edit can be undone
  int64_t undoes = 0;           // for "undo": the edit it reverted
  bool has_changeset = false;   // an Edit's: every row it changed, as an SQLite changeset
};

struct NewClothClip {
  int64_t start_state = 0;
  int64_t primary_clip = 0;
  int32_t first_frame = 0;
  double max_strain = 0;  // the quality metrics: ClipMetrics
  double max_penetration = 0;
  ClipStatus status = ClipStatus::Ok;
  int64_t run = 0;
  double mean_penetration = kUnknownMetric;  // m
  double jitter = kUnknownMetric;            // m
  int32_t halved_steps = -1;
  int32_t worst_frame = -1;

  void set_metrics(const ClipMetrics& m) {
    max_strain = m.max_strain;
    max_penetration = m.max_penetration;
    mean_penetration = m.mean_penetration;
    jitter = m.jitter;
    halved_steps = m.halved_steps;
    worst_frame = m.worst_frame;
  }
};

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

  void set_meta(const std::string& key, const std::string& value);  // e.g. "scene"
  void put_garment(const Garment& garment);  // once; clips must match its vertex count
  int64_t add_motion_file(const std::string& path, const std::string& content_hash);
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
  // a transaction in which SQLite's session extension records every row changed in cloth_state,
  // cloth_clip, cloth_edge, run and meta. commit() stores that changeset in the edit log with the
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

  sqlite3* handle() { return db_; }

 private:
  Writer(sqlite3* db, std::string path);
  void exec(const char* sql);
  void migrate(int from_version);
  [[noreturn]] void throw_sql(const char* what);
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
  // Reads through the writer's own connection (not closed with this Reader; the Writer must
  // outlive it), so it sees the writer's uncommitted changes: tools that read back what their
  // edit has written so far, inside the edit's transaction.
  Status open_on(Writer& writer, Error* err);
  void close();
  bool is_open() const { return db_ != nullptr; }
  const std::string& path() const { return path_; }
  int schema_version() const { return schema_version_; }
  const CodecSettings& codec() const { return codec_; }

  Status meta(const std::string& key, std::string* value, Error* err);
  Status all_meta(std::vector<std::pair<std::string, std::string>>* out, Error* err);
  Status garment(Garment* out, Error* err);  // NotFound if none was stored
  Status motion_files(std::vector<MotionFile>* out, Error* err);
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

  // The basis a codec version 2 blob names (table codec_basis, database/basis_store.hpp), loaded
  // on first use and kept for the Reader's life; null for a version 1 blob. NotFound if the file
  // has no basis with that id. Defined in basis_store.cpp.
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
  Status prepare(sqlite3_stmt** cache, const char* sql, Error* err);
  Status step_error(const char* what, Error* err);

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
