// `clothdb db check` and `clothdb db info`: integrity of a clothdb file and a summary of it.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "database/format/bases.hpp"
#include "database/store/writer.hpp"

namespace clothdb::db {

struct CheckReport {
  std::vector<std::string> problems;  // empty: the file is sound
  // Sound but incomplete: ways out of a node that a state has no clip along ("unexplored"; the
  // runtime falls back to the nearest state that has one). The demo database has some by design:
  // its budget ends the exploration before every state is expanded.
  std::vector<std::string> warnings;
  uint64_t blobs_checked = 0;
  uint64_t rows_checked = 0;
  bool ok() const { return problems.empty(); }
};

// Never throws for problems in the file: everything wrong is listed in the report. Checks
// SQLite's integrity_check and foreign_key_check, that the file is a clothdb database this build
// reads, every blob's header and chunk checksums (by decoding it fully), that each blob agrees
// with its row (frame and vertex counts, garment size) and that every edge, clip, state and
// transition points at rows that exist. Then everything the runtime relies on (runtime/db.cpp
// refuses the same at open): one garment row whose arrays match its counts and whose triangle
// indices are in range; primary clips of >= 2 frames at a finite positive rate; transitions
// joining a clip's last frame to the next clip's first, and complete at every node (every clip
// into a node to every clip out of it); cloth clips spanning their primary clip from a state at
// its source node; every cloth clip with an edge out when its end node has a way on, landing at
// that node; meta version keys this build knows; a start clip that exists.
// At most kMaxFindingsPerKind findings of one kind are listed, then a count of the rest.
CheckReport check_database(const std::string& path);

struct DatabaseInfo {
  std::string path;
  uint64_t file_bytes = 0;  // main file plus any WAL not yet checkpointed
  int schema_version = 0;
  CodecSettings codec;
  std::vector<std::pair<std::string, std::string>> meta;
  uint32_t garment_vertices = 0;  // 0: no garment
  uint32_t garment_triangles = 0;
  uint64_t motion_files = 0, primary_clips = 0, primary_transitions = 0;
  uint64_t cloth_states = 0, cloth_clips = 0, cloth_edges = 0, runs = 0, edits = 0;
  uint64_t clips_ok = 0, clips_flagged = 0, clips_edited = 0;
  uint64_t cloth_frames = 0;     // frames over all cloth clips
  uint64_t clip_blob_bytes = 0;  // encoded
  uint64_t clip_raw_bytes = 0;   // as float32 positions
  uint64_t state_blob_bytes = 0;
  double max_clip_error = 0;  // largest measured codec error, m
  // Frame codec in use (docs/DATABASE.md, "version 2"): blobs per format version, and the stored
  // bases.
  uint64_t clips_v1 = 0, clips_v2 = 0, states_v1 = 0, states_v2 = 0;
  // Codec version 3 clips and their error contracts (docs/DATABASE.md, "codec_contract"): the
  // worst recorded figure of each kind and the loosest caps.
  uint64_t clips_v3 = 0, contracts = 0;
  codec::ContractFigures worst_contract;
  codec::Contract loosest_caps;
  std::vector<BasisRow> bases;
  double run_cpu_seconds = 0;
  uint64_t linked_edges = 0;  // clip ends that linked back to a state their clip did not make
  // Dead ends closed by a link (schema 4, ClothLink) and their blend errors, m.
  uint64_t cloth_links = 0;
  double mean_link_error = 0, max_link_error = 0;
  // How exploration spread over the graph: clips_per_edge[k] primary clips have k cloth clips
  // along them (k up to the largest count), so a run that spent its budget on one loop shows.
  std::vector<uint64_t> clips_per_edge;
  std::string
      last_run_notes;  // the newest summary a run left (e.g. the explorer's unresolved errors)
  // The newest run has no finish time: it was killed (or is still running). Its committed batches
  // are in the file and the same command resumes it; last_run_notes is then an earlier run's.
  bool last_run_unfinished = false;
  int64_t last_run_id = 0;
  std::string last_run_started;
};

// Throws ClothdbError when the file cannot be opened or is not a clothdb database.
DatabaseInfo read_database_info(const std::string& path);

}  // namespace clothdb::db
