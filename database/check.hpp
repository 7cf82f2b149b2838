// `clothdb db check` and `clothdb db info`: integrity of a clothdb file and a summary of it.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "database/basis_store.hpp"
#include "database/schema.hpp"

namespace clothdb::db {

struct CheckReport {
  std::vector<std::string> problems;  // empty: the file is sound
  uint64_t blobs_checked = 0;
  uint64_t rows_checked = 0;
  bool ok() const { return problems.empty(); }
};

// Never throws for problems in the file: everything wrong is listed in the report. Checks
// SQLite's integrity_check and foreign_key_check, that the file is a clothdb database this build
// reads, every blob's header and chunk checksums (by decoding it fully), that each blob agrees
// with its row (frame and vertex counts, garment size) and that every edge, clip, state and
// transition points at rows that exist.
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
  // Frame codec in use (issue 17): blobs per format version, and the stored bases.
  uint64_t clips_v1 = 0, clips_v2 = 0, states_v1 = 0, states_v2 = 0;
  std::vector<BasisRow> bases;
  double run_cpu_seconds = 0;
};

// Throws ClothdbError when the file cannot be opened or is not a clothdb database.
DatabaseInfo read_database_info(const std::string& path);

}  // namespace clothdb::db
